"""The held-out check (issue 51, item 3): random objects at random skin sites and depths
(physhand_mj/bench/heldout.py), run as a stress test by four measures; and the generator itself
(reproducible by seed, closed meshes, placements where it says, the bones' clearance right).

The quick tests need no solver; ``test_heldout_pass_rate`` is marked slow (12 cases x 20 frames,
~30 s on the CPU): ``pytest -m slow tests/test_heldout.py``. benchmarks/heldout.py runs the same
generator over more cases (docs/contact.md, "Held-out objects").
"""

import warnings

import numpy as np
import pytest
import trimesh

import physhand_mj as ph
from physhand_mj.bench import heldout
from physhand_mj.bench.cases import Case, case_frame, case_position, run_case, site_point
from physhand_mj.contact import Objects
from physhand_mj.contact.surface import primitive_points
from physhand_mj.rotations import quat_to_mat
from physhand_mj.types import GeomType

SEED = 0
STRESS_CASES = 12  # the first 12 cases of benchmarks/heldout.py's seed 0: every kind at least once
STRESS_FRAMES = 20  # pressed over 10, held 10
# Measured on the CPU (2026-11-29, main at 9a77111; docs/benchmarks/heldout_cpu.json): Config() passes
# all 12 (a CPU run is one fixed path), and 178 of the 187 feasible cases of seed 0's first 200 (95 %);
# the paper's contact (no feature push, no side-aware exits, no tether) passes 1 of the 12. A contact
# change moves the held contact onto other paths: at 95 % per case, fewer than 10 of 12 pass on ~2 %
# of them, while a broken contact passes a few.
STRESS_MIN_PASSED = 10


@pytest.fixture(scope="module")
def asset():
    return ph.load_asset()


@pytest.fixture(scope="module")
def sites(asset):
    return heldout.skin_sites(asset)


def _draw(asset, sites, seed, i):
    return heldout.draw_case(seed, i, asset, sites)


def test_generator_is_reproducible_by_seed(asset, sites):
    a = [_draw(asset, sites, SEED, i) for i in range(len(heldout.KINDS))]
    b = [_draw(asset, sites, SEED, i) for i in range(len(heldout.KINDS))]
    c = [_draw(asset, sites, SEED + 1, i) for i in range(len(heldout.KINDS))]
    for x, y, z in zip(a, b, c):
        assert x.kind == y.kind == z.kind and x.shape == y.shape and x.vertex == y.vertex
        assert x.case.depth == y.case.depth and np.array_equal(x.case.turn, y.case.turn)
        if x.case.vertices is not None:
            assert np.array_equal(x.case.vertices, y.case.vertices) and np.array_equal(x.case.faces, y.case.faces)
        assert (x.vertex, x.case.depth) != (z.vertex, z.case.depth), "another seed draws other cases"
    # case i does not depend on how many are drawn: generate(seed, 12) is generate(seed, 40)'s head
    assert [h.label for h in heldout.generate(SEED, 2, asset)] == [h.label for h in a[:2]]


def test_generator_draws_closed_meshes_the_contact_takes_as_they_are():
    # 16 draws of every kind: closed, consistently wound, outward (positive volume), and Objects.add
    # neither repairs (it warns when it does) nor rejects them
    objs = Objects("cpu", 16 * len(heldout.KINDS))
    shapes = set()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for i in range(16):
            for kind in heldout.KINDS:
                label, gtype, size, v, f, _ = heldout.draw_object(kind, np.random.default_rng([SEED, i]))
                shapes.add(label.split()[0])
                if gtype != GeomType.MESH:
                    objs.add(gtype, size, name=label)
                    continue
                m = trimesh.Trimesh(v, f, process=False)
                assert m.is_watertight and m.is_winding_consistent and m.volume > 0, (kind, label)
                objs.add(GeomType.MESH, None, vertices=v, faces=f, name=label, mesh_grid_spacing=0.0)
    # every family of the issue: hulls, dented spheres, star prisms, tori, box and mesh plates,
    # capsules and cylinders, shells, analytic and mesh cones, wedges
    assert {"hull", "dented", "star", "torus", "box", "mesh", "capsule", "cylinder", "shell", "cone",
            "wedge"} <= shapes, shapes


