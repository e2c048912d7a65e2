"""Config.self_collision's substep passes inside the fused substep kernel (solver/fused_self.py): the
same positions as self_contact.py's launches (bit for bit on the CPU: one lane, the listed vertices
in order, the same float sums), the same lists, the same independent measure, and a frame without
objects one frame launch again (docs/self_collision.md "How it runs")."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.config import Execution
from physhand_mj.contact.self_measures import self_penetration
from physhand_mj.solver import fused

FIELDS = ("x", "x_prev", "v", "lam_edge", "lam_tet", "lam_dih")


def _run(key: str, frames: int, fused_substep=None, self_collision: bool = True, friction: float = 0.0):
    """``hand_only``'s keyframe ``key`` rolled out as ``physhand rollout`` does (SoftHand, MuJoCo
    stepping its targets), ``frames`` frames on the CPU (``friction``: Tuning.self_friction); the hand,
    the last report, each frame's pairs."""
    import mujoco

    from physhand_mj.rollout import load_rollout_scene

    model, data, _ = load_rollout_scene(ph.scene_path("hand_only"), key)
    cfg = ph.Config(frame_dt=float(model.opt.timestep), device="cpu", self_collision=self_collision,
                    execution=Execution(fused_substep=fused_substep), tuning=ph.Tuning(self_friction=friction))
    hand = ph.SoftHand(model, data, cfg, settle_contact=False)
    res, pairs = {}, []
    for _ in range(frames):
        mujoco.mj_step(model, data)
        res = hand.step()
        pairs.append(res.get("self_pairs"))
    return hand, res, pairs


def _same_state(a, b) -> None:
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a.state, name).numpy(), getattr(b.state, name).numpy(), err_msg=name)


@pytest.mark.parametrize("key", ["pinch", "power"])
def test_fused_self_passes_equal_the_launches(key, monkeypatch):
    """The CPU's default (the fused substep) runs the passes inside the kernel: bit for bit the
    non-fused solver's (fused_substep=False: the five-launch substep and self_contact's launches) and
    the fused kernel followed by self_contact's launches (fused.SELF_IN_KERNEL False), with the same
    pairs every frame; the frame is one frame launch plus the self-contact query's once-a-frame ops:
    2 x self_passes x substeps launches, the last advance and the inverted-tet count fewer than the
    fused kernel with the launches after it (pinch / power: 28 ops against 108; non-fused 168)."""
    frames = 4
    fz, res, pairs = _run(key, frames)
    assert fz.solver.fused_substep and fz.solver._self_fused  # (the CPU default takes the fused self path)
    assert min(pairs) > 0 and res["self_corrections"] > 0
    ref, ref_res, ref_pairs = _run(key, frames, fused_substep=False)
    assert not ref.solver.fused_substep
    monkeypatch.setattr(fused, "SELF_IN_KERNEL", False)
    out, out_res, out_pairs = _run(key, frames)
    assert out.solver.fused_substep and not out.solver._self_fused
    assert pairs == ref_pairs == out_pairs
    for other in (ref, out):
        _same_state(fz, other)
    cfg = fz.config
    passes = 2 * cfg.self_passes * cfg.substeps
    # (hand_only's SoftHand has a contact stage, gated off: a launch per substep either way)
    assert out_res["ops_run"] - res["ops_run"] == passes
    assert res["self_ops_run"] == 9 and out_res["self_ops_run"] == 9 + passes  # (a queried frame: slack and query)
    assert res["self_corrections"] == ref_res["self_corrections"] == out_res["self_corrections"]


