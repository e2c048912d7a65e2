"""Only the effects a scene calls for (physhand_mj/solver/activity.py): with no object near the hand no
contact kernel runs, objects enter and leave the work set through the broadphase, skipping changes
no result, and switching an effect off removes exactly its launches (sleeping: test_sleep.py)."""

import numpy as np
import pytest

from physhand_mj.config import Tuning
from physhand_mj.rollout import bone_clearances
import physhand_mj as ph
from activity_helpers import FAR, R, _solver, _step, scene  # noqa: F401 (scene: a fixture)
from physhand_mj.solver.activity import _Gate
from physhand_mj.types import Config, GeomType


def _kernel_name(op):
    cmd = getattr(op, "cmd", None) or getattr(op, "__self__", None)
    k = getattr(cmd, "kernel", None)
    return None if k is None else f"{k.module.name}.{k.key}"


def _leaves(ops, inside=False):
    """(list, index, inside a gated block) of every recorded op, through the gated blocks."""
    for i, op in enumerate(ops):
        if isinstance(op, _Gate):
            yield from _leaves(op.sub, True)
        else:
            yield ops, i, inside


def _instrument(solver, state):
    """Wrap every recorded op so that running it logs its kernel (or None for memsets, refits)."""
    ran = []
    ops = solver._ops[(id(state), id(solver.contact))]
    for lst, i, _ in list(_leaves(ops)):
        op = lst[i]

        def wrapped(op=op, name=_kernel_name(op)):
            ran.append(name)
            op()

        lst[i] = wrapped
    return ran


def _is_contact_kernel(name):
    return name is not None and (".contact." in name or ".metrics" in name or name.endswith("tether_skin"))


def test_no_object_near_runs_no_contact_kernel(scene):
    solver, state, objects, top = _solver(scene)
    poses = scene[2]
    _step(solver, state, poses)  # records (and compiles) the frame
    ran = _instrument(solver, state)
    out = _step(solver, state, poses)
    contact = [k for k in ran if _is_contact_kernel(k)]
    assert contact == [], f"contact kernels ran with no object near: {sorted(set(contact))}"
    assert out["contact_ops_run"] == 0 and out["objects_near"] == 0 and out["triangles_frame"] == 0
    assert out["ops_run"] == len(ran), (out["ops_run"], len(ran))
    # the ball enters the work set: the broadphase lists triangles and the contact runs
    objects.set_pose(0, top + [0.0, 0.0, R - 0.002], (1.0, 0.0, 0.0, 0.0))
    ran.clear()
    out = _step(solver, state, poses)
    names = set(ran)
    assert {"find_active", "decide_and_project", "apply_contact", "penetration_samples"} <= {
        n.rsplit(".", 1)[1] for n in names if n}, names
    assert out["objects_near"] == 1 and out["triangles_frame"] > 0 and out["triangles_tested"] > 0
    assert out["contact_ops_run"] > 0 and out["ops_run"] == len(ran), (out["ops_run"], len(ran))
    counts = solver.contact.stage_counts()
    assert out["triangles_stage"] == counts[:, 0].sum()
    # ... and leaves it
    objects.set_pose(0, FAR, (1.0, 0.0, 0.0, 0.0))
    ran.clear()
    out = _step(solver, state, poses)
    assert not [k for k in ran if _is_contact_kernel(k)] and out["objects_near"] == 0
    assert out["penetration_count"] == 0 and not solver.contact.push.numpy().any()


def test_object_within_margin_but_not_touching_runs_the_broadphase_only(scene):
    solver, state, objects, top = _solver(scene)
    poses = scene[2]
    # inside the host box test, outside the triangles' frame margin (the sphere's bounding box
    # overlaps the grown skin box but no triangle is within 1 cm): the broadphase runs, nothing else
    lo = state.x.numpy()[: solver.model.n_skin].min(axis=0).astype(float)
    objects.set_pose(0, lo - (R + 0.006) / np.sqrt(3.0), (1.0, 0.0, 0.0, 0.0))
    _step(solver, state, poses)
    ran = _instrument(solver, state)
    out = _step(solver, state, poses)
    contact = {k.rsplit(".", 1)[1] for k in ran if _is_contact_kernel(k)}
    assert out["objects_near"] == 1 and out["triangles_frame"] == 0
    assert contact == {"find_active"}, contact