def test_generator_places_the_deepest_point_at_the_drawn_depth(asset, sites):
    # the object's deepest point along the site's inward normal ends case.depth below the skin point
    # (the lead from the support function is right through the spin, tilt and base turns)
    for i in range(2 * len(heldout.KINDS)):
        h = _draw(asset, sites, SEED, i)
        c = h.case
        p0, n, quat = case_frame(c, asset)
        pos = case_position(c, p0, n, c.depth)
        if c.gtype == GeomType.MESH:
            pts, tol = c.vertices, 1e-9
        else:  # points on the analytic surface: its support point lies between them
            pts, tol = primitive_points(c.gtype, c.size, edge_spacing=1e-4, surface_spacing=2e-4)[0], 5e-5
        deepest = ((pts @ quat_to_mat(quat).T + pos - p0) @ -n).max()
        assert c.depth - tol <= deepest <= c.depth + 1e-9, (h.label, deepest, c.depth)
        assert heldout.DEPTH_MM[0] <= c.depth * 1e3 <= heldout.DEPTH_MM[1]
        assert c.start == (-c.depth if h.embedded else heldout.PRESS_START_MM * 1e-3)


def _bones_ref(asset):
    return heldout.bone_points(asset)


def test_feasibility_rule_on_two_analytic_placements(asset):
    """A sphere 0.5 mm into the palm leaves the bones clear (feasible); a 1 mm plate pressed face first
    and tilted 20 degrees 8 mm into the fingertip holds the distal phalanx (infeasible). Both
    clearances are the analytic SDFs' (numpy) over the same bone points."""
    bones = _bones_ref(asset)
    r = 0.006
    ball = Case("ball", GeomType.SPHERE, (r, 0.0, 0.0), lead=r, site="palm", depth=0.5e-3)
    p0, n = site_point(asset, "palm")
    centre = p0 - n * 0.5e-3 + n * r
    ref = (np.linalg.norm(bones - centre, axis=1) - r).min() * 1e3
    got = heldout.clearance_mm(ball, asset, bones)
    assert abs(got - ref) < 2e-3 and got > heldout.CLEARANCE_MM, (got, ref)  # float32: ~um

    half = np.array([0.01, 0.008, 0.0005])
    turn = heldout._quat_axis([1.0, 1.0, 0.0], np.radians(20.0))
    d = quat_to_mat(turn).T @ [0.0, 0.0, 1.0]
    plate = Case("plate", GeomType.BOX, tuple(half), lead=heldout.support(GeomType.BOX, half, None, d),
                 site="fingertip", depth=8e-3, turn=turn)
    p0, n, quat = case_frame(plate, asset)
    pos = case_position(plate, p0, n, plate.depth)
    q = (bones - pos) @ quat_to_mat(quat)  # the bone points in the box's frame
    out = np.abs(q) - half
    sdf = np.linalg.norm(np.maximum(out, 0.0), axis=1) + np.minimum(out.max(axis=1), 0.0)
    got = heldout.clearance_mm(plate, asset, bones)
    assert abs(got - sdf.min() * 1e3) < 2e-3 and got < 0.0, (got, sdf.min() * 1e3)

    h = heldout.Heldout(plate, "plate", "test", 0, "distph2_r", False, got)
    assert not h.feasible and heldout.Heldout(ball, "x", "x", 0, "x", False, heldout.CLEARANCE_MM).feasible


def test_verdict_counts_held_frames_and_every_measure():
    h = heldout.Heldout(Case("x", GeomType.SPHERE, (0.005, 0, 0), press_frames=3), "convex", "x", 0, "x", False)
    zero = {k: np.zeros(6) for _, c, d in heldout.MEASURES for k in (c, d)}
    rows = dict(zero, ms=np.ones(6), max_disp_mm=np.ones(6), finite=True)
    assert heldout.verdict(h, rows)["passed"]
    pressing = dict(rows, dense_count=np.array([5, 9, 1, 0, 0, 0]), dense_max_um=np.array([50.0, 90, 1, 0, 0, 0]))
    assert heldout.verdict(h, pressing)["passed"], "frames before the hold do not count"
    held = dict(rows, check_count=np.array([0, 0, 0, 0, 2, 0]), check_max_um=np.array([0, 0, 0, 0, 3.5, 0]))
    v = heldout.verdict(h, held)
    assert not v["passed"] and v["failed"] == ["check"] and v["measures"]["check"]["held_max_um"] == 3.5
    assert heldout.verdict(h, dict(rows, finite=False))["failed"] == ["nonfinite"]


@pytest.mark.slow
def test_heldout_pass_rate(asset):
    cases = heldout.generate(SEED, STRESS_CASES, asset)
    assert {h.kind for h in cases} == set(heldout.KINDS)
    verdicts = []
    for h in cases:
        r = run_case(h.case, ph.Config(device="cpu"), frames=STRESS_FRAMES, asset=asset)
        v = heldout.verdict(h, r)
        verdicts.append((h, v))
        assert v["finite"], f"{h.label}: not finite"
    feasible = [(h, v) for h, v in verdicts if h.feasible]
    failed = [f"{h.label}: {v['failed']} {v['measures']}" for h, v in feasible if not v["passed"]]
    assert len(feasible) - len(failed) >= STRESS_MIN_PASSED * len(feasible) / STRESS_CASES, "\n".join(failed)