def _solver_run(frames: int, fused_substep=None, self_collision: bool = True):
    """A bare Solver (no objects: no contact stage) closing the hand from ``open`` to ``power`` over
    6 frames, then holding it; the solver, its state, the last report, each frame's pairs."""
    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
    from physhand_mj.solver import Solver, make_model

    asset, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    q0, q1 = model.key("open").qpos.copy(), model.key("power").qpos.copy()
    cfg = ph.Config(device="cpu", self_collision=self_collision, execution=Execution(fused_substep=fused_substep))
    solver = Solver(make_model(asset, cfg), cfg)
    state = solver.make_state(*mount_pose(model, data))
    res, pairs = {}, []
    for f in range(frames):
        a = min((f + 1) / 6, 1.0)
        solver.set_body_poses(state, *bone_poses_at(model, data, (1 - a) * q0 + a * q1, ids))
        res = solver.step(state)
        pairs.append(res.get("self_pairs"))
    return solver, state, res, pairs


def test_fused_self_frame_is_one_launch(monkeypatch):
    """Without objects the fused self path's frame is the option-off frame plus the query's
    once-a-frame ops (one frame launch: no launch a substep), bit for bit the non-fused solver's and
    the fused kernel's with self_contact's launches after it (closing to the power grasp, ops a frame:
    off 2; on 13, against 104 with the launches and 164 non-fused)."""
    fz, st, res, pairs = _solver_run(10)
    assert fz.fused_substep and fz._self_fused and max(pairs) > 0
    ref, st_ref, ref_res, ref_pairs = _solver_run(10, fused_substep=False)
    monkeypatch.setattr(fused, "SELF_IN_KERNEL", False)
    out, st_out, out_res, out_pairs = _solver_run(10)
    assert pairs == ref_pairs == out_pairs
    for other in (st_ref, st_out):
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(st, name).numpy(), getattr(other, name).numpy(), err_msg=name)
    off, _, off_res, _ = _solver_run(1, self_collision=False)
    cfg = fz.config
    assert res["ops_run"] == off_res["ops_run"] + 12  # (the slack's 5 and the query's 7: self_contact.record_frame)
    # with the launches: a fused launch per substep (frame launch off), the passes, the last advance and the count
    assert out_res["ops_run"] - res["ops_run"] == 2 * cfg.self_passes * cfg.substeps + cfg.substeps - 1 + 2
    assert ref_res["ops_run"] > out_res["ops_run"]


@pytest.mark.parametrize("friction", [0.0, 0.5])
@pytest.mark.parametrize("lanes", [1, 64])
def test_fused_self_fixed_point_sum_in_any_order(lanes, friction, monkeypatch):
    """ACCUM "fixed" (CUDA's default) on the CPU: the self passes' moves and x_prev shares added as
    int32 steps, so one lane and Warp's 64-lane CPU blocks (a GPU block's lanes meeting at the
    barriers) give the same bits and pairs. (Against the float sum the closing pinch differs by up to
    ~0.4 mm after its 20 settle frames and 3 more: the contact's choices amplify rounding, as the float
    sum in 64 lanes' order does, ~0.3 mm; without self-collision the two sums stay within 1 um.)"""
    if lanes > 1 and not hasattr(wp.config, "enable_cpu_blocks"):
        pytest.skip("this Warp has no multi-lane CPU blocks (wp.config.enable_cpu_blocks)")
    monkeypatch.setattr(fused, "ACCUM", "fixed")
    block = fused.BLOCK_DIM

    def run(k):
        if hasattr(wp.config, "enable_cpu_blocks"):
            monkeypatch.setattr(wp.config, "enable_cpu_blocks", k > 1)
        monkeypatch.setattr(fused, "BLOCK_DIM", 64 if k > 1 else block)
        hand, res, pairs = _run("pinch", 3, fused_substep=True, friction=friction)
        assert hand.solver._fused.fixed and hand.solver._self_fused
        return hand, pairs

    one, one_pairs = run(1)
    assert min(one_pairs) > 0
    if lanes > 1:
        many, many_pairs = run(lanes)
        assert many_pairs == one_pairs
        _same_state(one, many)


