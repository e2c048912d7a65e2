"""Skin self-collision in batched worlds (Config.self_collision with BatchedHands; solver/self_contact.py,
docs/self_collision.md "Batched worlds"): each world equals one hand run alone, and a vertex pairs
only with its own world's triangles however the worlds overlap (every batched world lies at the origin)."""

import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.rotations import nlerp
from physhand_mj.batch import BatchedHands
from physhand_mj.contact.self_measures import self_penetration
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config

RAMP, HOLD = 6, 4  # frames from the rest pose to the keyframe's bones, then held


@pytest.fixture(scope="module")
def setup():
    asset, model, data = open_hand_scene("hand_only", "open")
    return asset, model, data, body_ids(model, asset.body_names), mount_pose(model, data)


def _schedule(setup, keys):
    """Per frame, per world: bone poses moving from the open hand to keyframe ``keys[w]`` in RAMP frames."""
    asset, model, data, ids, _ = setup
    start = bone_poses_at(model, data, model.key("open").qpos.copy(), ids)
    ends = [bone_poses_at(model, data, model.key(k).qpos.copy(), ids) for k in keys]
    frames = []
    for f in range(RAMP + HOLD):
        a = min((f + 1) / RAMP, 1.0)
        frames.append([(start[0] * (1 - a) + e[0] * a, nlerp(start[1], e[1], a)) for e in ends])
    return frames


def _serial(setup, cfg, key, frames, w):
    """One hand alone through world ``w``'s poses: its positions, per-frame pair counts, the skin measure."""
    asset, *_, mount = setup
    s = Solver(make_model(asset, cfg), cfg)
    st = s.make_state(*mount)
    pairs = []
    for poses in frames:
        s.set_body_poses(st, *poses[w])
        out = s.step(st)
        pairs.append((out["self_vertices"], out["self_pairs"], out["self_corrections"]))
    return st.x.numpy(), np.array(pairs)


def _batched(setup, cfg, keys):
    asset, *_, mount = setup
    frames = _schedule(setup, keys)
    batch = BatchedHands(asset, len(keys), cfg, *mount)
    pairs = []
    for poses in frames:
        out = batch.step(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]))
        assert out["nonfinite"] == 0
        rows = out["worlds"]
        pairs.append([(r["self_vertices"], r["self_pairs"], r["self_corrections"]) for r in rows])
        # the frame's sums are the worlds'
        assert out["self_pairs"] == sum(r["self_pairs"] for r in rows)
    return batch, frames, np.array(pairs)


def _no_cross_pairs(batch):
    """Every listed pair names a triangle of the vertex's own world."""
    sc = batch.solver.selfc
    n = int(sc.counts.numpy()[0])
    v = sc.vlist.numpy()[:n]
    cand, cn = sc.cand.numpy()[v], sc.cand_n.numpy()[v]
    tri = np.concatenate([cand[k, : cn[k]] for k in range(n)]) if n else np.zeros(0, int)
    own = np.repeat(v // sc.ns1, cn)
    assert np.array_equal(tri // sc.nf1, own)
    return n


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
@pytest.mark.parametrize("keys", [("open", "pinch", "power")], ids=["open-pinch-power"])
def test_batched_worlds_equal_one_hand_each(setup, keys):
    """Three worlds closing to open, pinch and power at once equal three hands run alone with the
    option: positions within 1e-7 m (measured: bit for bit on the CPU; one BVH grouped by world walks
    each world's subtree as one hand's BVH is walked, and equal distances are ordered by triangle),
    the same listed vertices, pairs and corrections every frame, the same self-penetration measure
    per world."""
    asset = setup[0]
    cfg = Config(device="cpu", self_collision=True)
    batch, frames, bp = _batched(setup, cfg, keys)
    assert bp[-1, 2, 1] > 0 and bp[-1, 0, 1] == 0  # power listed pairs, the open hand none
    assert _no_cross_pairs(batch) > 0
    faces = np.asarray(asset.skin_faces)
    for w, key in enumerate(keys):
        x, sp = _serial(setup, cfg, key, frames, w)
        np.testing.assert_array_equal(bp[:, w], sp, err_msg=key)
        assert np.abs(batch.positions(w) - x).max() <= 1e-7, key  # (measured: 0, bit for bit)
        assert self_penetration(batch.skin(w), faces) == self_penetration(x[: asset.n_skin], faces), key


def test_overlapping_worlds_never_pair_across(setup):
    """Two worlds at the same pose lie on top of each other (every skin vertex on the other world's
    skin): neither lists a triangle of the other, and each ends as one hand alone."""
    asset = setup[0]
    cfg = Config(device="cpu", self_collision=True)
    batch, frames, bp = _batched(setup, cfg, ("pinch", "pinch"))
    assert _no_cross_pairs(batch) > 0
    x, sp = _serial(setup, cfg, "pinch", frames, 0)
    for w in range(2):
        np.testing.assert_array_equal(bp[:, w], sp)
        assert np.abs(batch.positions(w) - x).max() <= 1e-7


@pytest.mark.parametrize("options", [
    # Tuning.self_tet_keep: the tet guard walks each world's own tets (one world's lists shifted by its offsets)
    dict(tuning=ph.Tuning(self_tet_keep=0.02)),
    # Tuning.self_friction: the fused substep's passes read each world's x_prev
    dict(tuning=ph.Tuning(self_friction=0.5)),
    # Config.skin_compression False: each world's skin edges stretch-only, their rest lengths tiled with their sign
    dict(skin_compression=False),
    # Tuning.self_edges: the edge pairs from each world's own edges (the edges' BVH grouped by world)
    dict(tuning=ph.Tuning(self_edges=True)),
    # Tuning.self_every: one list for two frames, the batch's frame count as the hand's
    dict(tuning=ph.Tuning(self_every=2)),
], ids=["tet_keep", "friction", "stretch_only_skin", "edges", "every2"])
def test_batched_options_equal_one_hand(setup, options):
    """Each self-collision option in batched worlds: world 1 (power) ends as the hand alone, with the
    same pairs every frame; and the option changes that hand (it is not a no-op)."""
    cfg = Config(device="cpu", self_collision=True, **options)
    batch, frames, bp = _batched(setup, cfg, ("pinch", "power"))
    x, sp = _serial(setup, cfg, "power", frames, 1)
    np.testing.assert_array_equal(bp[:, 1], sp)
    assert np.abs(batch.positions(1) - x).max() <= 1e-7
    assert not np.array_equal(x, _serial(setup, Config(device="cpu", self_collision=True), "power", frames, 1)[0])
