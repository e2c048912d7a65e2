"""Config.tuning.touch_damping (contact/touch.py): the velocity of the skin an object pushed decays
after each contact stage, so held contact comes to rest."""

import math

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.bench.cases import run_case, wall_case
from physhand_mj.contact.touch import damp_touched, touch_keep
from activity_helpers import R, _solver, _step, scene  # noqa: F401 (scene: a fixture)
from physhand_mj.types import Placement

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.mark.parametrize("device", DEVICES)
def test_damp_touched_scales_the_substeps_velocity_relative_to_the_carrier(device):
    """Four vertices moved in substep 1; the first, third and fourth pushed by an object. Without a
    carrier bone (the first and third) the substep's velocity (x - x^i) / h is scaled by keep; the
    fourth rides a bone that moved 1 mm along x in the substep (body_sub[0] -> body_sub[1]), so it
    keeps that ride and keep of the rest; the second, not pushed, is left alone; positions never
    change."""
    x = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 2.0, 0.0], [0.1, 0.0, 0.0]], np.float32)
    move = np.array([[1e-3, 0, 0], [0, 2e-3, 0], [0, 0, -3e-3], [1e-3, 2e-3, 0]], np.float32)
    arr = lambda a, t=wp.vec3: wp.array(a, dtype=t, device=device)  # noqa: E731
    ident = wp.transform_identity()
    shifted = wp.transform(wp.vec3(1e-3, 0.0, 0.0), wp.quat_identity())
    body_sub = wp.array([[ident], [shifted]], dtype=wp.transform, device=device)
    body_pose = wp.array([[ident], [shifted]], dtype=wp.transform, device=device)
    xa, prev = arr(x), arr(x - move)
    wp.launch(damp_touched, 4, [arr(np.array([0, -1, 2, 0], np.int32), int), xa, 0.25,
                                arr(np.array([-1, -1, -1, 0], np.int32), int), body_sub, body_pose, 1], [prev],
              device=device)
    want = move * np.array([[0.25], [1.0], [0.25], [1.0]], np.float32)
    want[3] = [1e-3, 0.25 * 2e-3, 0.0]  # the bone's ride kept, the rest scaled
    np.testing.assert_allclose(xa.numpy() - prev.numpy(), want, atol=2e-7)  # (float32 at 1 m)
    np.testing.assert_array_equal(xa.numpy(), x)


def test_touch_keep_is_the_decay_over_the_time_between_stages(scene):
    """A stage keeps exp(-dt / touch_damping), dt the time since the substep the last stage damped,
    as the solver's schedule records them: 10 stages of 0.5 ms at 10 substeps, 5 of 1 ms with
    contact_every=2; with the stage on both sides of the constraints the first of a substep's two
    keeps 0.5 ms's share and the second 1 (no time passed), the same per substep. On by default
    (0.72 ms); off at 0 and with two_way (whose exchange damps its own contacts): nothing recorded;
    a negative time is refused."""
    tau = 7.2e-4

    def keeps(**config):  # the keeps of one frame's recorded stages, the ball 3 mm into the back of the hand
        solver, state, objects, top = _solver(scene, **config)
        objects.set_pose(0, top + [0.0, 0.0, R - 0.003], (1.0, 0.0, 0.0, 0.0))
        _step(solver, state, scene[2])
        return solver.contact.touch.keeps

    assert keeps(touch_damping=tau) == pytest.approx([math.exp(-0.5e-3 / tau)] * 10)
    assert keeps(touch_damping=tau, contact_every=2) == pytest.approx([math.exp(-1e-3 / tau)] * 5)
    assert keeps(touch_damping=tau, contact_placement=Placement.BOTH) == pytest.approx([math.exp(-0.5e-3 / tau), 1.0] * 10)
    assert touch_keep(0.0, 0.5e-3) == 1.0 and touch_keep(tau, 0.0) == 1.0
    assert ph.Config().tuning.touch_damping == tau and keeps() == pytest.approx([math.exp(-0.5e-3 / tau)] * 10)
    assert keeps(touch_damping=0.0) == [] and keeps(touch_damping=tau, two_way=True) == []
    with pytest.raises(ValueError, match="touch_damping"):
        ph.Config(device="cpu", tuning=ph.Tuning(touch_damping=-1e-3)).validate()


def test_held_skin_at_a_slanted_wall_comes_to_rest():
    """The 16 mm plate slanted 25 degrees, 3 mm into the palm (tests/test_thin_walls.py's family):
    without touch damping the skin swings (its largest displacement from rest changes by up to 9.7 mm from frame
    to frame over the last 8 of 16 frames) and keeps samples inside the plate in held frames (7-36,
    up to 0.49 mm); with touch_damping 0.72 ms (the default: half the pushed skin's velocity a stage) it is at
    rest (within 0.2 mm) and clean by all four measures in every frame (measured 2026-12-01, CPU)."""
    asset = ph.load_asset()
    case = wall_case(0.008, 0.001, 0.003, tilt=25.0)
    runs = {tau: run_case(case, ph.Config(device="cpu", tuning=ph.Tuning(touch_damping=tau)), frames=16, asset=asset)
            for tau in (0.0, 7.2e-4)}
    swing = {tau: float(np.ptp(r["max_disp_mm"][-8:])) for tau, r in runs.items()}
    keys = ("skin_count", "dense_count", "obj_count", "check_count")
    assert swing[0.0] > 2.0 and runs[0.0]["skin_count"][-8:].max() > 0, swing
    damped = runs[7.2e-4]
    assert damped["finite"] and swing[7.2e-4] < 0.5, swing
    assert all(damped[k][-8:].max() == 0 for k in keys), {k: damped[k].tolist() for k in keys}