@pytest.mark.slow  # 36 frames of the power grasp twice, and the measure (brute-force winding numbers)
def test_fused_self_measure_power():
    """The independent measure after the power grasp's 36 frames: the fused self path's (the CPU's
    default) as the non-fused one's (the same bits), and with the fixed-point sum at most the bound
    the launches' test holds (100 of 698 inside at 0.2 mm)."""
    fz, _, _ = _run("power", 36)
    ref, _, _ = _run("power", 36, fused_substep=False)
    faces = np.asarray(fz.asset.skin_faces)
    a, b = (self_penetration(h.state.x.numpy(), faces) for h in (fz, ref))
    assert a == b and a["inside_200um"] <= 100, (a, b)


@pytest.mark.slow
def test_fused_self_fixed_point_measure_power(monkeypatch):
    """The fixed-point sum (CUDA's) through the power grasp: finite, at most 100 vertices inside."""
    monkeypatch.setattr(fused, "ACCUM", "fixed")
    hand, res, _ = _run("power", 36, fused_substep=True)
    x = hand.state.x.numpy()
    assert np.all(np.isfinite(x)) and res["nonfinite"] == 0
    m = self_penetration(x, np.asarray(hand.asset.skin_faces))
    assert m["inside_200um"] <= 100, m


def _batch_run(keys, fused_substep=None, self_collision: bool = True):
    """BatchedHands of len(keys) worlds on the CPU, world w closing from ``open`` to ``keys[w]`` over 6
    frames and holding it 3 more (test_self_collision_batch's schedule); the batch, its last report,
    each frame's per-world (listed vertices, pairs, corrections)."""
    from physhand_mj.batch import BatchedHands
    from test_self_collision_batch import _schedule, open_hand_scene, body_ids, mount_pose

    asset, model, data = open_hand_scene("hand_only", "open")
    setup = (asset, model, data, body_ids(model, asset.body_names), mount_pose(model, data))
    cfg = ph.Config(device="cpu", self_collision=self_collision, execution=Execution(fused_substep=fused_substep))
    batch = BatchedHands(asset, len(keys), cfg, *setup[4])
    out, rows = {}, []
    frames = _schedule(setup, keys)
    for poses in frames:
        out = batch.step(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]))
        assert out["nonfinite"] == 0
        if self_collision:
            rows.append([(r["self_vertices"], r["self_pairs"], r["self_corrections"]) for r in out["worlds"]])
    return batch, out, np.array(rows), setup, frames


def _same_batch_state(a, b) -> None:
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a.state, name).numpy(), getattr(b.state, name).numpy(), err_msg=name)


@pytest.mark.parametrize("keys", [("open", "pinch", "power"), ("power", "pinch")], ids=["open-pinch-power", "power-pinch"])
def test_batched_fused_self_equals_the_launches(keys, monkeypatch):
    """Batched worlds (BatchedHands, no objects) on the CPU's default take the passes inside the fused
    kernel, a block per world reading its world's segment of the lists: bit for bit the fused kernel
    with self_contact's launches after it (fused.SELF_IN_KERNEL False) and the non-fused solver
    (fused_substep=False), the same per-world pairs every frame, and each world bit for bit one hand
    alone through its poses; the frame stays one frame launch (the option-off frame plus the query's
    11 once-a-frame ops, however many worlds)."""
    from test_self_collision_batch import _serial

    fz, res, rows, setup, frames = _batch_run(keys)
    assert fz.solver.fused_substep and fz.solver._self_fused and rows[:, :, 1].max() > 0
    ref, ref_res, ref_rows, *_ = _batch_run(keys, fused_substep=False)
    assert not ref.solver.fused_substep
    monkeypatch.setattr(fused, "SELF_IN_KERNEL", False)
    out, out_res, out_rows, *_ = _batch_run(keys)
    monkeypatch.undo()
    assert out.solver.fused_substep and not out.solver._self_fused
    np.testing.assert_array_equal(rows, ref_rows)
    np.testing.assert_array_equal(rows, out_rows)
    for other in (ref, out):
        _same_batch_state(fz, other)
    off, off_res, *_ = _batch_run(keys, self_collision=False)
    assert res["ops_run"] == off_res["ops_run"] + 12
    cfg = fz.config
    assert out_res["ops_run"] - res["ops_run"] == 2 * cfg.self_passes * cfg.substeps + cfg.substeps - 1 + 2
    for w, key in enumerate(keys):  # each world as one hand alone (the fused self path too: the CPU's default)
        x, sp = _serial(setup, fz.config, key, frames, w)
        np.testing.assert_array_equal(rows[:, w], sp, err_msg=key)
        np.testing.assert_array_equal(fz.positions(w), x, err_msg=key)


