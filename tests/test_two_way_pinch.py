"""Two-way coupling's pinch reference (issue 52, item 4): a box squeezed between two soft pads
(physhand_mj/bench/pinch.py) holds against gravity when 2 mu N >= m g and slips otherwise, N being
each pad's normal force while the box's full weight hangs on the pads (read off the reaction on the
pad's core; the flesh's shear lowers it ~10 % below the squeeze's)."""

import numpy as np
import pytest

from physhand_mj.bench.pinch import G, PinchRig, pinch_pads

pytest.importorskip("tetgen")  # (the pads are built with the asset builder: the `build` extra)

MASS, DEPTH = 0.01, 0.4e-3  # kg, m: a 10 g box, each pad pressed 0.4 mm past touching


@pytest.fixture(scope="module")
def pads():
    return pinch_pads()


@pytest.fixture(scope="module")
def bound(pads):
    """mu at the bound with the squeeze's N (gravity off): m g / (2 N)."""
    rig = PinchRig(pads, mass=MASS, mu=0.5)
    return MASS * G / (2 * rig.squeeze(DEPTH, frames=40, settle=20))


def pinch(pads, mu):
    """Squeeze, then gravity on (ramped over 0.2 s) for 0.8 s: (mu over the bound with N under the
    full load, slipped?, the run's figures). Slipped: the box fell more than 10 mm or still falls
    faster than 20 mm/s at the end (slide_angle's criterion)."""
    rig = PinchRig(pads, mass=MASS, mu=mu)
    rig.squeeze(DEPTH, frames=40, settle=20)
    out = rig.hold(160, ramp=40)
    ratio = mu / (MASS * G / (2 * out["normal"]))
    return ratio, bool(out["drop"] > 0.01 or out["speed"] > 0.02), out


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_a_pinch_holds_above_the_bound_and_slips_below(pads, bound):
    """mu 0.9 x the bound slips (below the bound also with N under load); 1.5 x holds (about 1.38 x
    with N under load: the load lowers N by ~8 %) without creeping (Coulomb's static friction: the box
    still after the flesh's shear has taken the load), its skin not entered by either measure."""
    ratio, slipped, _ = pinch(pads, 0.9 * bound)
    assert slipped and ratio < 1.0, ratio
    ratio, slipped, out = pinch(pads, 1.5 * bound)
    assert not slipped and ratio > 1.15, (ratio, out["drop"], out["speed"])
    creep = (out["zs"][-101] - out["zs"][-1]) / (100 * 0.005)  # m/s down over the last 0.5 s
    assert abs(creep) < 1.0e-3, creep  # (before the fix: 4.4 mm/s)
    assert out["state"]["penetration"] == 0 and out["state"]["object_in_skin"] == 0
    assert out["state"]["friction"][0] == pytest.approx(MASS * G, rel=0.1)  # friction carries the weight


@pytest.mark.slow
def test_pinch_slip_onset_is_within_15_percent_of_the_bound(pads, bound):
    """A sweep of mu: every slipping run is below 1.15 x the bound (N under load) and every holding
    one above 0.85 x, and the onset (between the largest slipping and the smallest holding ratio) is
    within 15 % of 1 (measured: between 0.99 and 1.05)."""
    runs = [pinch(pads, r * bound)[:2] for r in (0.9, 1.15, 1.2, 1.25, 1.3, 1.5)]
    slip = [r for r, s in runs if s]
    held = [r for r, s in runs if not s]
    assert slip and held, runs
    assert max(slip) < 1.15 and min(held) > 0.85, runs
    assert max(slip) < min(held), runs
    onset = 0.5 * (max(slip) + min(held))
    assert abs(onset - 1.0) < 0.15, (onset, runs)


@pytest.mark.slow  # two hand runs of 260 frames (~20-40 s each on a 2-core CPU)
def test_the_hands_pinch_holds_above_the_bound_and_slips_below():
    """The hand's own pinch (bench.pinch.HandPinch: hand_only's pinch keyframe, a free 16 x 16 x 3 mm
    10 g card between the thumb's and the index's tips, settled 0.3 s without gravity, then gravity
    ramped in): mu 0.21 slips (about 0.97 x the bound, N the tips' push along the card's normal under
    the full load) and mu 0.3 holds (about 1.4 x), the skin alone holding it (no proxy touches the
    card). The onset lies at 1.01-1.13 x (within 15 %), but partly thanks to the contact damping,
    which also brakes the card's fall (docs/coupling.md: "A pinch"), so only the two ends are checked.
    (mu 0.22, 0.97 x with Eq. 9's offset at 4 um, slipped at 1.01 x at 20 um on a 2-core AMD EPYC, where
    the tips' skin stands 20 um off the card and the pinch presses a little harder; measured
    2026-12-01; 0.21 slips at 0.97 x.)"""
    from physhand_mj.bench.pinch import HandPinch

    for mu, slips in ((0.21, True), (0.3, False)):
        rig = HandPinch(mu=mu, mass=MASS)
        rig.settle(60)
        out = rig.hold(200, ramp=40)
        ratio = mu / (MASS * G / (2 * out["normal"]))
        assert bool(out["drop"] > 0.01 or out["speed"] > 0.02) == slips, (mu, ratio, out["drop"], out["speed"])
        if slips:
            assert ratio < 1.0, ratio
        else:
            assert ratio > 1.3 and out["proxy_contacts"] == 0, (ratio, out["proxy_contacts"])
