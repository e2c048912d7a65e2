"""BatchedHands.submit / wait (physhand_mj/batch.py): a frame queued while the host checks the next
frame's poses and builds the last frame's per-world rows runs the frames ``step`` runs, with the
same reports one call later; reading the batch mid-pipeline waits for the frame in flight."""

import numpy as np
import pytest
import warp as wp

from physhand_mj.config import Tuning
import physhand_mj as ph
from physhand_mj.batch import BatchedHands
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
from physhand_mj.types import Config, GeomType

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device"))]


@pytest.fixture(scope="module")
def setup():
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    return asset, model, data, body_ids(model, asset.body_names), mount_pose(model, data)


def _pressed_batch(setup, device):
    """Two worlds with a 1 mm sphere each: world 1's inside a skin triangle of the back of the hand,
    where the vertex strategy's decision points (corners, edge midpoints) do not see it, so its
    depth shows in every frame's measure; world 0's 5 cm clear. Returns the batch, the spheres'
    places (2, 1, 3) m and the triangle's outward normal."""
    asset = setup[0]
    batch = BatchedHands(asset, 2, Config(device=device, contact="vertex"), *setup[4],
                         objects=[dict(gtype=GeomType.SPHERE, size=(0.001, 0, 0), name="ball")])
    skin = batch.skin(1)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    x = skin[asset.skin_faces].astype(float)
    t = np.argmin(np.linalg.norm(x.mean(axis=1) - top, axis=1))
    n = np.cross(x[t, 1] - x[t, 0], x[t, 2] - x[t, 0])
    n /= np.linalg.norm(n)
    return batch, np.stack([top + [0.0, 0.1, 0.05], x[t].mean(axis=0) - 5e-4 * n])[:, None], n


def _frames(setup, frames: int, n):
    """Per frame the bones of both worlds (the open pose) and how far world 1's sphere moves
    (0.05 mm a frame deeper along -n)."""
    asset, model, data, ids, mount = setup
    pos, quat = bone_poses_at(model, data, model.key("open").qpos, ids)
    return [(np.stack([pos, pos]), np.stack([quat, quat]), -5e-5 * (k + 1) * n) for k in range(frames)]


def _moved(where, shift):
    """The spheres' places with world 1's moved by ``shift`` (m)."""
    return where + np.stack([np.zeros(3), shift])[:, None]


def _strip(report: dict) -> dict:
    return {k: v for k, v in report.items() if k != "worlds"}


@pytest.mark.parametrize("device", DEVICES)
def test_submitted_frames_are_the_frames_step_runs(setup, device):
    """Five frames of a pressed world and a free one, by ``step`` and by ``submit``: the same skins
    (CPU: bit for bit; CUDA: the contact's float atomics add in no fixed order) and the same reports,
    each returned by the next call; ``wait`` returns the last, then None."""
    a, where, n = _pressed_batch(setup, device)
    b, _, _ = _pressed_batch(setup, device)
    frames = _frames(setup, 5, n)
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
    by_step, by_submit = [], []
    for pos, quat, shift in frames:
        by_step.append(a.step(pos, quat, _moved(where, shift), ident))
    for pos, quat, shift in frames:
        by_submit.append(b.submit(pos, quat, _moved(where, shift), ident))
    assert by_submit[0] is None
    by_submit = by_submit[1:] + [b.wait()]
    assert b.wait() is None
    depth = [r["worlds"][1]["penetration_max_um"] for r in by_step]
    assert all(r["triangles_tested"] > 0 for r in by_step)  # (world 1's sphere is near: the contact runs)
    assert len(set(depth)) == len(depth) and min(depth) > 100, depth  # (each frame's rows differ)
    if device == "cpu":
        assert np.array_equal(a.skins(), b.skins())
        assert [_strip(r) for r in by_step] == [_strip(r) for r in by_submit]
        assert [r["worlds"] for r in by_step] == [r["worlds"] for r in by_submit]
    else:  # (each frame's rows differ by ~50 um: a report one frame off would be far outside 5 um)
        np.testing.assert_allclose(a.skins(), b.skins(), atol=2e-5)
        assert [sorted(r) for r in by_step] == [sorted(r) for r in by_submit]
        assert [[w["nonfinite"] for w in r["worlds"]] for r in by_step] == \
            [[w["nonfinite"] for w in r["worlds"]] for r in by_submit]
        np.testing.assert_allclose([r["worlds"][1]["penetration_max_um"] for r in by_submit], depth, atol=5.0)
    assert b.last_worlds == by_submit[-1]["worlds"]


