"""Config.skin_compression: skin edges that resist stretch only (solver/edge.py, docs/self_collision.md
"Skin that gives in compression")."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.solver.edge import edge_correction
from physhand_mj.types import Layer

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@wp.kernel
def _step(x1: wp.array(dtype=wp.vec3), x2: wp.array(dtype=wp.vec3), rest: wp.array(dtype=float),
          moves: wp.array(dtype=int), d1: wp.array(dtype=wp.vec3), d2: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    m, dlam, a, b = edge_correction(x1[i], x2[i], 1.0, 1.0, rest[i], 0.0, 0.0)
    moves[i] = m
    d1[i] = a
    d2[i] = b


@pytest.mark.parametrize("device", DEVICES)
def test_stretch_only_edge_analytic(device):
    """A 1 mm edge of two unit inverse masses (hard, alpha 0) at 0.8 mm and 1.3 mm: the two-sided edge
    (rest +1 mm) moves each end half the error back (0.1 and 0.15 mm); the stretch-only edge (rest -1 mm)
    does nothing compressed and exactly the same stretched."""
    L = 1.0e-3
    x1 = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]], np.float32)
    x2 = np.array([[0.8 * L, 0, 0], [1.3 * L, 0, 0], [0.8 * L, 0, 0], [1.3 * L, 0, 0]], np.float32)
    rest = np.array([L, L, -L, -L], np.float32)
    arr = lambda a, t=wp.vec3: wp.array(a, dtype=t, device=device)
    moves, d1, d2 = wp.zeros(4, dtype=int, device=device), wp.zeros(4, dtype=wp.vec3, device=device), \
        wp.zeros(4, dtype=wp.vec3, device=device)
    wp.launch(_step, 4, inputs=[arr(x1), arr(x2), arr(rest, float)], outputs=[moves, d1, d2], device=device)
    m, a, b = moves.numpy(), d1.numpy(), d2.numpy()
    assert m.tolist() == [1, 1, 0, 1]
    np.testing.assert_allclose(a[0], [-0.1e-3, 0, 0], atol=1e-9)  # compressed: pushed apart
    np.testing.assert_allclose(b[0], [0.1e-3, 0, 0], atol=1e-9)
    np.testing.assert_allclose(a[1], [0.15e-3, 0, 0], atol=1e-9)  # stretched: pulled together
    np.testing.assert_allclose(a[2], 0.0)
    np.testing.assert_array_equal(a[3], a[1])
    np.testing.assert_array_equal(b[3], b[1])


def test_model_marks_only_skin_edges():
    """skin_compression False makes the skin-skin edges' rest lengths negative and leaves every flesh
    edge and attachment as it is; the default makes none negative."""
    from physhand_mj.solver import make_model

    asset = ph.load_asset()
    on = make_model(asset, ph.Config(device="cpu").validate())
    off = make_model(asset, ph.Config(device="cpu", skin_compression=False).validate())
    ids, r_on, r_off = on.edge_ids.numpy(), on.edge_rest.numpy(), off.edge_rest.numpy()
    assert np.all(r_on > 0)
    layer = np.asarray(asset.layer)
    skin = (layer[ids] == Layer.SKIN).all(axis=1) & ~on.edge_is_att
    assert skin.sum() > 10000
    np.testing.assert_array_equal(r_off[skin], -r_on[skin])
    np.testing.assert_array_equal(r_off[~skin], r_on[~skin])
    with pytest.raises(ValueError, match="skin_compression"):
        ph.Config(skin_compression=0).validate()


def test_model_marks_flesh_edges_and_keeps_attachments():
    """flesh_compression False makes every other tet edge stretch-only; the flesh attachments (Eq. 4)
    keep resisting both ways; with skin_compression False too, every tet edge is stretch-only."""
    from physhand_mj.solver import make_model

    asset = ph.load_asset()
    on = make_model(asset, ph.Config(device="cpu").validate())
    flesh = make_model(asset, ph.Config(device="cpu", flesh_compression=False).validate())
    both = make_model(asset, ph.Config(device="cpu", skin_compression=False, flesh_compression=False).validate())
    ids, r_on = on.edge_ids.numpy(), on.edge_rest.numpy()
    att = np.asarray(on.edge_is_att)
    skin = (np.asarray(asset.layer)[ids] == Layer.SKIN).all(axis=1) & ~att
    np.testing.assert_array_equal(flesh.edge_rest.numpy()[~skin & ~att], -r_on[~skin & ~att])
    np.testing.assert_array_equal(flesh.edge_rest.numpy()[skin | att], r_on[skin | att])
    np.testing.assert_array_equal(both.edge_rest.numpy()[~att], -r_on[~att])
    assert att.any() and np.all(both.edge_rest.numpy()[att] > 0)
    with pytest.raises(ValueError, match="flesh_compression"):
        ph.Config(flesh_compression="no").validate()


def _grasp(scene: str, last: int = 1, **options):
    """``scene``'s grasp keyframe with self-collision and ``options``, 36 frames (CPU): the
    self-penetration measure (contact/self_measures.py; with ``last`` > 1 a list, one per frame of
    the last ``last``) and the object's two measures (order-9 skin samples and the denser check
    points)."""
    import mujoco

    from physhand_mj.contact.self_measures import self_penetration
    from physhand_mj.rollout import load_rollout_scene

    model, data, _ = load_rollout_scene(ph.scene_path(scene), "grasp")
    cfg = ph.Config(frame_dt=float(model.opt.timestep), device="cpu", self_collision=True, **options)
    hand = ph.SoftHand(model, data, cfg, settle_contact=False)
    faces, per = np.asarray(hand.asset.skin_faces), []
    for f in range(36):
        mujoco.mj_step(model, data)
        hand.step()
        if f >= 36 - last:
            x = hand.state.x.numpy()
            assert np.all(np.isfinite(x))
            per.append(self_penetration(x, faces))
    return (per[0] if last == 1 else per), hand.penetration(order=9, check=True)


def test_stretch_only_skin_clears_the_glass_grasp():
    """hoi_glass1's grasp with self-collision, 36 frames (CPU): with the skin's edges stretch-only the
    skin's buckled folds are gone (measured: 2 vertices' 0.2 mm offsets inside the skin and 9 skin edges
    through another triangle, against 8 and 36 with the paper's two-sided edges), and the object stays
    out of the skin by both of its measures."""
    m, p = _grasp("hoi_glass1", skin_compression=False)
    assert m["inside_200um"] <= 4 and m["crossing_edges"] <= 18, m
    assert p["penetration_count"] == 0 and p["object_in_skin_count"] == 0, p


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_stretch_only_tissue_clears_the_toothpaste_grasp():
    """hoi_toothpaste's grasp with self-collision and every tet edge stretch-only (skin and flesh), 36
    frames (CPU): over the last six frames the skin edges through another skin triangle are 3 or
    fewer in the median frame and the vertices' 0.2 mm offsets inside the skin 3 or fewer in every
    frame, the object out of the skin by both of its measures. The count swings from frame to frame:
    over frames 25-36 crossing edges 0-15 (median 2), offsets inside 0-3; with the paper's two-sided
    edges 8-37 and 3-10, with stretch-only skin alone 0-16 and 0-5 (measured 2026-12-01; at Eq. 9's
    former 4 um offset 0-6 / 0-3, 15-53 / 4-12, 0-15 / 0-2)."""
    per, p = _grasp("hoi_toothpaste", last=6, skin_compression=False, flesh_compression=False)
    assert np.median([m["crossing_edges"] for m in per]) <= 3, per
    assert max(m["inside_200um"] for m in per) <= 3, per
    assert p["penetration_count"] == 0 and p["object_in_skin_count"] == 0, p