def test_batched_fused_self_fixed_point_sum(monkeypatch):
    """ACCUM "fixed" (CUDA's default) in batched worlds on the CPU: each world bit for bit the same
    world run as a batch of one (its block reads only its own world's lists and buffers), and, where
    this Warp has multi-lane CPU blocks, 64 lanes give the one lane's bits."""
    monkeypatch.setattr(fused, "ACCUM", "fixed")
    block = fused.BLOCK_DIM

    def run(keys, lanes):
        if hasattr(wp.config, "enable_cpu_blocks"):
            monkeypatch.setattr(wp.config, "enable_cpu_blocks", lanes > 1)
        monkeypatch.setattr(fused, "BLOCK_DIM", 64 if lanes > 1 else block)
        b, _, rows, *_ = _batch_run(keys, fused_substep=True)
        assert b.solver._fused.fixed and b.solver._self_fused
        return b, rows

    both, rows = run(("pinch", "power"), 1)
    assert rows[-1, :, 1].min() > 0
    for w, key in enumerate(("pinch", "power")):
        one, one_rows = run((key,), 1)
        np.testing.assert_array_equal(rows[:, w], one_rows[:, 0], err_msg=key)
        np.testing.assert_array_equal(both.positions(w), one.positions(0), err_msg=key)
    if hasattr(wp.config, "enable_cpu_blocks"):
        many, many_rows = run(("pinch", "power"), 64)
        np.testing.assert_array_equal(rows, many_rows)
        _same_batch_state(both, many)


def test_friction_passes_equal_the_launches():
    """Tuning.self_friction in the passes inside the fused kernel (float sum): bit for bit the
    five-launch substep's launches on the CPU, the same pairs (the fixed-point sum with friction:
    test_fused_self_fixed_point_sum_in_any_order)."""
    frames = 4
    fz, res, pairs = _run("power", frames, friction=0.5)
    assert fz.solver._self_fused and res["self_corrections"] > 0
    ref, ref_res, ref_pairs = _run("power", frames, fused_substep=False, friction=0.5)
    assert pairs == ref_pairs
    _same_state(fz, ref)
    plain, *_ = _run("power", frames)
    assert np.abs(plain.state.x.numpy() - fz.state.x.numpy()).max() > 1e-6  # (friction changed the result)


def test_unused_features_compiled_out(monkeypatch):
    """The fused kernel and the passes' resolve launch leave Tuning.self_tet_keep's guard and
    Tuning.self_friction out where they are 0 (self_contact.pair_correction_fn: a kernel at a register
    cap spills what it carries): the same bits as the variants with both compiled in, in the fused path
    and in the launches."""
    from physhand_mj.solver import self_contact

    hand, res, pairs = _run("power", 4)
    assert hand.solver.selfc.features() == (False, False) and res["self_corrections"] > 0
    launches, _, l_pairs = _run("power", 4, fused_substep=False)
    lean = hand.solver._fused.kernel
    monkeypatch.setattr(self_contact.SelfContact, "features", lambda self: (True, True))
    full, _, full_pairs = _run("power", 4)
    full_l, _, full_l_pairs = _run("power", 4, fused_substep=False)
    assert full.solver._fused.kernel is not lean  # (another kernel: both compiled in)
    assert self_contact.resolve_kernel(True, True) is not self_contact.resolve_kernel(False, False)
    assert pairs == full_pairs == l_pairs == full_l_pairs
    for other in (full, launches, full_l):
        _same_state(hand, other)