def test_reading_mid_pipeline_waits_and_keeps_the_report(setup):
    """``penetration()`` between two submits measures the frame in flight after it ends (the skin
    ``step`` gives), and that frame's report comes with the next submit; ``step`` with a report
    not yet read says to wait first."""
    a, where, n = _pressed_batch(setup, "cpu")
    b, _, _ = _pressed_batch(setup, "cpu")
    frames = _frames(setup, 3, n)
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
    (p0, q0, s0), (p1, q1, s1), (p2, q2, s2) = frames
    r0 = a.step(p0, q0, _moved(where, s0), ident)
    r1 = a.step(p1, q1, _moved(where, s1), ident)
    assert b.submit(p0, q0, _moved(where, s0), ident) is None
    got0 = b.submit(p1, q1, _moved(where, s1), ident)
    assert b.penetration() == a.penetration()  # frame 1 ended first
    with pytest.raises(RuntimeError, match="wait"):
        b.step(p2, q2, _moved(where, s2), ident)
    got1 = b.submit(p2, q2, _moved(where, s2), ident)  # frame 1's report, kept through the reading
    assert _strip(got0) == _strip(r0) and _strip(got1) == _strip(r1)
    assert got1["worlds"] == r1["worlds"]
    r2 = a.step(p2, q2, _moved(where, s2), ident)
    assert np.array_equal(a.skins(), b.skins())
    assert _strip(b.wait()) == _strip(r2)
    b.submit(p0, q0, _moved(where, s0), ident)
    with pytest.raises(RuntimeError, match="in flight"):  # (the frame in flight still reads its end poses)
        b.solver.set_body_poses(b.state, p0.reshape(-1, 3), q0.reshape(-1, 4))
    b.wait()
    b.close()  # (nothing in flight)
    c, _, _ = _pressed_batch(setup, "cpu")
    c.submit(p0, q0, _moved(where, s0), ident)
    c.close()  # a frame in flight ends before the arrays go
    with pytest.raises(RuntimeError, match="closed"):
        c.wait()


def test_a_pipelined_batch_falls_asleep_and_wakes_when_step_does(setup):
    """No objects, the bones held, then moved: the frames ``submit`` runs sleep and wake at the
    frames ``step``'s do (the sleep test reads the frame before's outcome, which ``submit`` finishes
    before it decides the next), and the skins stay bit for bit."""
    asset, model, data, ids, mount = setup
    pos, quat = bone_poses_at(model, data, model.key("open").qpos, ids)
    pos, quat = np.stack([pos] * 2), np.stack([quat] * 2)
    moved = pos.copy()
    moved[1, 5:] += [0.0, 0.0, 2e-3]  # world 1's later bones 2 mm up: the hand must wake
    plan = [(pos, quat)] * 75 + [(moved, quat)] * 2  # (asleep from frame ~70 with these settings)
    cfg = Config(device="cpu", sleep_speed=0.02, tuning=Tuning(sleep_frames=3))
    a = BatchedHands(asset, 2, cfg, *mount)
    b = BatchedHands(asset, 2, cfg, *mount)
    by_step = [a.step(p, q)["asleep"] for p, q in plan]
    by_submit = [r["asleep"] for r in [b.submit(p, q) for p, q in plan][1:] + [b.wait()]]
    assert any(by_step) and not by_step[-1], by_step  # (it slept, then woke)
    assert by_submit == by_step
    assert np.array_equal(a.skins(), b.skins())