def test_skipping_changes_no_result(scene):
    """An object approaching, touching and pressing: skip_idle on and off give the same skin, bit
    for bit (CPU), the same metrics and the same contact report."""
    runs = []
    for skip in (True, False):
        solver, state, objects, top = _solver(scene, GeomType.BOX, (0.015, 0.015, 0.015), skip_idle=skip)
        outs = []
        for k in range(12):
            objects.set_pose(0, top + [0.0, 0.0, 0.015 + 0.03 - 0.0035 * k], (1.0, 0.0, 0.0, 0.0))
            outs.append(_step(solver, state, scene[2]))
        runs.append((state.x.numpy().copy(), outs, solver.contact.push.numpy().copy()))
    (x1, o1, p1), (x2, o2, p2) = runs
    assert np.array_equal(x1, x2), float(np.abs(x1 - x2).max())
    assert np.array_equal(p1, p2)
    keys = ("penetration_count", "penetration_max_um", "tethered", "triangles_frame", "triangles_tested",
            "features_listed")
    assert [[o[k] for k in keys] for o in o1] == [[o[k] for k in keys] for o in o2]
    assert o1[0]["contact_ops_run"] == 0 < o2[0]["contact_ops_run"]  # far: skipped
    # touching: the same work, less the passes after one that moved nothing (they would repeat it)
    assert 0 < o1[-1]["contact_ops_run"] <= o2[-1]["contact_ops_run"]
    assert o1[-1]["features_listed"] > 0  # the box's corners and edges near the skin


def test_the_cuda_gating_path_changes_no_result(scene):
    """CUDA decides level 1 on the host from the frame broadphase run ahead of the frame's graph
    (Solver.step; a conditional graph node cannot hold a mesh refit). That path, forced on the CPU,
    gives the always-on run's skin bit for bit, runs only the broadphase while the box is far, and
    reports the ops it ran."""
    runs = []
    for ahead in (True, False):
        solver, state, objects, top = _solver(scene, GeomType.BOX, (0.015, 0.015, 0.015), skip_idle=ahead)
        solver.activity.gate_ahead = ahead  # before the first frame records
        outs, rans, ran = [], [], []
        for k in range(12):
            objects.set_pose(0, top + [0.0, 0.0, 0.015 + 0.03 - 0.0035 * k], (1.0, 0.0, 0.0, 0.0))
            outs.append(_step(solver, state, scene[2]))
            rans.append(list(ran))
            if not k:
                ran = _instrument(solver, state)
            ran.clear()
        runs.append((state.x.numpy().copy(), outs, rans, solver))
    (x1, o1, r1, s1), (x2, o2, _, _) = runs
    assert np.array_equal(x1, x2), float(np.abs(x1 - x2).max())
    keys = ("penetration_count", "penetration_max_um", "triangles_frame", "triangles_tested", "features_listed")
    assert [[o[k] for k in keys] for o in o1] == [[o[k] for k in keys] for o in o2]
    far, touch = 1, len(o1) - 1
    assert o1[far]["triangles_frame"] == 0 and o1[touch]["triangles_frame"] > 0
    assert not [k for k in r1[far] if _is_contact_kernel(k)]  # the broadphase ran ahead, outside the frame's ops
    assert o1[far]["contact_ops_run"] == 2 < o1[touch]["contact_ops_run"]  # the broadphase and its counter reset
    assert o1[touch]["ops_run"] == len(r1[touch]) + 2  # (run ahead)
    assert o1[far]["ops_run"] == len(r1[far]) + 2


