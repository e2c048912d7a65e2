"""Long runs and random cases (issue 14): the soak and property-based poses and object placements.

Soak: cycles of 100 frames: the hand closes half way to the power grasp while a 10 mm ball, riding
with the palm's bone, presses 3 mm into the palm (30 frames), holds (30), opens and withdraws (30),
rests away (10). 2 cycles in the default run, 100 cycles (10,000 frames) under ``-m soak``. Asserted
every frame: finite, skin within the 25 mm tether of its bones, volume within 2 %; at the end of
every cycle (object away, hand open): no tet inverted, zero by both measures, and no drift: the skin
within 0.5 mm of where the first cycle left it; while held: penetration by both measures not growing
from cycle to cycle (the worst of the last cycles within the first cycle's + 2 samples / 20 um).

Hypothesis: a random pose within the joint ranges (a fraction of the way from ``open`` to a random
point of the range box), one object (sphere, capsule, box, cone, knife, 1 mm plate) at the
fingertip or palm, riding with the site's bone, pressed 0-5 mm in, held, withdrawn. Asserted:
finite, skin within 50 mm of its carried position (the thumb web at the thumb's limits reaches
44 mm without contact; docs/stability.md), volume within 10 %, penetration not growing while held,
zero once away, and no more tets inverted near where the object was (15 mm) at the end than the same
poses without the object invert there (a curled pose inverts crease tets by itself). Where the
object's path passes through a bone, the hold's growth is not asserted (no penetration-free skin).
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

import physhand_mj as ph
from physhand_mj.bench.cases import Case, press_case
from physhand_mj.types import GeomType
from stress_harness import Stress, press_schedule

CYCLE = 100
BALL = Case("ball", GeomType.SPHERE, (0.005, 0.0, 0.0), lead=0.005, site="palm", start=0.01)


def _soak(scene, cycles):
    run = Stress(scene, ph.Config(device="cpu"), BALL)
    q0, q1 = scene.open, 0.5 * (scene.open + scene.key("power"))
    depth = press_schedule(0.003, -0.01, 30, 30, 30, 10, away=0.01)
    ends, held = [], []
    for c in range(cycles):
        for f in range(CYCLE):
            a = min((f + 1) / 30, 1.0) if f < 60 else max(1.0 - (f - 59) / 30, 0.0)
            measure = f in (45, 59, CYCLE - 1) or cycles <= 2  # the measures cost ~15 ms: sample them in long runs
            run.frame(depth=depth[f], qpos=q0 + a * (q1 - q0), measure=measure)
        ends.append(run.state.x.numpy()[: scene.asset.n_skin].astype(float).copy())
        r = run.rows
        held.append([max(r[k][c * CYCLE + 45], r[k][c * CYCLE + 59]) for k in
                     ("skin_count", "skin_max_um", "obj_count", "obj_max_um")])
    return run, np.array(ends), np.array(held)


def _check_soak(run, ends, held, margins, cycles):
    free = [c * CYCLE + CYCLE - 1 for c in range(cycles)]
    out = run.check(volume_tol=0.02)
    r = run.arrays()
    assert (r["inverted"][free] == 0).all(), f"inverted at cycle ends: {r['inverted'][free].tolist()}"
    assert np.nansum(r["skin_count"][free]) == 0 and np.nansum(r["obj_count"][free]) == 0, run.report()
    drift = np.linalg.norm(ends - ends[0], axis=2).max(axis=1) * 1e3
    assert drift.max() <= 0.5, f"the skin drifts from cycle to cycle (mm): {drift.round(3).tolist()}"
    first, last = held[0], held[-max(1, cycles // 10):].max(axis=0)
    assert last[0] <= first[0] + 2 and last[2] <= first[2] + 2, f"held counts grow: {held.tolist()}"
    assert last[1] <= first[1] + 20 and last[3] <= first[3] + 20, f"held depths grow: {held.tolist()}"
    margins.update(out, case=f"soak: {cycles} cycles x {CYCLE} frames", drift_mm=round(float(drift.max()), 4),
                   drift_bound_mm=0.5, held_first=held[0].round(1).tolist(), held_last=last.round(1).tolist(),
                   inverted_cycle_end=int(r["inverted"][free].max()))


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_soak_short(scene, margins):
    run, ends, held = _soak(scene, 2)
    _check_soak(run, ends, held, margins, 2)


@pytest.mark.soak
def test_soak_10000_frames(scene, margins):
    run, ends, held = _soak(scene, 100)
    _check_soak(run, ends, held, margins, 100)


KINDS = {
    "sphere": lambda site: Case("sphere", GeomType.SPHERE, (0.006, 0, 0), lead=0.006, site=site),
    "capsule": lambda site: Case("capsule", GeomType.CAPSULE, (0.003, 0.01, 0), lead=0.003, site=site, lay=True),
    "box": lambda site: Case("box", GeomType.BOX, (0.008, 0.006, 0.004), lead=0.004, site=site),
    "cone_tip": lambda site: press_case("cone_tip", site=site),
    "knife": lambda site: press_case("knife", site=site),
    "plate": lambda site: press_case("plate", site=site),
}


# frames (5 ms) to pose in: 20 frames is at most 15.7 rad/s on the widest joint range (1.57 rad), the
# speed of a fast human finger. Posing in 6 frames (52 rad/s) stopped the bones so abruptly that the
# flesh lost 22 % of its volume for two frames with or without the object (measured at 72 % toward
# the lower limits; docs/stability.md), beyond the 10 % bound, a response to the pose, not the contact.
POSE_FRAMES = 20
SETTLE = 8  # frames (5 ms) both runs rest, the object away, before the inverted tets are compared
NEAR_M = 0.015  # m: the tets "where the contact was" (objects here are <= 16 mm across)


def _inverted(x, tets):
    a, b, c, d = (x[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) <= 0.0


def _random_case(scene, margins, fraction, corner, kind, site, depth, spin):
    import dataclasses

    target = scene.open + fraction * (scene.lo + np.asarray(corner) * (scene.hi - scene.lo) - scene.open)
    case = dataclasses.replace(KINDS[kind](site), spin=spin, start=0.02)
    run = Stress(scene, ph.Config(device="cpu"), case)
    for f in range(POSE_FRAMES):  # pose in, the object 20 mm away
        run.frame(depth=-0.02, qpos=scene.open + (f + 1) / POSE_FRAMES * (target - scene.open))
    sched = press_schedule(depth, -0.02, 5, 6, 2, 3, away=0.1)  # 100 mm: in a curled pose 20 mm can touch a finger
    held = None
    for d in sched:
        run.frame(depth=d)
        if held is None and d == depth:
            held = run.pos.copy()  # the object's centre while it is held (world, m)
    r = run.arrays()
    # the same poses without the object (the reference run, also for the inverted tets below)
    ref = Stress(scene, ph.Config(device="cpu"))
    for f in range(POSE_FRAMES):
        ref.frame(qpos=scene.open + (f + 1) / POSE_FRAMES * (target - scene.open))
    for _ in sched:
        ref.frame()
    # a pose near the joint limits dips the flesh's volume by itself when its bones stop (up to 11 % for
    # a frame, docs/stability.md; 10.6 % at 99 % toward every lower limit, found 2026-11-27 with the box
    # never touching): the bound is 10 % or the reference's dip and 2 % more
    ref_dip = float(np.abs(ref.arrays()["volume"]).max())
    # a random object path can pass through a bone of a curled finger on its way to the site: then no
    # penetration-free skin exists (the skin is caught between bone and object, or crossed with it),
    # and as for the objects started 20 mm inside (test_stress_fast) only finite, bounded, volume and
    # nothing left once away are asserted, not the hold's growth
    bone_hit = int(r["bones_in"].max())
    out = run.check(volume_tol=max(0.10, ref_dip + 0.02), carried_mm=50.0, grow_count=10, grow_um=100.0,
                    hold=None if bone_hit else (POSE_FRAMES + 5, POSE_FRAMES + 11))
    out.update(bones_inside_max=bone_hit, volume_reference_pct=round(ref_dip * 100, 3))
    # "no tet left inverted once the contact ends", where the contact was: a curled pose inverts
    # crease tets by itself (up to ~200 at 80 % toward the limits, measured), and their count flickers
    # by +-10 % frame to frame while the hand settles, anywhere in the hand. So the reference is the
    # same poses without the object, as many frames, and the check is local: of the tets with a vertex
    # within NEAR_M of the held object's centre, after SETTLE more frames for both, the fewest inverted
    # over the last 4 frames at most the most the reference shows over its last 4 (the crease tets
    # flicker: which ones and how many differ between any two runs by ~2 of ~2,000, measured)
    tets = run._tets
    near = (np.linalg.norm(run.state.x.numpy().astype(float)[tets] - held, axis=2) < NEAR_M).any(axis=1)
    counts = {"run": [], "ref": []}
    for _ in range(SETTLE):  # both settle, the object away; the near counts of the last 4 frames
        for key, s_ in (("run", run), ("ref", ref)):
            s_.frame(measure=False)
            counts[key].append(int((_inverted(s_.state.x.numpy().astype(float), tets) & near).sum()))
    n_run, n_ref = min(counts["run"][-4:]), max(counts["ref"][-4:])
    assert n_run <= n_ref, (f"tets within {NEAR_M * 1e3:.0f} mm of the object inverted after it left: {counts['run']}, "
                            f"the same poses without it {counts['ref']} (of {int(near.sum())} tets): {run.report()}")
    out.update(tets_near=int(near.sum()), inverted_near_after=counts["run"], inverted_near_reference=counts["ref"])
    assert np.nansum(r["skin_count"][-2:]) == 0 and np.nansum(r["obj_count"][-2:]) == 0, run.report()
    key = f"{kind} {site} depth {depth * 1e3:.1f} mm pose {fraction:.2f}"
    margins.setdefault("examples", {})[key] = out


CASES = dict(fraction=st.floats(0.0, 1.0), corner=st.lists(st.floats(0.0, 1.0), min_size=23, max_size=23),
             kind=st.sampled_from(sorted(KINDS)), site=st.sampled_from(["fingertip", "palm"]),
             depth=st.floats(0.0, 0.005), spin=st.floats(0.0, np.pi))
SLOW = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large]


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
@settings(max_examples=3, deadline=None, derandomize=True, database=None, suppress_health_check=SLOW)
@given(**CASES)
def test_random_pose_and_object(scene, margins, fraction, corner, kind, site, depth, spin):
    _random_case(scene, margins, fraction, corner, kind, site, depth, spin)


@pytest.mark.soak
@settings(max_examples=40, deadline=None, database=None, suppress_health_check=SLOW,
          phases=[Phase.explicit, Phase.generate])  # no shrinking: an example costs ~2 s
@given(**CASES)
# found by this test on 2026-11-23 (docs/stability.md, "Hypothesis"): the 1 mm plate 0.5 mm into the
# palm of a pose 61 % toward a random corner; 40-66 order-9 samples at ~0.48 mm (the plate's
# mid-plane) while held, growing 55 -> 66: on its way in the plate passed through a curled finger's
# bone (2 skeleton vertices inside it), so no penetration-free skin exists. Kept as an example.
@example(fraction=0.6056132857637325, corner=[0.0, 0.0, 0.11430900097648913, 0.08144265334704605, 0.37068416194517334,
                                              0.0, 0.0, 0.8816990747032782, 0.8186685344222648, 0.025, 0.2816241943685163,
                                              0.0, 0.11744433451788308, 0.0, 0.244388701195065, 0.8816990747032782,
                                              0.37068416194517334, 1.0, 0.4494698672480727, 0.6163852905854125,
                                              0.8005070693587055, 0.8830286248469998, 0.7667898417439865],
         kind="plate", site="palm", depth=0.0005, spin=1.7574914596466022)
# and a cone tip 1.6 mm into the palm of a pose 91 % toward a corner: 2 crease tets near it inverted
# at the end that the run without it did not invert (it inverted 24 others there): the flicker the
# settled comparison allows
@example(fraction=0.9111307161116691, corner=[0.35067035494425297, 0.14280202347641627, 0.3333314528, 0.0,
                                              0.07706074837901179, 0.5637528502481094, 0.4614267011448626,
                                              0.45757487923543116, 0.9436149048088234, 0.35846742604937437, 0.0,
                                              0.2927141761828856, 0.9173194950142127, 0.0028662257, 0.4233505597890127,
                                              0.0035, 0.7426187605677753, 0.5, 0.0, 0.09609655162192102,
                                              0.9135363080883572, 0.47098838368334006, 0.13590729560863804],
         kind="cone_tip", site="palm", depth=0.001596452722582931, spin=0.9564154343227714)
# found 2026-11-27: a pose 99 % toward every lower joint limit dips the flesh's volume 10.6 % for one frame
# as its bones stop, with the box at the fingertip never touching (the reference run dips the same)
@example(fraction=0.9856565839441895, corner=[0.0] * 23, kind="box", site="fingertip", depth=0.0, spin=0.0)
# and (known, not fixed) a box 1.8 mm into the palm of a pose at a corner of the joint limits: after it
# left, 1-2 of the 1,515 tets within 15 mm of it stayed inverted over the last 4 settled frames where
# the same poses without it ended with none (7, 6, 5, 2, 1, 2, 2, 2 against 2, 2, 1, 0, 0, 0, 0, 0);
# the same at the session's first commit (docs/stability.md)
@example(fraction=1.0, corner=[0.05431910454354251, 0.4794181465200896, 0.7227280365771603, 2.220446049250313e-16,
                                              0.7889038704941895, 0.9557469567381343, 1e-05, 1.192092896e-07,
                                              3.354982171374753e-265, 0.25, 0.5649441031062347, 0.99,
                                              0.3462234884607221, 1.175494351e-38, 1.7564478326707839e-35, 0.26844573821603596,
                                              2.0974829447850946e-67, 1.192092896e-07, 2.5311199458905614e-45, 0.11884384268338713,
                                              0.6975882581253791, 1.4022061836700555e-274, 0.29335251431374326],
         kind='box', site='palm', depth=0.0017624629569744923, spin=1.0).xfail(raises=AssertionError,
                                                                       reason="crease tets left inverted")
# and (known, not fixed) the 1 mm plate 3.8 mm into the palm of a pose 22 % toward a corner: one held frame
# with 29 order-9 samples up to 279 um inside and 7 check points, clean the frames before and after
# (the same at the session's first commit; docs/stability.md)
@example(fraction=0.22385958446249693, corner=[0.560489991871182, 0.6631885711529352, 0.4004507006285841, 0.0,
                                              0.29824300012372423, 1.0, 2.7118927224725378e-300, 0.7254019572792391,
                                              0.40443039470491915, 0.7680149143589079, 4.43542848281755e-124, 0.8511687512722153,
                                              0.4976141759365357, 0.4896558928155442, 5e-324, 0.7847293146468222,
                                              0.4880446011210814, 0.8712950773701829, 0.9439184022736937, 0.0641725379992606,
                                              0.0, 0.8263483876325219, 0.25177644170004837],
         kind='plate', site='palm', depth=0.0037772973312942214, spin=6.103515625e-05).xfail(raises=AssertionError,
                                                                       reason="a held frame's residue")
def test_random_pose_and_object_many(scene, margins, fraction, corner, kind, site, depth, spin):
    _random_case(scene, margins, fraction, corner, kind, site, depth, spin)