@pytest.mark.parametrize("device", DEVICES)
def test_poses_staged_during_a_frame_are_the_next_frames(setup, device):
    """``submit`` fills the next frame's pose upload buffer while the frame before runs
    (``Solver.stage_pose_rows``). Two worlds bending a finger by a different amount every frame, by
    ``step`` and by ``submit``: the same bone poses on the device after each frame, and the same skins
    (CPU bit for bit; CUDA within 1 um). A stale buffer (the frame before's poses) would lag a frame."""
    asset, model, data, ids, mount = setup
    q0 = model.key("open").qpos.copy()
    jnt = model.jnt_qposadr[model.joint("mcp2_flexion_r").id]

    def poses(k):
        out = []
        for w in range(2):
            q = q0.copy()
            q[jnt] += 0.08 * (k + 1) * (w + 1)
            out.append(bone_poses_at(model, data, q, ids))
        return np.stack([p[0] for p in out]), np.stack([p[1] for p in out])

    frames = [poses(k) for k in range(4)]
    a = BatchedHands(asset, 2, Config(device=device), *mount)
    b = BatchedHands(asset, 2, Config(device=device), *mount)
    by_step = [a.step(pos, quat) for pos, quat in frames]
    by_submit = [b.submit(pos, quat) for pos, quat in frames][1:] + [b.wait()]
    end = a.state.body_pose.numpy()
    assert np.array_equal(b.state.body_pose.numpy(), end)
    assert not np.array_equal(end[0], end[1])  # (the bones moved in the last frame)
    assert [r["nonfinite"] for r in by_step] == [r["nonfinite"] for r in by_submit] == [0] * 4
    if device == "cpu":
        assert np.array_equal(a.skins(), b.skins())
    else:
        np.testing.assert_allclose(a.skins(), b.skins(), atol=1e-6)


def test_a_staged_upload_is_taken_only_with_the_rows_it_was_staged_with(setup):
    """``Solver.launch(state, staged=token)`` uploads the staged buffer only where
    ``set_body_pose_rows`` was given the rows it was staged with and the token is the last one
    staged: set other rows instead, or stage again, and the frame still moves the bones to the rows
    set (the buffer is filled again from the state); with a valid token the staged buffer itself
    goes up (a mark written into it after staging arrives)."""
    asset, model, data, ids, mount = setup
    hands = BatchedHands(asset, 1, Config(device="cpu"), *mount)
    solver, state = hands.solver, hands.state
    q = model.key("open").qpos.copy()
    pos, quat = bone_poses_at(model, data, q, ids)
    rows_a = solver.pose_rows(pos + hands.offsets[0], quat)
    q[model.jnt_qposadr[model.joint("mcp2_flexion_r").id]] += 0.3
    pos_b, quat_b = bone_poses_at(model, data, q, ids)
    rows_b = solver.pose_rows(pos_b + hands.offsets[0], quat_b)
    assert solver.stage_pose_rows(state, rows_a) is None  # (no frame in flight: nothing to stage)

    def pair(rows, stage, then):
        """A frame set to ``rows``; while it runs ``stage()`` stages and returns a token; the next
        frame set to ``then`` and launched with that token. Returns the token and the uploaded
        [start, end] rows of the second frame."""
        solver.set_body_pose_rows(state, rows)
        solver.launch(state)
        token = stage()
        solver.finish(state)
        solver.set_body_pose_rows(state, then)
        solver.launch(state, staged=token)
        solver.finish(state)
        return token, state.body_pose.numpy()

    token, up = pair(rows_a, lambda: solver.stage_pose_rows(state, rows_a), rows_b)  # not the staged rows
    assert token is not None and np.array_equal(up[1], rows_b)
    _, up = pair(rows_a, lambda: solver.stage_pose_rows(state, rows_b), rows_b)  # the staged rows
    assert np.array_equal(up[0], rows_a) and np.array_equal(up[1], rows_b)  # (the buffer as staged)
    # the staged buffer is what goes up (a mark written into it after staging arrives; refilling would lose it)
    mark = rows_b.copy()
    mark[0, 0] += 0.25

    def marked():
        token = solver.stage_pose_rows(state, rows_b)
        solver.poses.pins[token[1]].numpy()[1] = mark
        return token

    _, up = pair(rows_a, marked, rows_b)
    assert np.array_equal(up[1], mark)

    # only the last token staged counts: staging again (other rows) voids the first
    def twice():
        first = solver.stage_pose_rows(state, rows_b)
        solver.stage_pose_rows(state, rows_a)
        return first

    _, up = pair(rows_a, twice, rows_b)
    assert np.array_equal(up[1], rows_b)