def test_conditional_contact_passes_change_no_result(scene):
    """CUDA (graphs, tiled features) puts each contact pass after the first behind a conditional
    graph node (wp.capture_if on a flag keep_moved sets from the previous pass's counters): a pass
    after one that moved nothing is skipped on the device. That path, forced on the CPU (capture_if
    then reads the flag on the host), gives the always-on run's skin bit for bit and reports fewer
    ops while the box touches."""
    runs = []
    for cond in (True, False):
        solver, state, objects, top = _solver(scene, GeomType.BOX, (0.015, 0.015, 0.015), skip_idle=cond)
        solver.activity.gate_ahead = cond  # before the first frame records
        solver.activity.conditional = cond
        outs = []
        for k in range(12):
            objects.set_pose(0, top + [0.0, 0.0, 0.015 + 0.03 - 0.0035 * k], (1.0, 0.0, 0.0, 0.0))
            outs.append(_step(solver, state, scene[2]))
        runs.append((state.x.numpy().copy(), outs, solver))
    (x1, o1, s1), (x2, o2, _) = runs
    assert any(g.cond is not None for g in s1.activity.gates)  # the passes were conditional
    # each stage's later passes nest (a skipped pass skips the rest in one test): of a stage's level-2
    # gates only its second pass's is outside another, and only its last holds none
    passes = [g for g in s1.activity.gates if g.level == 2 and g.slots != (s1.contact.held_slot,)]
    holds = [sum(op in passes for op in g.sub) for g in passes]
    stages = len(passes) // (s1.config.contact_passes - 1)
    assert len(passes) == stages * (s1.config.contact_passes - 1) and stages > 0
    assert holds.count(0) == stages and set(holds) == {0, 1}
    assert sum(any(g in h.sub for h in passes) for g in passes) == len(passes) - stages
    assert np.array_equal(x1, x2), float(np.abs(x1 - x2).max())
    keys = ("penetration_count", "penetration_max_um", "triangles_frame", "triangles_tested", "features_listed")
    assert [[o[k] for k in keys] for o in o1] == [[o[k] for k in keys] for o in o2]
    # (the frame before the last: in the last the box holds a bone of the back of the hand 2 mm deep and
    # more, and there the bones' hold cuts the pushes short, which keeps every pass moving: bones.KEEP)
    assert 0 < o1[-2]["contact_ops_run"] < o2[-2]["contact_ops_run"]



