"""A Solver compiles the Warp modules its first recorded frame launches before it makes the launches
(solver.load_modules: side by side on CUDA), only those: a hand without objects compiles no contact
kernel; and the frame it records is the one it recorded before (benchmarks/fingerprint.py checks
the results bit for bit)."""

import numpy as np
import warp as wp

import physhand_mj as ph
from physhand_mj.solver import solver as solver_mod


def _spy(monkeypatch):
    """The {module name: block_dim values} each load_modules call was given, in order."""
    calls = []
    real = solver_mod.load_modules

    def spy(device, modules, workers=None):
        calls.append({m.name: set(b) for m, b in modules.items()})
        real(device, modules, workers)

    monkeypatch.setattr(solver_mod, "load_modules", spy)
    return calls


def test_a_frame_without_objects_loads_only_the_solvers_modules(monkeypatch):
    calls = _spy(monkeypatch)
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    config = ph.Config(device="cpu")
    solver = ph.Solver(ph.make_model(asset, config), config)
    state = solver.make_state(*ph.mount_pose(model, data))
    solver.step(state)
    solver.step(state)  # (replayed: nothing more to load)
    assert len(calls) == 1 and calls[0], calls
    names = set(calls[0])
    assert any("solver.integrate" in n for n in names), names
    assert not any(".contact." in n for n in names), names
    ops = solver._ops[(id(state), id(None))]
    assert ops and not any(isinstance(op, solver_mod._StandIn) for op in ops)  # (every launch made in place)


def test_a_frame_with_objects_loads_the_contact_modules_once(monkeypatch):
    import mujoco

    calls = _spy(monkeypatch)
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    hand = ph.SoftHand(model, data, ph.Config(device="cpu"), settle_frames=1)
    for _ in range(2):
        mujoco.mj_step(model, data)
        hand.step()
    assert len(calls) == 1, [sorted(c) for c in calls]  # (one frame recorded: the settling frame's)
    names = set(calls[0])
    assert any(".contact.broadphase" in n for n in names) and any(".contact.slack" in n for n in names), names
    from physhand_mj.contact import broadphase

    assert broadphase.find_active.module.execs  # (loaded, before its launches were made)


def test_modules_load_side_by_side_as_their_launches_would():
    """load_modules with threads (CUDA's way; run here on the CPU) leaves each module loaded for the
    block size its launch asks, and a launch then finds it."""
    from physhand_mj.contact import slack

    device = wp.get_device("cpu")
    mods = {slack.skin_motion.module: {None}, solver_mod.integrate.advance.module: {None}}
    solver_mod.load_modules(device, mods, workers=2)
    for m in mods:
        assert any(ctx == device.context for ctx, _ in m.execs), m.name
    x = wp.zeros(3, dtype=wp.vec3, device=device)
    mv = slack.skin_moves(3, 1, device)
    wp.launch(slack.skin_motion, 3, [x, wp.zeros(3, dtype=int, device=device), wp.full(1, 1.0, dtype=float,
                                                                                       device=device)],
              [mv], device=device)
    out, fast_count = mv.vmotion, mv.fast_count
    assert np.all(out.numpy() == 0) and fast_count.numpy()[0] == 0