def test_a_launch_given_its_staged_rows_sets_them_after_queueing(setup):
    """``Solver.launch(state, staged=token, rows=rows)`` (what ``submit`` does) sets the frame's end
    poses as ``set_body_pose_rows`` then ``launch`` would, with the host copy of the rows made after the
    frame is queued where the token holds these very rows (``PoseInput.set_rows_late``): the same
    uploaded poses, host rows and skins as the two calls; a token for other rows is declined and the
    rows set as usual."""
    asset, model, data, ids, mount = setup
    q = model.key("open").qpos.copy()
    adr = model.jnt_qposadr[model.joint("mcp2_flexion_r").id]
    both = [BatchedHands(asset, 1, Config(device="cpu"), *mount) for _ in range(2)]

    def rows_at(hands, angle):
        q[adr] = angle
        pos, quat = bone_poses_at(model, data, q, ids)
        return hands.solver.pose_rows(pos + hands.offsets[0], quat)

    for late, hands in zip((False, True), both):
        solver, state = hands.solver, hands.state
        rows_a, rows_b, rows_c = (rows_at(hands, a) for a in (0.1, 0.4, 0.7))
        solver.set_body_pose_rows(state, rows_a)
        solver.launch(state)
        token = solver.stage_pose_rows(state, rows_b)
        solver.finish(state)
        if late:
            assert solver.poses.set_rows_late(state, rows_c, token, None) is False  # (staged for other rows)
            assert solver.poses.set_rows_late(state, rows_b, token, None) is True
            solver.launch(state, staged=token, rows=rows_b)
        else:
            solver.set_body_pose_rows(state, rows_b)
            solver.launch(state, staged=token)
        assert np.array_equal(state.pose_host[0], rows_b) and np.array_equal(state.pose_host[1], rows_b)
        solver.finish(state)
        up = state.body_pose.numpy()
        assert np.array_equal(up[0], rows_a) and np.array_equal(up[1], rows_b)
        # a token for other rows: declined, the rows set before the launch (the frame still ends at them)
        token = solver.stage_pose_rows(state, rows_b) if solver.launch(state) is None else None
        solver.finish(state)
        solver.launch(state, staged=token, rows=rows_c)
        solver.finish(state)
        assert np.array_equal(state.body_pose.numpy()[1], rows_c) and np.array_equal(state.pose_host[1], rows_c)
    assert np.array_equal(both[0].skins(), both[1].skins())


def test_a_pipelined_batch_warns_of_a_fast_bone_as_step_does(setup):
    """The fast-motion check (a bone moving farther in a frame than Config.contact_frame_margin -
    contact_margin) is taken when ``submit`` stages the poses: a batch whose hands jump 3 cm in one
    frame warns once, naming the same distance by ``step`` and by ``submit``."""
    asset, model, data, ids, mount = setup
    pos, quat = bone_poses_at(model, data, model.key("open").qpos, ids)
    frames = [(np.stack([pos, pos]), np.stack([quat, quat]))] * 2
    frames.append((np.stack([pos, pos + [0.0, 0.0, 0.03]]), np.stack([quat, quat])))
    said = []
    for mode in ("step", "submit"):
        batch, where, _ = _pressed_batch(setup, "cpu")
        with pytest.warns(RuntimeWarning, match="contact_frame_margin") as rec:
            ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
            for p, q in frames:
                getattr(batch, mode)(p, q, where, ident)
            if mode == "submit":
                batch.wait()
        said.append([str(w.message) for w in rec if "contact_frame_margin" in str(w.message)])
        # (physhand_mj.warn.warn_user: the warning names this file's line, not the package's)
        assert {w.filename for w in rec if "contact_frame_margin" in str(w.message)} == {__file__}, mode
    assert len(said[0]) == 1 and said[0] == said[1] and "moved 30.0 mm" in said[0][0], said