def test_contact_pass_tol_skips_passes_only_before_the_frames_last_stage(scene):
    """Config.tuning.contact_pass_tol: in every stage but the frame's last, a pass runs only when the pass
    before it moved some vertex by more than the tolerance. With 1 m no stage but the last runs more
    than its first pass (their later passes' lists stay empty), the last stage still runs until a
    pass moves nothing, so every frame of a box pressing into the hand ends with no skin sample in
    it while the bones are clear of it, in fewer ops than the default; CUDA's device flag (keep_moved, conditional passes forced
    on the CPU) skips the same passes as the CPU's host test, bit for bit, at 1 m and at 0.5 mm (where
    the pass moves decide: some later passes run, fewer than the default's). Where passes are not
    gated (``skip_idle=False``) the option is not applied: the default's skin bit for bit."""
    runs = []
    for tol, cond, idle in ((0.0, False, True), (1.0, False, True), (1.0, True, True), (5e-4, False, True),
                            (5e-4, True, True), (1.0, False, False), (0.0, False, False)):
        # (the box ends 8.5 mm into the back of the hand, past its bones: without the bones' hold,
        # contact/bones.py, the skin is pushed out of it in every frame, which the passes' gating is
        # tested on; in the frames where a bone is inside it no penetration-free skin exists)
        solver, state, objects, top = _solver(scene, GeomType.BOX, (0.015, 0.015, 0.015), contact_pass_tol=tol,
                                              skip_idle=idle, bone_hold=False)
        solver.activity.gate_ahead = cond
        solver.activity.conditional = cond
        outs, later = [], []
        for k in range(12):
            objects.set_pose(0, top + [0.0, 0.0, 0.015 + 0.03 - 0.0035 * k], (1.0, 0.0, 0.0, 0.0))
            outs.append(_step(solver, state, scene[2]))
            outs[-1]["bones_clear"] = bone_clearances(solver.contact, state)[0] > 0.0
            c = solver.contact
            lists = c.lists.counters_host.numpy()[np.asarray(c.pass_slots)].reshape(len(c._stage_slots), -1)
            later.append(lists[:, 1:].sum(axis=1))  # per stage: triangles its later passes tested
        runs.append((state.x.numpy().copy(), outs, np.array(later)))
    (x0, o0, l0), (x1, o1, l1), (x2, o2, l2), (x3, o3, l3), (x4, o4, l4), (x5, o5, l5), (x6, o6, l6) = runs
    pressed = [k for k in range(12) if o0[k]["triangles_tested"] > 0]
    assert len(pressed) >= 4 and l0[pressed][:, :-1].sum() > 0  # the default re-tests in every stage
    assert l1[:, :-1].sum() == 0 and l1[:, -1].sum() > 0  # tol: only the last stage re-tests
    # zero where a penetration-free skin exists (the bones clear of the box); the last frames put
    # bones inside it, where the skin's answer is the infeasible start's (tests/test_bone_inside.py)
    assert sum(o["bones_clear"] for o in o0) >= 8 and [o["bones_clear"] for o in o0] == [o["bones_clear"] for o in o1]
    assert all(o["penetration_count"] == 0 for o in o0 + o1 if o["bones_clear"]), [o["penetration_count"] for o in o1]
    assert sum(o1[k]["contact_ops_run"] for k in pressed) < sum(o0[k]["contact_ops_run"] for k in pressed)
    assert np.array_equal(x1, x2), float(np.abs(x1 - x2).max())
    keys = ("penetration_count", "triangles_tested", "triangles_stage")  # (ops: each path counts its own)
    assert [[o[k] for k in keys] for o in o1] == [[o[k] for k in keys] for o in o2]
    assert np.array_equal(l1, l2)
    assert 0 < l3[:, :-1].sum() < l0[:, :-1].sum()  # 0.5 mm: the moves decide
    assert np.array_equal(x3, x4) and np.array_equal(l3, l4), float(np.abs(x3 - x4).max())
    assert all(o["penetration_count"] == 0 for o in o3 if o["bones_clear"])
    assert np.array_equal(x5, x6), float(np.abs(x5 - x6).max())  # ungated: not applied
    with pytest.raises(ValueError, match="contact_pass_tol"):
        Config(tuning=Tuning(contact_pass_tol=-1e-4)).validate()

def _recorded(solver, state, poses):
    _step(solver, state, poses)
    ops = solver._ops[(id(state), id(solver.contact))]
    return [_kernel_name(lst[i]) for lst, i, _ in _leaves(ops)]


def _without(names, drop):
    return [n for n in names if n is None or not n.endswith(drop)]


@pytest.mark.parametrize("effect, config, kernels", [
    # a Jacobi group fewer: its averaging launch goes with it (one per substep)
    ("smoothness", dict(smoothness=False), ("solve_dihedrals", "apply_jacobi")),
    ("tether", dict(skin_tether=0.0), ("tether_skin",)),
    ("substep metrics", dict(substep_metrics=True), ("penetration_samples",)),
])
def test_switching_an_effect_off_removes_exactly_its_launches(scene, effect, config, kernels):
    # the smoothness's own launches are the five-launch substep's (Config.execution.fused_substep=False); the
    # fused substep (the CPU's default) has one launch either way and walks no dihedral (below)
    extra = dict(fused_substep=False) if effect == "smoothness" else {}
    base_s, base_st, *_ = _solver(scene, **extra)
    other_s, other_st, *_ = _solver(scene, **config, **extra)
    base, other = _recorded(base_s, base_st, scene[2]), _recorded(other_s, other_st, scene[2])
    more, less = (other, base) if effect == "substep metrics" else (base, other)
    assert len(more) > len(less), effect
    count = lambda names, k: sum(1 for n in names if n and n.endswith(k))
    subs = base_s.config.substeps
    assert count(more, kernels[0]) - count(less, kernels[0]) == subs  # one per substep
    if effect == "smoothness":
        assert count(more, "apply_jacobi") - count(less, "apply_jacobi") == subs
    for k in kernels:
        more = _without(more, k)
        less = _without(less, k)
    assert more == less, f"{effect}: launches other than {kernels} changed"
    if effect == "smoothness":  # fused: the same launches, and no dihedral left to walk
        on, off = _solver(scene), _solver(scene, **config)
        assert on[0]._fused is not None and off[0]._fused is not None
        assert on[0]._fused.dih_ids.shape[0] > 0 == off[0]._fused.dih_ids.shape[0]
        assert _recorded(on[0], on[1], scene[2]) == _recorded(off[0], off[1], scene[2])


