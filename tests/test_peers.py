"""The CPU peer harness (benchmarks/peers): MuJoCo's flex scene is the body it was given, and the
penetration measures computed on a peer's vertices agree with an analytic case: a sphere of radius R
sunk d into the flat top of a soft block at rest."""

import sys
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "peers"))

from common import Measure, block_body, sphere_case  # noqa: E402
from mujoco_flex import FlexRun  # noqa: E402

from physhand_mj.types import Layer  # noqa: E402

R, DEPTH = 0.006, 0.001  # m
POS_TOL = 1e-9  # m: MuJoCo's vertex positions are the asset's (double precision, no transform)
DEPTH_TOL = 2e-6  # m: float32 positions of ~1 cm and the SDF
SAMPLE_GAP = 1e-4  # m: the sphere's 1 mm surface sampling misses its lowest point by at most (1 mm)^2 / 2R


@pytest.fixture(scope="module")
def block():
    return block_body(nx=6, ny=6, nz=3, spacing=0.004)


def lattice_reference(x, faces, centre, order):
    """Order-``order`` lattice samples of every triangle inside the sphere: count, deepest (m)."""
    pts = [x[faces[:, 0]] * (1 - i / order - j / order) + x[faces[:, 1]] * (i / order) + x[faces[:, 2]] * (j / order)
           for i in range(order + 1) for j in range(order + 1 - i)]
    phi = np.linalg.norm(np.concatenate(pts) - centre, axis=1) - R
    return int(np.sum(phi < 0)), float(-phi.min())


def test_flex_scene_is_the_body_and_steps(block):
    case = sphere_case(radius=R, depth=DEPTH)
    run = FlexRun(block, case, frames=2)
    m = run.model
    movable = int(np.sum(block.layer != Layer.SKELETON))
    assert (m.nflex, m.flex_dim[0], m.nflexvert, m.nflexelem) == (1, 3, block.n_vertices, len(block.tets))
    assert m.nv == 3 * movable, f"{m.nv} dofs for {movable} movable vertices"
    assert m.geom("object").type == mujoco.mjtGeom.mjGEOM_SPHERE
    err = np.abs(run.x - block.positions).max()
    assert err < POS_TOL, f"flex vertices off the body's rest positions by {err} m"
    for k in range(2):  # the object approaches from 2 mm outside: no contact yet, nothing moves but gravity
        out = run.frame(k)
        assert out["finite"] and not out["unstable"], out
    np.testing.assert_allclose(run.data.mocap_pos[0], run.path[1], atol=1e-12)


def test_measures_on_peer_vertices_match_the_analytic_sphere(block):
    case = sphere_case(radius=R, depth=DEPTH)
    measure = Measure(block, case)
    run = FlexRun(block, case, frames=1)
    x = run.x  # the flex's vertices, at rest
    centre = np.array([0.0, 0.0, R - DEPTH])  # lowest point DEPTH below the top face (z = 0) at a vertex
    quat = np.array([1.0, 0.0, 0.0, 0.0])
    got = measure(x, centre, quat)

    faces = np.asarray(block.skin_faces)
    for order, key in ((5, "skin"), (9, "dense")):
        count, deepest = lattice_reference(x, faces, centre, order)
        assert got[f"{key}_count"] == count, f"order {order}: {got[f'{key}_count']} samples inside, numpy {count}"
        assert abs(got[f"{key}_max_um"] * 1e-6 - DEPTH) < DEPTH_TOL, f"order {order}: {got[f'{key}_max_um']} um"
        assert abs(deepest - DEPTH) < DEPTH_TOL  # the lead vertex is a sample: the reference sees d too

    # object side: the sphere's surface points inside the block (a box: z in (-h, 0), |x|, |y| < w),
    # depth = distance to the nearest face
    objs = measure.solver.contact.points
    p = objs.pts_host + centre  # geom frame = world (identity rotation)
    lo, hi = x[:, :].min(0), x[: block.n_skin].max(0)
    lo[2] = x[: block.n_skin, 2].min()
    inside = np.all((p > lo) & (p < hi), axis=1)
    depth = np.minimum(p - lo, hi - p).min(axis=1)[inside]
    assert got["obj_count"] == int(inside.sum()), f"{got['obj_count']} object points inside, box test {inside.sum()}"
    assert abs(got["obj_max_um"] * 1e-6 - depth.max()) < DEPTH_TOL, (got["obj_max_um"], depth.max() * 1e6)
    assert DEPTH - SAMPLE_GAP < got["obj_max_um"] * 1e-6 <= DEPTH + DEPTH_TOL, got["obj_max_um"]

    # and nothing is reported once the sphere is lifted clear
    clear = measure(x, centre + [0.0, 0.0, DEPTH + 1e-4], quat)
    assert clear["skin_count"] == clear["dense_count"] == clear["obj_count"] == 0, clear
