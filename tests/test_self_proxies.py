"""The hand model's self proxies (MJCF class ``self_proxy``, hand_mjcf.enable_self_proxies): each
collision proxy's copy, inert as shipped, turned on by SoftHand with Config.self_collision, so MuJoCo
keeps two parts' bones from coming nearer than where their rest skins would meet
(docs/self_collision.md, "The bones keep the flesh's room")."""

import mujoco
import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.hand_mjcf import SELF_PROXY_BIT, SELF_PROXY_SUFFIX, body_ids, enable_self_proxies
from physhand_mj.rollout import load_rollout_scene

# adjacent fingers' middle phalanges: the power keyframe presses them together
NEIGHBOURS = [("midph2_r", "midph3_r"), ("midph3_r", "midph4_r"), ("midph4_r", "midph5_r")]


def _scene(key):
    model, data, _ = load_rollout_scene(ph.scene_path("hand_only"), key)
    return model, data


def _self_geoms(model):
    return [g for g in range(model.ngeom) if model.geom(g).name.endswith(SELF_PROXY_SUFFIX)]


def _bone_gap(model, data, a: str, b: str) -> float:
    """The least distance (m) between the bone meshes of bodies ``a`` and ``b`` (MuJoCo's own bone
    display geoms, class ``bone``: vertices in the world frame), not the proxies."""
    def verts(body):
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, body + "_bone")
        mid = model.geom_dataid[g]
        v = model.mesh_vert[model.mesh_vertadr[mid]:model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
        return v @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]

    from scipy.spatial import cKDTree

    return float(cKDTree(verts(a)).query(verts(b))[0].min())


def _hold(model, data, frames=36):
    for _ in range(frames):
        mujoco.mj_step(model, data)


def test_self_proxies_mirror_the_proxies_and_are_inert_as_shipped():
    model, data = _scene("power")
    proxies = [g for g in range(model.ngeom) if model.geom(g).name.endswith("_proxy")]
    selfs = _self_geoms(model)
    assert len(proxies) == len(selfs) == 16
    for g in proxies:
        s = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, model.geom(g).name[:-len("_proxy")] + SELF_PROXY_SUFFIX)
        assert s >= 0
        assert model.geom_bodyid[s] == model.geom_bodyid[g] and model.geom_type[s] == model.geom_type[g]
        np.testing.assert_array_equal(model.geom_size[s], model.geom_size[g])
        np.testing.assert_array_equal(model.geom_pos[s], model.geom_pos[g])
        np.testing.assert_array_equal(model.geom_quat[s], model.geom_quat[g])
        assert model.geom_contype[s] == SELF_PROXY_BIT and model.geom_conaffinity[s] == 0
        assert model.geom_margin[s] == pytest.approx(2.5e-3)
    # the power keyframe presses the fingers together, yet nothing touches an inert self proxy
    _hold(model, data, 5)
    assert not any(c.geom1 in selfs or c.geom2 in selfs for c in data.contact[:data.ncon])


def test_self_proxies_keep_the_bones_apart():
    """MuJoCo alone, the power keyframe held 36 frames: the index's and the middle finger's middle
    phalanges (their bone meshes, not the proxies) come 0.9 mm apart without the self proxies; with
    them the fingers stop where their rest skins meet, every neighbouring pair's bones more than 3 mm
    apart. The open keyframe,
    whose parts lie apart, moves bit for bit as without them."""
    model, data = _scene("power")
    _hold(model, data)
    before = [_bone_gap(model, data, a, b) for a, b in NEIGHBOURS]
    model, data = _scene("power")
    on = enable_self_proxies(model, body_ids(model, ph.load_asset().body_names))
    assert len(on) == 16
    _hold(model, data)
    after = [_bone_gap(model, data, a, b) for a, b in NEIGHBOURS]
    assert min(before) < 1.5e-3, before
    assert min(after) > 3e-3, (before, after)  # (measured 4.5-4.7 mm against 0.9, 2.1 and 5.3)
    # the other proxies still collide with objects as before: their bits are untouched
    assert set(model.geom_conaffinity[[g for g in range(model.ngeom) if model.geom(g).name.endswith("_proxy")]]) == {1}

    model, data = _scene("open")
    _hold(model, data, 20)
    q_off = data.qpos.copy()
    model, data = _scene("open")
    enable_self_proxies(model, body_ids(model, ph.load_asset().body_names))
    _hold(model, data, 20)
    np.testing.assert_array_equal(data.qpos, q_off)


@pytest.mark.parametrize("self_collision,self_proxies,expect", [(True, True, 16), (True, False, 0), (False, True, 0)])
def test_soft_hand_turns_them_on_with_self_collision(self_collision, self_proxies, expect):
    model, data = _scene("open")
    cfg = ph.Config(frame_dt=0.005, self_collision=self_collision, tuning=ph.Tuning(self_proxies=self_proxies))
    hand = ph.SoftHand(model, data, cfg, settle_frames=0)
    assert len(hand.self_proxies) == expect
    lit = [g for g in _self_geoms(model) if model.geom_conaffinity[g] & SELF_PROXY_BIT]
    assert len(lit) == expect


def test_a_soft_hand_without_the_option_turns_them_off():
    """The model follows the last SoftHand made on it: one without self-collision turns the copies
    off again, geoms and bodies (MuJoCo's body filter) alike, and the power keyframe then has no
    self-proxy contact."""
    model, data = _scene("power")
    ph.SoftHand(model, data, ph.Config(frame_dt=0.005, self_collision=True), settle_frames=0)
    mujoco.mj_forward(model, data)
    selfs = set(_self_geoms(model))
    assert any(c.geom1 in selfs and c.geom2 in selfs for c in data.contact[:data.ncon])
    body_bits = model.body_conaffinity.copy()
    hand = ph.SoftHand(model, data, ph.Config(frame_dt=0.005), settle_frames=0)
    assert len(hand.self_proxies) == 0
    assert not any(model.geom_conaffinity[g] & SELF_PROXY_BIT for g in selfs)
    assert not np.any(model.body_conaffinity & SELF_PROXY_BIT) and np.any(body_bits & SELF_PROXY_BIT)
    mujoco.mj_forward(model, data)
    assert not any(c.geom1 in selfs or c.geom2 in selfs for c in data.contact[:data.ncon])


def test_tuning_checks_the_flag():
    with pytest.raises(ValueError, match="self_proxies"):
        ph.Config(tuning=ph.Tuning(self_proxies="yes")).validate()