@pytest.mark.parametrize("every", [2, 3])
def test_contact_every_runs_fewer_stages_and_nothing_else(scene, every):
    """Config.contact_every = k records a contact stage every k-th substep counted back from the last
    (ceil(substeps / k) stages, the last substep's always), the solver's own launches unchanged; a
    sphere pressed 2 mm into the back of the hand still ends each frame clean by the skin measure."""
    subs = Config().substeps
    runs = {}
    for k in (1, every):
        solver, state, objects, top = _solver(scene, contact_every=k)
        objects.set_pose(0, top + [0.0, 0.0, R - 0.002], (1.0, 0.0, 0.0, 0.0))
        names = _recorded(solver, state, scene[2])
        for _ in range(2):
            out = _step(solver, state, scene[2])
        runs[k] = names, solver, out
    (base, s1, o1), (other, s2, o2) = runs[1], runs[every]
    count = lambda names, k: sum(1 for n in names if n and n.endswith(k))
    assert count(base, "stage_lists") == subs and len(s1.contact._stage_slots) == subs
    assert count(other, "stage_lists") == -(-subs // every) == len(s2.contact._stage_slots)
    # the contact stage's launches: the contact's own and, with Tuning.flesh_carry, the carry around each stage
    own = lambda names: [n for n in names if n and not n.startswith(("physhand_mj.contact", "physhand_mj.solver.carry"))]
    assert own(base) == own(other) and len(own(base)) >= 2 * subs  # (fused: a launch and the tether a substep)
    assert o1["triangles_tested"] > 0 and o2["triangles_tested"] > 0
    assert o1["penetration_count"] == 0 and o2["penetration_count"] == 0, (o1, o2)


def test_substep_metrics_only_when_asked_and_change_nothing_else(scene):
    runs = []
    for sub in (False, True):
        solver, state, objects, top = _solver(scene, substep_metrics=sub)
        objects.set_pose(0, top + [0.0, 0.0, R - 0.002], (1.0, 0.0, 0.0, 0.0))
        for _ in range(3):
            out = _step(solver, state, scene[2])
        runs.append((state.x.numpy().copy(), out, solver.substep_metrics.copy()))
    (x1, o1, r1), (x2, o2, r2) = runs
    assert np.array_equal(x1, x2)
    assert o1["penetration_count"] == o2["penetration_count"]
    assert not r1.any() and r2[:, 0].sum() >= 0 and r2.shape == r1.shape
    assert np.array_equal(r2[:, 3:], np.zeros_like(r2[:, 3:]))  # the second measure runs at the frame's end only


def test_frame_metrics_only_when_asked_and_change_nothing_else(scene):
    """Config.frame_metrics=False records no skin measure in the frame (one launch fewer, nothing else
    changed), leaves the skin the same bit for bit, reports no penetration from the frame, and the
    measure asked afterwards gives the frame's own row: a 1 mm sphere 0.5 mm into the middle of a skin
    triangle, which the vertex strategy's decision points (corners, edge midpoints) do not see."""
    runs = []
    faces = scene[0].skin_faces
    for on in (True, False):
        solver, state, objects, top = _solver(scene, size=(0.001, 0.0, 0.0), contact="vertex", frame_metrics=on)
        x = state.x.numpy()[faces]
        t = np.argmin(np.linalg.norm(x.mean(axis=1) - top, axis=1))
        n = np.cross(x[t, 1] - x[t, 0], x[t, 2] - x[t, 0])
        objects.set_pose(0, x[t].mean(axis=0) - 5e-4 * n / np.linalg.norm(n), (1.0, 0.0, 0.0, 0.0))
        names = _recorded(solver, state, scene[2])
        for _ in range(2):
            out = _step(solver, state, scene[2])
        runs.append((names, state.x.numpy().copy(), out, solver, state))
    (n1, x1, o1, s1, _), (n2, x2, o2, s2, st2) = runs
    count = lambda names: sum(1 for n in names if n and n.endswith("penetration_samples"))
    assert count(n1) == 1 and count(n2) == 0
    assert _without(n1, "penetration_samples") == n2
    assert np.array_equal(x1, x2)
    assert "penetration_count" in o1 and not any(k.startswith("penetration") for k in o2), o2
    frame_row = s1.contact.read_metrics()[-1][:3]
    assert frame_row[0] > 0, frame_row  # (the sphere presses in: a row that could differ)
    np.testing.assert_array_equal(frame_row, s2.contact.measure(st2, objects_side=False)[:3])


def test_softhand_metrics_measure_on_demand_what_the_frame_did_not():
    """SoftHand.metrics() with the skin measure off in the frame and the object side on gives what the
    defaults give (the frame's skin measure, the object side on demand): each side from where it was
    measured, none overwritten by the other's zeros (the HOI box grasp one frame in: both nonzero)."""
    import mujoco

    runs = []
    for cfg in (dict(), dict(frame_metrics=False, object_metrics=True)):
        model = mujoco.MjModel.from_xml_path(str(ph.scene_path("hoi_box")))
        data = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
        mujoco.mj_forward(model, data)
        hand = ph.SoftHand(model, data, ph.Config(device="cpu", **cfg), settle_frames=0)
        mujoco.mj_step(model, data)
        out = hand.step()
        runs.append((out, {k: v for k, v in hand.metrics().items() if k.startswith(("penetration", "object_in"))}))
    (o1, m1), (o2, m2) = runs
    assert m1 == m2 and m1["penetration_count"] > 0 and m1["object_in_skin_count"] > 0, (m1, m2)
    assert "penetration_count" in o1 and "object_in_skin_count" not in o1
    assert "object_in_skin_count" in o2 and "penetration_count" not in o2


def test_a_rollout_refuses_to_log_without_frame_metrics():
    from types import SimpleNamespace

    from physhand_mj.rollout import rollout_config

    model = SimpleNamespace(opt=SimpleNamespace(timestep=0.002))
    assert rollout_config(model, 10, "multires", "cpu", {}).frame_metrics
    # an option of an expert group by its name, as a rollout list's JSON gives it
    assert rollout_config(model, 10, "multires", "cpu", {"feature_offset": 5e-5}).feature_offset == 5e-5
    with pytest.raises(ValueError, match="frame_metrics"):
        rollout_config(model, 10, "multires", "cpu", {"frame_metrics": False})


def test_softhand_metrics_say_what_ran():
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device="cpu"), settle_frames=2)
    mujoco.mj_step(model, data)
    hand.step()
    m = hand.metrics()
    for k in ("objects_near", "triangles_frame", "triangles_tested", "features_listed", "ops_run", "contact_ops_run"):
        assert isinstance(m[k], int) and m[k] >= (-1 if k == "objects_near" else 0), (k, m[k])
    assert m["ops_run"] >= m["contact_ops_run"]


# -- sleeping: a still hand with no object near costs one launch per frame --------------------------


def test_the_wall_carry_records_nothing_without_a_wall(scene):
    """Tuning.wall_carry (on by default) in a scene without a broad wall: the recorded launches are
    those with the share at 0, none of the carry's."""
    a_s, a_st, *_ = _solver(scene)
    b_s, b_st, *_ = _solver(scene, wall_carry=0.0)
    a, b = _recorded(a_s, a_st, scene[2]), _recorded(b_s, b_st, scene[2])
    assert a == b and not any(n and n.startswith("physhand_mj.solver.carry") for n in a)
    p_s, p_st, *_ = _solver(scene, GeomType.BOX, (0.008, 0.008, 0.0005))  # a plate: a broad wall
    p = _recorded(p_s, p_st, scene[2])
    # the frame's mark, and a snapshot and a carry around each of the frame's stages
    assert sum(1 for n in p if n and n.startswith("physhand_mj.solver.carry")) == 1 + 2 * Config().substeps
