"""Sleeping (physhand_mj/solver/sleep.py, physhand_mj/solver/regions.py): a still hand with no object near
rides its bones from its last solved shape and wakes without a visible jump when a bone moves or an
object approaches; regions of the hand sleep alone (docs/activity.md)."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from activity_helpers import FAR, R, _solver, _step, scene  # noqa: F401 (scene: a fixture)
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, open_hand_scene
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config


def _until_asleep(solver, state, poses, limit=500):
    for k in range(limit):
        out = _step(solver, state, poses)
        if out["asleep"]:
            return k, out
    raise AssertionError(f"the still hand did not fall asleep in {limit} frames")


def _moved(poses, rot, shift, about):
    """Bone poses (pos (B, 3), quat (B, 4) w x y z) moved as one rigid body: rotated by ``rot``
    (3 x 3) about ``about`` and shifted by ``shift`` (m)."""
    from physhand_mj.rotations import quat_to_mat

    pos, quat = poses
    mats = quat_to_mat(quat)
    new_pos = (pos - about) @ rot.T + about + shift
    new = rot @ mats
    w = np.sqrt(np.maximum(1.0 + np.trace(new, axis1=1, axis2=2), 1e-12)) / 2.0
    q = np.stack([w, (new[:, 2, 1] - new[:, 1, 2]) / (4 * w), (new[:, 0, 2] - new[:, 2, 0]) / (4 * w),
                  (new[:, 1, 0] - new[:, 0, 1]) / (4 * w)], axis=1)
    return new_pos, q


@pytest.mark.parametrize("ahead, device", [
    (False, "cpu"), pytest.param(True, "cpu", marks=pytest.mark.slow),
    pytest.param(True, "cuda", marks=pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device"))],
    ids=["cpu-gates", "cuda-gates", "cuda"])
def test_a_still_hand_sleeps_rides_its_bones_and_wakes_for_an_object(scene, ahead, device):
    """Also along CUDA's path (the broadphase run ahead decides 'no object near'), forced on the CPU,
    and on a CUDA device (the sleeping frame a captured graph)."""
    solver, state, objects, top = _solver(scene, device=device)
    solver.activity.gate_ahead = ahead  # before the first frame records
    poses = scene[2]
    k, out = _until_asleep(solver, state, poses)
    assert out["ops_run"] <= 6 + 2 * ahead and out["contact_ops_run"] == 2 * ahead
    assert out["penetration_count"] == 0
    x0 = state.x.numpy().astype(np.float64)
    # the whole hand turned rigidly (1 degree about its first bone's origin: under the 2 degrees
    # that wake it, and that bone does not start moving) stays asleep and its skin is the sleeping
    # shape moved by that transform (a sudden shift would wake it: its first bone's velocity changes)
    c, s = np.cos(np.radians(1.0)), np.sin(np.radians(1.0))
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    about, shift = poses[0][0], np.zeros(3)
    out = _step(solver, state, _moved(poses, rot, shift, about))
    assert out["asleep"]
    # asleep on CUDA's path, the host decides 'no object near' from the sleeping skin's per-bone boxes:
    # no broadphase runs ahead (no contact op at all)
    assert out["contact_ops_run"] == 0 and out["ops_run"] <= 6 and out["objects_near"] == 0
    want = (x0 - about) @ rot.T + about + shift
    assert np.abs(state.x.numpy() - want).max() < 2e-6
    # ... moving with its bones' velocity over the frame
    assert np.abs(state.v.numpy() - (want - x0) / solver.config.frame_dt).max() < 2e-6 / solver.config.frame_dt
    # held there, still asleep (CUDA's path: the host test cached while nothing moved), the skin unmoved
    out = _step(solver, state, _moved(poses, rot, shift, about))
    assert out["asleep"] and out["contact_ops_run"] == 0 and out["objects_near"] == 0
    assert np.abs(state.x.numpy() - want).max() < 2e-6
    # an object coming within the frame margin wakes it: the contact runs
    objects.set_pose(0, want[np.argmax(want[: solver.model.n_skin, 2])] + [0.0, 0.0, R - 0.001],
                     (1.0, 0.0, 0.0, 0.0))
    out = _step(solver, state, _moved(poses, rot, shift, about))
    assert not out["asleep"] and out["contact_ops_run"] > 0 and out["triangles_tested"] > 0


@pytest.mark.slow  # 2 x 330 frames: carried, it first sleeps at frame ~262
def test_a_woken_hand_matches_an_always_awake_run(scene):
    """Carried at a steady 5 cm/s it falls asleep (settled relative to its bones), then a finger
    bends: the skin stays within 0.1 mm of a run that never slept (it wakes moving with its bones)."""
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    qpos = model.key("open").qpos.copy()
    joint = next(j for j in range(model.njnt) if model.joint(j).name == "mcp2_flexion_r")
    speed = np.array([0.05, 0.0, 0.0]) * Config().frame_dt  # m per frame
    carried = lambda poses, k: (poses[0] + speed * k, poses[1])  # noqa: E731
    runs = []
    for sleep in (Config().sleep_speed, 0.0):
        cfg = Config(device="cpu", sleep_speed=sleep)
        solver = Solver(make_model(asset, cfg), cfg)
        state = solver.make_state(*scene[1])
        asleep = [_step(solver, state, carried(scene[2], k))["asleep"] for k in range(300)]
        still = state.x.numpy().copy()
        woke = []
        for k in range(30):  # bend the index finger's MCP by 0.004 rad per frame
            q = qpos.copy()
            q[model.jnt_qposadr[joint]] += 0.004 * (k + 1)
            woke.append(_step(solver, state, carried(bone_poses_at(model, data, q, ids), 300 + k))["asleep"])
        runs.append((asleep, still, woke, state.x.numpy().copy()))
    (asleep, still_a, woke, bent_a), (never, still_b, _, bent_b) = runs
    assert any(asleep) and not any(never) and not any(woke)
    assert np.abs(still_a - still_b).max() < 1e-4
    assert np.abs(bent_a - bent_b).max() < 1e-4


@pytest.mark.slow  # falls asleep twice, turns and creeps: ~20 s on a 2-core CPU
def test_a_sleeping_hand_wakes_when_gravity_turns_in_it_or_a_finger_creeps(scene):
    """Per-frame tests alone would miss slow changes: the hand turning as one body (gravity turns
    in it: woken before 2 degrees) and a finger bending below the per-frame tolerance (woken once
    it has moved 10 um relative to the others since falling asleep)."""
    solver, state, _, _ = _solver(scene)
    poses = scene[2]
    _until_asleep(solver, state, poses)
    about = poses[0][0]
    for k in range(1, 40):  # 0.1 degree per frame about the vertical through the first bone
        c, s = np.cos(np.radians(0.1 * k)), np.sin(np.radians(0.1 * k))
        out = _step(solver, state, _moved(poses, np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
                                           np.zeros(3), about))
        if not out["asleep"]:
            break
    assert not out["asleep"] and 0.1 * k <= 2.1, f"still asleep after turning {0.1 * k:.1f} degrees"
    turned = _moved(poses, np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3), about)
    _until_asleep(solver, state, turned, limit=400)
    # a finger creeping 2 um per frame at its tip stays under the per-frame tolerance (10 um)
    pos, quat = turned
    tip = solver.model.body_names.index("distph2_r") if "distph2_r" in solver.model.body_names else len(pos) - 1
    for k in range(1, 30):
        p = pos.copy()
        p[tip] = p[tip] + np.array([0.0, 0.0, 2e-6]) * k
        out = _step(solver, state, (p, quat))
        if not out["asleep"]:
            break
    assert not out["asleep"] and k * 2e-6 <= 12e-6, f"still asleep after the tip crept {k * 2} um"


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not wp.is_cuda_available(), reason="no CUDA device"))])
def test_regions_sleep_alone_ride_their_bones_and_wake_to_match_an_awake_run(scene, device):
    """Config.region_sleep (physhand_mj/solver/regions.py), gravity off so the open hand is settled at once:
    every region falls asleep; the index then bends and wakes itself and its neighbours (middle
    finger, palm) while the thumb, ring and little fingers sleep on, riding their still bones (their
    skin does not move by a bit while the awake flesh next to it does); then the ring and little
    fingers bend and wake. Throughout, the skin stays within 0.1 mm of a run in which nothing ever
    sleeps."""
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    qpos = model.key("open").qpos.copy()
    adr = {k: model.jnt_qposadr[model.joint(f"mcp{k}_flexion_r").id] for k in (2, 4, 5)}
    def poses(k):
        q = qpos.copy()
        q[adr[2]] += 0.004 * min(max(k - 20, 0), 30)  # the index bends in frames 21-50
        for j in (4, 5):
            q[adr[j]] += 0.004 * min(max(k - 50, 0), 20)  # ring and little in frames 51-70
        return bone_poses_at(model, data, q, ids)

    runs = []
    for regions in (True, False):
        cfg = Config(device=device, gravity=(0.0, 0.0, 0.0), region_sleep=regions, sleep_speed=3e-3 if regions else 0.0)
        solver = Solver(make_model(asset, cfg), cfg)
        state = solver.make_state(*scene[1])
        asleep, xs = [], []
        for k in range(72):
            out = _step(solver, state, poses(k))
            asleep.append(set(out.get("regions_asleep", [])))
            xs.append(state.x.numpy().astype(float).copy())
        runs.append((solver, asleep, xs))
    (solver, asleep, xa), (_, never, xb) = runs
    assert asleep[19] == {"palm", "thumb", "index", "middle", "ring", "little"}, asleep[19]
    assert all(a == {"thumb", "ring", "little"} for a in asleep[22:50]), asleep[22:50]
    assert asleep[71] == {"thumb"}, asleep[71]
    assert not any(never)
    # the sleeping ring finger's soft vertices rode their still bones: not moved by a bit, while the
    # awake middle finger's (its neighbour) did move
    region = solver.regions.vertex_region.numpy()
    ring, middle = np.flatnonzero(region == 4), np.flatnonzero(region == 3)
    assert len(ring) > 300 and np.array_equal(xa[49][ring], xa[21][ring])
    assert np.abs(xa[49][middle] - xa[21][middle]).max() > 1e-7
    for k in (19, 49, 71):  # all asleep; the index bent with three regions asleep; all awake but the thumb
        d = np.linalg.norm(xa[k] - xb[k], axis=1)
        assert d.max() < 1e-4, (k, d.max())


def test_region_sleep_is_refused_unless_a_bool():
    with pytest.raises(ValueError, match="region_sleep"):
        Config(region_sleep="yes").validate()


def test_a_region_near_an_object_stays_awake(scene):
    """Config.region_sleep: with a sphere 5 mm from the little finger's skin (within
    contact_frame_margin, not touching) the little finger never sleeps while the regions far from it do;
    moved away, the sphere lets it fall asleep too."""
    solver, state, objects, _ = _solver(scene, gravity=(0.0, 0.0, 0.0), region_sleep=True)
    rs = solver.regions
    x = state.x.numpy().astype(float)
    little = np.flatnonzero(rs.vertex_region.numpy() == 5)
    centre = x[: solver.model.n_skin].mean(axis=0)
    tip = little[np.argmax(np.linalg.norm(x[little] - centre, axis=1))]
    out_dir = (x[tip] - centre) / np.linalg.norm(x[tip] - centre)
    objects.set_poses((x[tip] + out_dir * (R + 0.005))[None], np.array([[1.0, 0.0, 0.0, 0.0]]))
    asleep = [set(_step(solver, state, scene[2])["regions_asleep"]) for _ in range(25)]
    # (the ring finger, 4-5 mm beside the little one, may be within the margin of the sphere too)
    assert {"palm", "thumb", "index", "middle"} <= asleep[-1] and "little" not in asleep[-1], asleep[-1]
    objects.set_poses(np.array([FAR]), np.array([[1.0, 0.0, 0.0, 0.0]]))
    # the index bends meanwhile, so the hand as a whole stays awake and the little finger must fall
    # asleep on its own (a whole-hand sleep would report every region asleep)
    _, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, ph.load_asset().body_names)
    q = model.key("open").qpos.copy()
    adr = model.jnt_qposadr[model.joint("mcp2_flexion_r").id]
    for k in range(15):
        q[adr] += 0.004
        out = _step(solver, state, bone_poses_at(model, data, q, ids))
        assert not out["asleep"]
    assert rs.asleep[5] and "little" in out["regions_asleep"], out["regions_asleep"]
    assert not rs.asleep[2]  # the bending index itself is awake


def test_a_region_wakes_when_a_neighbour_creeps(scene):
    """Config.region_sleep: the middle finger bending slower than Config.tuning.sleep_bone_motion per frame
    (5e-5 rad a frame at its MCP: ~9 um at the fingertip) still wakes its neighbours (index, ring,
    palm) within a few frames: their motion since they fell asleep counts the neighbour's bones too,
    not only the per-frame step (found in review: they stayed frozen against it, 0.4-0.6 mm off
    after 1,500 frames)."""
    solver, state, _, _ = _solver(scene, gravity=(0.0, 0.0, 0.0), region_sleep=True)
    rs = solver.regions
    _, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, ph.load_asset().body_names)
    q = model.key("open").qpos.copy()
    adr = model.jnt_qposadr[model.joint("mcp3_flexion_r").id]
    for _ in range(12):
        _step(solver, state, scene[2])
    assert rs.asleep.all()
    for k in range(8):
        q[adr] += 5e-5
        poses = bone_poses_at(model, data, q, ids)
        _step(solver, state, poses)
    from physhand_mj.solver.sleep import bone_motions

    assert bone_motions(*[np.concatenate([p, r[:, [1, 2, 3, 0]]], axis=1) for p, r in (scene[2], poses)]).max() > 1e-5
    assert not rs.asleep[2] and not rs.asleep[4] and not rs.asleep[0], rs.asleep
    assert rs.asleep[1]  # the thumb, no neighbour of the middle finger, sleeps on
