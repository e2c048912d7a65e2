"""Mesh SDFs against exact references at sharp edges and tips (issue 11): the sign is right on both
sides of 30-degree knife edges and cone tips, on open meshes (winding number) and after the
orientation repairs of ``Objects.add``; bad meshes are refused with the fix in the message.

References (float64): the distance is a brute-force point-triangle distance over all faces; the
sign of a convex polyhedron is the maximum of its face-plane functions (its value is the inside
distance), of the star prism a 2D point-in-polygon test, of open meshes the closed mesh's."""

import warnings

import numpy as np
import pytest
import trimesh
import warp as wp

from physhand_mj.contact import Objects
from physhand_mj.contact.broadphase import triangle_bound
from physhand_mj.contact.sdf import (MESH_SIGN_PSEUDO, MESH_SIGN_PSEUDO_NEAR, MESH_SIGN_WINDING, geom_sdf, geom_sdf_grad,
                                     face_rounding, mesh_face_closest, mesh_near_closest, mesh_near_faces, mesh_near_ids, sdf_mesh_near)
from physhand_mj.types import GeomType

DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])
SIGN_BAND = 1e-6  # m: sign errors are only allowed this close to the surface (float32 rounding)
DIST_TOL = 1e-7  # m: |phi| against the float64 distance, for objects of a few centimetres
STEP = 1e-5  # m: step along the gradient in the outward test


@wp.kernel
def _eval(size: wp.vec3, mesh: wp.vec2ul, p: wp.array(dtype=wp.vec3),
          phi: wp.array(dtype=float), grad: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    d, g = geom_sdf_grad(int(GeomType.MESH), p[i], size, mesh)
    phi[i] = geom_sdf(int(GeomType.MESH), p[i], size, mesh)  # (the value query: the grid's where it has one)
    grad[i] = g


def mesh_sdf(mesh, points, device="cpu", grid=False, **kw):
    """(phi, grad, sign method) of ``mesh`` added to an ``Objects``, at ``points`` (geom frame): the
    exact BVH query everywhere, or with ``grid`` the query the contact runs (the mesh's distance grid
    answering the points it proves farther than sdf.GRID_BAND outside)."""
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name="m", mesh_range=1.0, **kw)
    n = len(points)
    phi = wp.full(n, np.inf, dtype=float, device=device)
    grad = wp.zeros(n, dtype=wp.vec3, device=device)
    size = objs._host["size"][0]
    ids = objs._host["mesh"][0]
    wp.launch(_eval, n, inputs=[wp.vec3(*size), wp.vec2ul(int(ids[0]), int(ids[1]) if grid else 0),
                                wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=device)],
              outputs=[phi, grad], device=device)
    method = int(size[1])  # (MESH_SIGN_PSEUDO_NEAR signs as MESH_SIGN_PSEUDO does)
    return phi.numpy().astype(float), grad.numpy().astype(float), MESH_SIGN_PSEUDO if method == MESH_SIGN_PSEUDO_NEAR else method


# -- exact references ----------------------------------------------------------------------------

def point_triangle_distance(p, a, b, c):
    """Distance (float64) from points p (n, 3) to triangles (a, b, c) (n, 3 each): the minimum over
    the triangle's candidate closest points (interior projection where it falls inside, the three
    edge projections, the vertices)."""
    ab, ac, bc = b - a, c - a, c - b
    nrm = np.cross(ab, ac)
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = p - ((p - a) * nrm).sum(1, keepdims=True) * nrm / (nrm * nrm).sum(1, keepdims=True)
        inside = np.ones(len(p), bool)
        for x, y in ((a, b), (b, c), (c, a)):
            inside &= (np.cross(y - x, proj - x) * nrm).sum(1) >= 0
        cands = [np.where(inside[:, None], proj, a)]
        for x, e in ((a, ab), (a, ac), (b, bc)):
            t = np.clip(((p - x) * e).sum(1) / (e * e).sum(1), 0, 1)
            cands.append(x + np.nan_to_num(t)[:, None] * e)
    cands += [a, b, c]
    return np.min([np.linalg.norm(p - q, axis=1) for q in cands], axis=0)


def unsigned_distance(mesh, p):
    tri = np.asarray(mesh.triangles, float)
    pp = np.repeat(p, len(tri), axis=0)
    t = np.tile(tri, (len(p), 1, 1))
    return point_triangle_distance(pp, t[:, 0], t[:, 1], t[:, 2]).reshape(len(p), len(tri)).min(1)


def convex_sdf(mesh, p):
    """Signed distance to a convex polyhedron: max of the face-plane functions inside."""
    plane = np.einsum("pfk,fk->pf", p[:, None, :] - mesh.triangles[None, :, 0], mesh.face_normals)
    inside = plane.max(1) <= 0
    return np.where(inside, plane.max(1), unsigned_distance(mesh, p))


# -- shapes with sharp features --------------------------------------------------------------------

def wedge(angle_deg=30.0, depth=0.04, length=0.04):
    """Triangular prism: a knife edge of ``angle_deg`` along x through the origin, body below it."""
    h = np.tan(np.radians(angle_deg) / 2) * depth
    v = [[x, y, z] for x in (-length / 2, length / 2) for y, z in ((0, 0), (-h, -depth), (h, -depth))]
    f = [[0, 2, 1], [3, 4, 5], [0, 4, 3], [0, 1, 4], [1, 5, 4], [1, 2, 5], [2, 3, 5], [2, 0, 3]]
    return trimesh.Trimesh(v, f)


def cone(apex_deg=30.0, height=0.04, sections=32):
    return trimesh.creation.cone(radius=np.tan(np.radians(apex_deg) / 2) * height, height=height, sections=sections)


CONVEX = {
    "box": lambda: trimesh.creation.box(extents=[0.06, 0.04, 0.02]),
    "cone30_tip": cone,
    "wedge30_knife": wedge,
    "icosphere0": lambda: trimesh.creation.icosphere(subdivisions=0, radius=0.03),
    "hull40": lambda: trimesh.convex.convex_hull(np.random.default_rng(0).normal(size=(40, 3)) * 0.03),
}


def star_prism(n=5, r_out=0.03, r_in=0.012, height=0.02):
    """Extruded 5-point star (36-degree tips, reflex notches): non-convex, exact inside test."""
    ang = np.arange(2 * n) * np.pi / n
    poly = np.c_[np.cos(ang), np.sin(ang)] * np.where(np.arange(2 * n) % 2, r_in, r_out)[:, None]
    fan = [[0, 1 + i, 1 + (i + 1) % (2 * n)] for i in range(2 * n)]
    mesh = trimesh.creation.extrude_triangulation(np.vstack([[0, 0], poly]), fan, height)
    mesh.apply_translation([0, 0, -height / 2])
    return mesh, poly, height


def inside_star(p, poly, height):
    inside = np.abs(p[:, 2]) < height / 2
    crossing = np.zeros(len(p), bool)
    for a, b in zip(poly, np.roll(poly, -1, 0)):
        straddle = (a[1] > p[:, 1]) != (b[1] > p[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a[0] + (p[:, 1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        crossing ^= straddle & (p[:, 0] < x)
    return inside & crossing


def near_features(mesh, n_edge=1500, n_vertex=500, seed=1):
    """Points 0.01-2 mm (log-uniform) from the sharp edges (perpendicular to the edge, any side) and
    from the vertices (any direction): inside and outside, around every edge and tip."""
    rng = np.random.default_rng(seed)
    radius = lambda k: np.exp(rng.uniform(np.log(1e-5), np.log(2e-3), (k, 1)))  # noqa: E731
    edges = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(1.0)]
    e = edges[rng.integers(len(edges), size=n_edge)]
    a, b = mesh.vertices[e[:, 0]], mesh.vertices[e[:, 1]]
    axis = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    d = rng.normal(size=(n_edge, 3))
    d -= (d * axis).sum(1, keepdims=True) * axis
    on_edge = a + rng.uniform(0, 1, (n_edge, 1)) * (b - a)
    tips = mesh.vertices[np.unique(edges)]
    dv = rng.normal(size=(n_vertex, 3))
    near_tips = tips[rng.integers(len(tips), size=n_vertex)]
    return np.concatenate([on_edge + radius(n_edge) * d / np.linalg.norm(d, axis=1, keepdims=True),
                           near_tips + radius(n_vertex) * dv / np.linalg.norm(dv, axis=1, keepdims=True)])


def samples(mesh, seed=1):
    rng = np.random.default_rng(seed)
    box = rng.uniform(mesh.bounds[0] - 0.005, mesh.bounds[1] + 0.005, (500, 3))
    return np.concatenate([near_features(mesh, seed=seed), box])


def assert_signed_distance(phi, want_sign, want_dist, what):
    sure = want_dist > SIGN_BAND
    wrong = sure & (np.sign(phi) != want_sign)
    assert not wrong.any(), (f"{what}: {wrong.sum()} sign errors, e.g. phi {phi[wrong][:3]} at distance "
                             f"{want_dist[wrong][:3]} (want sign {want_sign[wrong][:3]})")
    err = np.abs(np.abs(phi) - want_dist)
    assert err.max() < DIST_TOL, f"{what}: |phi| off by {err.max() * 1e6:.4f} um (tol {DIST_TOL * 1e6} um)"


# -- closed meshes: sign at edges and tips -----------------------------------------------------------

@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("shape", sorted(CONVEX))
def test_convex_meshes_match_the_exact_sdf_at_edges_and_tips(shape, device):
    mesh = CONVEX[shape]()
    p = samples(mesh)
    want = convex_sdf(mesh, p)
    phi, grad, method = mesh_sdf(mesh, p, device)
    assert method == MESH_SIGN_PSEUDO, "a closed mesh takes the pseudo-normal sign"
    assert (want < 0).sum() > 300 and (want > 0).sum() > 300, "samples on both sides"
    assert_signed_distance(phi, np.sign(want), np.abs(want), shape)


def test_nonconvex_star_prism_sign_at_tips_and_notches():
    mesh, poly, height = star_prism()
    p = samples(mesh)
    phi, _, _ = mesh_sdf(mesh, p)
    want_sign = np.where(inside_star(p, poly, height), -1.0, 1.0)
    assert_signed_distance(phi, want_sign, unsigned_distance(mesh, p), "star prism")


@pytest.mark.parametrize("shape", ["cone30_tip", "wedge30_knife", "box"])
def test_gradient_is_unit_and_points_outward(shape):
    mesh = CONVEX[shape]()
    p = samples(mesh, seed=2)
    phi, grad, _ = mesh_sdf(mesh, p)
    away = np.abs(phi) > 2 * STEP
    assert np.abs(np.linalg.norm(grad, axis=1) - 1).max() < 1e-5
    stepped, _, _ = mesh_sdf(mesh, p[away] + STEP * grad[away])
    rise = stepped - phi[away]
    assert rise.min() > 0.5 * STEP, f"phi rose by {rise.min():.3e} m along the gradient (step {STEP} m)"
    # on the surface (vertices: the tip; edge midpoints; face centres): the (pseudo) normal, outward
    edges = mesh.edges_unique
    surface = np.concatenate([mesh.vertices, mesh.vertices[edges].mean(1), mesh.triangles_center])
    phi_s, grad_s, _ = mesh_sdf(mesh, surface)
    assert np.abs(phi_s).max() < 1e-8
    assert np.abs(np.linalg.norm(grad_s, axis=1) - 1).max() < 1e-5
    assert mesh_sdf(mesh, surface + STEP * grad_s)[0].min() > 0.5 * STEP * np.sin(np.radians(15))


# -- open, mis-wound and overlapping meshes ------------------------------------------------------------

def _open_cases():
    box = CONVEX["box"]()
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    tip = cone()
    return {
        "box_without_one_side": (box, box.faces[~np.isclose(box.face_normals[:, 0], -1)]),
        "icosphere_with_a_hole": (ico, np.delete(ico.faces, [5], 0)),
        "cone_without_base": (tip, tip.faces[tip.face_normals[:, 2] > -0.9]),
    }


@pytest.mark.parametrize("case", sorted(_open_cases()))
def test_open_meshes_take_the_winding_number_sign(case):
    closed, faces = _open_cases()[case]
    open_mesh = trimesh.Trimesh(closed.vertices, faces, process=False)
    assert not open_mesh.is_watertight
    p = samples(closed)
    phi, _, method = mesh_sdf(open_mesh, p)
    assert method == MESH_SIGN_WINDING
    assert_signed_distance(phi, np.sign(convex_sdf(closed, p)), unsigned_distance(open_mesh, p), case)


def _flipped(faces, rows):
    f = faces.copy()
    f[rows] = f[rows][:, ::-1]
    return f


@pytest.mark.parametrize("case, message", [
    ("inside_out", "inside-out faces outward"),
    ("two_faces_flipped", "winding consistent"),
    ("open_inside_out", "inward-facing faces outward"),
])
def test_misoriented_meshes_are_repaired_with_a_warning(case, message):
    box = CONVEX["box"]()
    faces = {"inside_out": box.faces[:, ::-1], "two_faces_flipped": _flipped(box.faces, [0, 5]),
             "open_inside_out": box.faces[~np.isclose(box.face_normals[:, 0], -1)][:, ::-1]}[case]
    mesh = trimesh.Trimesh(box.vertices, faces, process=False)
    p = samples(box)
    with pytest.warns(UserWarning, match=message):
        phi, _, _ = mesh_sdf(mesh, p)
    assert_signed_distance(phi, np.sign(convex_sdf(box, p)), unsigned_distance(mesh, p), case)


def test_overlapping_parts_are_a_union():
    """Two closed boxes that intersect, in one mesh: inside either is inside (w = 2 where both)."""
    a = trimesh.creation.box(extents=[0.04, 0.02, 0.02])
    b = trimesh.creation.box(extents=[0.02, 0.04, 0.02])
    b.apply_translation([0.005, 0.005, 0.004])
    mesh = trimesh.util.concatenate([a, b])
    p = np.concatenate([near_features(a, 500, 200), near_features(b, 500, 200)])
    phi, _, method = mesh_sdf(mesh, p)
    assert method == MESH_SIGN_WINDING
    want = np.minimum(convex_sdf(a, p), convex_sdf(b, p))  # exact sign of the union
    assert_signed_distance(phi, np.sign(want), unsigned_distance(mesh, p), "two overlapping boxes")
    b.apply_translation([0.05, 0.0, 0.0])  # apart: the pseudo normal stays exact
    assert mesh_sdf(trimesh.util.concatenate([a, b]), p[:10])[2] == MESH_SIGN_PSEUDO


def test_degenerate_faces_and_triangle_soup_do_not_matter():
    box = CONVEX["box"]()
    soup = box.vertices[box.faces].reshape(-1, 3)  # an STL's unmerged vertices
    faces = np.arange(len(soup)).reshape(-1, 3)
    faces = np.vstack([faces, [[0, 0, 1], [2, 2, 2], [0, 3, 0]]])  # repeated vertices, zero area
    mesh = trimesh.Trimesh(soup, faces, process=False)
    p = samples(box)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing to repair
        phi, _, method = mesh_sdf(mesh, p)
    assert method == MESH_SIGN_PSEUDO
    assert_signed_distance(phi, np.sign(convex_sdf(box, p)), np.abs(convex_sdf(box, p)), "soup")


def test_forced_winding_sign_agrees_on_closed_meshes():
    mesh = CONVEX["wedge30_knife"]()
    p = samples(mesh)
    phi, _, method = mesh_sdf(mesh, p, mesh_sign="winding")
    assert method == MESH_SIGN_WINDING
    want = convex_sdf(mesh, p)
    assert_signed_distance(phi, np.sign(want), np.abs(want), "wedge, winding sign")


# -- meshes without an inside ----------------------------------------------------------------------

def test_meshes_without_an_inside_are_refused_with_the_fix():
    objs = Objects("cpu", 4)
    sheet = trimesh.Trimesh([[0, 0, 0], [0.05, 0, 0], [0.05, 0.05, 0], [0, 0.05, 0]], [[0, 1, 2], [0, 2, 3]])
    with pytest.raises(ValueError, match=r"mesh geom 'sheet' does not bound a region.*fill_holes.*thickness"):
        objs.add(GeomType.MESH, None, vertices=sheet.vertices, faces=sheet.faces, name="sheet")
    with pytest.raises(ValueError, match="'folded' does not bound a region"):  # both sides of the sheet
        objs.add(GeomType.MESH, None, vertices=sheet.vertices, faces=np.vstack([sheet.faces, sheet.faces[:, ::-1]]),
                 name="folded")
    with pytest.raises(ValueError, match="'folded1' is closed but encloses no volume.*thickness"):  # watertight
        objs.add(GeomType.MESH, None, vertices=sheet.vertices, faces=[[0, 1, 2], [0, 2, 1]], name="folded1")
    with pytest.raises(ValueError, match="'flat'.*degenerate"):
        objs.add(GeomType.MESH, None, vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]], name="flat")
    box = CONVEX["box"]()
    with pytest.raises(ValueError, match="mesh_sign"):
        objs.add(GeomType.MESH, None, vertices=box.vertices, faces=box.faces, name="b", mesh_sign="normal")
    assert len(objs) == 0, "refused meshes are not added"


@pytest.mark.parametrize("shape, half_mm", [
    ("plate", 0.5),    # a 1 mm plate: a wall, its half-thickness
    ("shell", 1.0),    # a closed 2 mm shell (two concentric spheres, the inner one inverted)
    ("sphere", 10.0),  # r 10 mm: its diameter's half (the fixed floor keeps acting: 0.1 x 10 mm > 0.5 mm)
    ("knife", 0.0),    # tapered (30-degree wedge): no wall, the fixed floor
])
def test_mesh_half_thickness_finds_walls_and_shells_only(shape, half_mm):
    """objects.mesh_half_thickness, the side-aware exit's floor for meshes (query.side_floor reads
    it from size[2]): against the analytic thickness of a plate, a shell and a sphere; 0 for a wedge."""
    from physhand_mj.cases import _wedge

    if shape == "plate":
        m = trimesh.creation.box(extents=(0.024, 0.024, 0.001))
    elif shape == "shell":
        outer, inner = trimesh.creation.icosphere(4, 0.012), trimesh.creation.icosphere(4, 0.010)
        inner.invert()
        m = trimesh.util.concatenate([outer, inner])
    elif shape == "sphere":
        m = trimesh.creation.icosphere(4, 0.010)
    else:
        m = trimesh.Trimesh(*_wedge())
    objs = Objects("cpu", 1)
    objs.add(GeomType.MESH, None, vertices=m.vertices, faces=m.faces, name=shape, mesh_range=0.05)
    half = float(objs.size.numpy()[0, 2]) * 1e3
    assert half == pytest.approx(half_mm, rel=0.03, abs=1e-9), half


@pytest.mark.parametrize("shape", ["icosphere0", "wedge30_knife"])
@pytest.mark.parametrize("device", DEVICES)
def test_the_distance_grid_answers_only_far_points_with_a_lower_bound(shape, device):
    """objects.mesh_grid: the query the contact runs equals the exact BVH query bit for bit wherever
    that is below sdf.GRID_BAND (inside, on and near the surface); farther out it may answer a lower
    bound (never above the exact distance, never below the band, within the grid's node diagonal)
    without the BVH walk, which it does for most far points; off the grid (more than GRID_PAD out of
    the mesh's box) it answers GRID_PAD, again a lower bound."""
    from physhand_mj.contact.objects import GRID_PAD
    from physhand_mj.contact.sdf import GRID_BAND

    mesh = CONVEX[shape]()
    rng = np.random.default_rng(11)
    surf = trimesh.sample.sample_surface(mesh, 3000, seed=1)[0]
    lo, hi = mesh.bounds[0] - GRID_PAD, mesh.bounds[1] + GRID_PAD
    p = np.concatenate([surf + rng.normal(0.0, 2e-3, surf.shape),  # near, both sides
                        rng.uniform(lo, hi, (3000, 3)),  # anywhere on the grid
                        rng.uniform(lo - 0.02, hi + 0.02, (1000, 3))])  # and off it
    exact, _, _ = mesh_sdf(mesh, p, device)
    fast, grad, _ = mesh_sdf(mesh, p, device, grid=True)
    near = exact < GRID_BAND
    assert near.sum() > 1500 and (~near).sum() > 3000
    np.testing.assert_array_equal(fast[near], exact[near])
    assert np.all(fast <= exact + 1e-7) and np.all(fast[~near] >= GRID_BAND * (1 - 1e-6))
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name="m")
    spacing = float(max(next(iter(objs._mesh_cache.values()))[-1].get_voxel_size()))
    assert spacing == pytest.approx(2e-3, rel=1e-4)
    on_grid = np.all((p > lo) & (p < hi), axis=1)
    gap = (exact - fast)[on_grid]  # (on the grid: within a node's reach of the exact distance)
    assert np.all(gap <= spacing * np.sqrt(3) + 1e-6), gap.max()
    answered = ~near & on_grid & (fast < exact - 1e-9)
    assert answered.sum() > 0.5 * (~near & on_grid).sum()
    off = ~np.all((p > lo - 5e-3) & (p < hi + 5e-3), axis=1)  # (the last node lies within a spacing past hi)
    assert off.sum() > 100
    np.testing.assert_allclose(fast[off], GRID_PAD, rtol=1e-6)
    assert np.all(exact[off] >= GRID_PAD)
    assert np.allclose(np.linalg.norm(grad, axis=1), 1.0, atol=1e-4)
    # an open mesh (winding-number sign) gets no grid: across a hole its inside is not bounded by faces
    open_box = trimesh.creation.box(extents=[0.03, 0.02, 0.01])
    open_box.faces = open_box.faces[2:]
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=open_box.vertices, faces=open_box.faces, name="open")
    assert int(objs._host["size"][0][1]) == MESH_SIGN_WINDING and int(objs._host["mesh"][0][1]) == 0


def test_a_contact_run_is_the_same_with_and_without_the_distance_grid():
    """Config.mesh_grid changes only the cost: a mesh cone pressed into the palm, a coarse mesh
    starting 4 mm deep at the fingertip end with the same skin, bit for bit (measured on all 16 mesh
    hard cases: docs/contact.md; the knife 20 mm through the fingertip: tests/stress)."""
    import physhand_mj as ph
    from physhand_mj.cases import press_case, run_case

    asset = ph.load_asset()
    for kind, site, depth, start, frames in (("mesh_cone", "palm", 0.004, 0.002, 6),
                                             ("coarse", "fingertip", 0.004, -0.004, 6)):
        skins = [run_case(press_case(kind, site=site, depth=depth, start=start),
                          ph.Config(device="cpu", mesh_grid=g), frames=frames, asset=asset)["skin"] for g in (0.0, 2e-3)]
        np.testing.assert_array_equal(skins[0], skins[1])
    with pytest.raises(ValueError, match="mesh_grid"):
        ph.Config(mesh_grid=-1e-3).validate()


@wp.kernel
def _near_lattice(size: wp.vec3, mesh: wp.uint64, tri: wp.array(dtype=wp.vec3), order: int,
                  exact: wp.array2d(dtype=float), near: wp.array2d(dtype=float), n_near: wp.array(dtype=int)):
    """Every point of an order-``order`` lattice on triangle t: the BVH query (geom_sdf, no grid) and
    the query over the triangle's near faces (sdf.mesh_near_faces / sdf_mesh_near, as query.py's
    decision points ask); n_near[t]: how many faces (-1: too many, the BVH then)."""
    t = wp.tid()
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    m, r = triangle_bound(a, b, c)
    ids, dist, n = mesh_near_faces(mesh, m, r, size[0])
    n_near[t] = n
    k = int(0)
    for i in range(order + 1):
        for j in range(order + 1 - i):
            u = float(i) / float(order)
            v = float(j) / float(order)
            p = a * (1.0 - u - v) + b * u + c * v
            exact[t, k] = geom_sdf(int(GeomType.MESH), p, size, wp.vec2ul(mesh, wp.uint64(0)))
            if n >= 0:
                near[t, k] = sdf_mesh_near(p, size, mesh, ids, dist, n, m)
            k += 1


def small_triangles(mesh, n, seed, spread=1.2e-3, depth=(-2e-3, 4e-3)):
    """``n`` random triangles of ~``spread`` (m) about points ``depth`` (m) off ``mesh``'s surface
    (negative: inside), and n / 4 more about its sharp edges and tips, both sides, where it has any."""
    rng = np.random.default_rng(seed)
    pts, fi = trimesh.sample.sample_surface(mesh, n, seed=seed)
    centres = pts + mesh.face_normals[fi] * rng.uniform(*depth, (n, 1))
    if (mesh.face_adjacency_angles > np.radians(1.0)).any():  # (a smooth mesh has none)
        centres = np.concatenate([centres, near_features(mesh, n_edge=n // 8, n_vertex=n // 8, seed=seed)])
    return (centres[:, None, :] + rng.normal(size=(len(centres), 3, 3)) * spread).astype(np.float32)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("shape", ["bowl", "wedge30_knife", "cone30_tip", "star", "hull40"])
def test_near_faces_answer_every_sample_as_the_bvh_does(shape, device):
    """The decision points' mesh query (sdf.mesh_near_faces, then sdf_mesh_near per lattice sample):
    the faces within d(m) + 2 r of a triangle's centroid hold every sample's closest face, and Warp's
    own leaf test over them returns the BVH query's phi (bit for bit but at exact ties), inside and outside, at knife
    edges, cone tips, a star's notches and the HOI bowl; a dense mesh overflows the capacity and
    falls back to the BVH, and Objects.add marks only meshes whose near faces are few
    (objects.near_faces_pay) for the decision points' search."""
    from physhand_mj.contact.sdf import MESH_NEAR_CAP
    from physhand_mj import scene_path

    if shape == "bowl":
        mesh = trimesh.load(scene_path("hoi_bowl").parent / "assets" / "bowl.stl")
    elif shape == "star":
        mesh = star_prism()[0]
    else:
        mesh = CONVEX[shape]()
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name="m", mesh_range=1.0)
    size = objs._host["size"][0]
    assert int(size[1]) in (MESH_SIGN_PSEUDO, MESH_SIGN_PSEUDO_NEAR)
    if shape in ("bowl", "wedge30_knife"):  # large faces beside the skin's: Objects.add marks them
        assert int(size[1]) == MESH_SIGN_PSEUDO_NEAR
    tri = small_triangles(mesh, 800, seed=3)
    order = 5
    k = (order + 1) * (order + 2) // 2
    exact = wp.zeros((len(tri), k), dtype=float, device=device)
    near = wp.full((len(tri), k), np.nan, dtype=float, device=device)
    n_near = wp.zeros(len(tri), dtype=int, device=device)
    wp.launch(_near_lattice, len(tri), [wp.vec3(*size), wp.uint64(int(objs._host["mesh"][0][0])),
                                        wp.array(tri.reshape(-1, 3), dtype=wp.vec3, device=device), order],
              [exact, near, n_near], device=device)
    n = n_near.numpy()
    used = n >= 0
    assert used.mean() > 0.6, f"only {used.mean():.0%} of the triangles found their near faces"  # (the cone: 79 %)
    assert n[used].max() <= MESH_NEAR_CAP and n[used].min() >= 1
    e, q = exact.numpy()[used], near.numpy()[used]
    assert (e < 0).sum() > 500 and (e > 0).sum() > 500  # inside and outside
    # equal but where two faces are equally close in exact arithmetic (across a shared edge: the BVH's
    # order or float box pruning may keep the other one, whose closest point rounds differently) or, on CUDA,
    # where the two codes' multiply-adds contract differently: then within a few nanometres
    off = q != e
    assert off.mean() < 1e-3, f"{off.sum()} of {off.size} samples differ"
    assert np.abs(q - e).max() <= 1e-8 and np.all(np.sign(q[np.abs(e) > 1e-8]) == np.sign(e[np.abs(e) > 1e-8]))
    # a dense sphere: more faces near a triangle than the capacity -> the BVH per sample (n = -1)
    dense = trimesh.creation.icosphere(subdivisions=6, radius=0.03)
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=dense.vertices, faces=dense.faces, name="d", mesh_range=1.0)
    tri = small_triangles(dense, 40, seed=4, spread=4e-3, depth=(0.0, 1e-3))
    n_near = wp.zeros(len(tri), dtype=int, device=device)
    wp.launch(_near_lattice, len(tri), [wp.vec3(*objs._host["size"][0]), wp.uint64(int(objs._host["mesh"][0][0])),
                                        wp.array(tri.reshape(-1, 3), dtype=wp.vec3, device=device), order],
              [wp.zeros((len(tri), k), dtype=float, device=device), wp.zeros((len(tri), k), dtype=float, device=device),
               n_near], device=device)
    assert (n_near.numpy() == -1).mean() > 0.9
    assert int(objs._host["size"][0][1]) == MESH_SIGN_PSEUDO  # and Objects.add leaves it to the BVH walk


@wp.func
def _plain_near(p: wp.vec3, size: wp.vec3, mesh: wp.uint64, ids: mesh_near_ids, n: int):
    """The near faces' closest face as first written: every listed face tested in order, the first
    strictly closest kept: (face or -1, u, v, squared distance)."""
    best = size[0] * size[0]
    face = int(-1)
    bu = float(0.0)
    bv = float(0.0)
    for k in range(n):
        d2, u, v = mesh_face_closest(mesh, ids[k], p)
        if d2 >= 0.0 and d2 < best:
            best = d2
            face = ids[k]
            bu = u
            bv = v
    return face, bu, bv, best


@wp.kernel
def _pruned_and_plain(size: wp.vec3, mesh: wp.uint64, tri: wp.array(dtype=wp.vec3), order: int,
                      pruned: wp.array2d(dtype=wp.vec4), plain: wp.array2d(dtype=wp.vec4), n_near: wp.array(dtype=int)):
    """(face, u, v, squared distance) of every order-``order`` lattice sample of triangle t by
    sdf.mesh_near_closest and by the plain loop."""
    t = wp.tid()
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    m, r = triangle_bound(a, b, c)
    ids, dist, n = mesh_near_faces(mesh, m, r, size[0])
    n_near[t] = n
    if n < 0:
        return
    k = int(0)
    for i in range(order + 1):
        for j in range(order + 1 - i):
            p = a * (1.0 - float(i + j) / float(order)) + b * (float(i) / float(order)) + c * (float(j) / float(order))
            f, u, v, d2 = mesh_near_closest(p, size, mesh, ids, dist, n, m)
            pruned[t, k] = wp.vec4(float(f), u, v, d2)
            f, u, v, d2 = _plain_near(p, size, mesh, ids, n)
            plain[t, k] = wp.vec4(float(f), u, v, d2)
            k += 1


def diagonal_triangles(mesh, n_per_edge=40, seed=5, spread=1.2e-3):
    """Small triangles centred on the flat edges of ``mesh`` (a box's face diagonals: two coplanar
    faces, every point above the edge equally close to both), 0-3 mm out."""
    rng = np.random.default_rng(seed)
    flat = mesh.face_adjacency_angles < 1e-6
    out = []
    for (v0, v1), (f0, _) in zip(mesh.face_adjacency_edges[flat], mesh.face_adjacency[flat]):
        a, b = mesh.vertices[v0], mesh.vertices[v1]
        for _ in range(n_per_edge):
            centre = a + (b - a) * rng.uniform(0.1, 0.9) + mesh.face_normals[f0] * rng.uniform(0.0, 3e-3)
            out.append(centre + rng.normal(size=(3, 3)) * spread)
    return np.asarray(out, np.float32)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("shape", ["bowl", "box", "star", "needle"])
def test_pruned_near_faces_answer_as_the_plain_loop(shape, device):
    """sdf.mesh_near_closest tests the face nearest the triangle's centre first and skips the faces its
    distance bound proves farther than the best so far: the same face, barycentrics and distance as
    testing every listed face in order, bit for bit, on the order-9 lattice, inside and outside;
    ties included (points over a box's face diagonals, equally close to its two triangles), and thin
    faces, whose closest points round worst (a needle of 10 x 0.15 x 0.15 cm at 0.3 m from the
    origin: faces of aspect 0.015). Fails with the bound's |p - m| left out, and on the needle with
    the faces' rounding allowance (sdf.face_rounding) left out."""
    from physhand_mj import scene_path

    if shape == "bowl":
        mesh = trimesh.load(scene_path("hoi_bowl").parent / "assets" / "bowl.stl")
    elif shape == "star":
        mesh = star_prism()[0]
    elif shape == "needle":
        mesh = trimesh.creation.box(extents=(0.1, 0.0015, 0.0015))
        mesh.apply_translation((0.2, 0.2, 0.1))
    else:
        mesh = CONVEX[shape]()
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name="m", mesh_range=1.0)
    tri = small_triangles(mesh, 600, seed=7)
    if shape == "box":
        tri = np.concatenate([tri, diagonal_triangles(mesh)])
    order = 9
    k = (order + 1) * (order + 2) // 2
    pruned = wp.zeros((len(tri), k), dtype=wp.vec4, device=device)
    plain = wp.zeros((len(tri), k), dtype=wp.vec4, device=device)
    n_near = wp.zeros(len(tri), dtype=int, device=device)
    wp.launch(_pruned_and_plain, len(tri), [wp.vec3(*objs._host["size"][0]), wp.uint64(int(objs._host["mesh"][0][0])),
                                            wp.array(tri.reshape(-1, 3), dtype=wp.vec3, device=device), order],
              [pruned, plain, n_near], device=device)
    used = n_near.numpy() >= 0
    assert used.mean() > 0.6 and (n_near.numpy()[used] > 1).mean() > 0.5  # several faces to choose from
    q, e = pruned.numpy()[used], plain.numpy()[used]
    assert (e[..., 0] >= 0).all()
    differ = (q != e).any(axis=-1)
    assert not differ.any(), (f"{differ.sum()} of {differ.size} samples differ, distance at most "
                              f"{np.abs(np.sqrt(q[..., 3]) - np.sqrt(e[..., 3])).max()} m")


@wp.kernel
def _skip_bound(mesh: wp.uint64, ms: wp.array(dtype=wp.vec3), ps: wp.array(dtype=wp.vec3),
                gap: wp.array(dtype=float), gap_raw: wp.array(dtype=float)):
    """How far the computed distance of p to face i falls short of the bound sdf.mesh_near_closest
    skips by (the listed lower distance from m less |p - m| and its slack), with and without the
    face's rounding allowance (sdf.face_rounding); 0 where the bound holds."""
    i = wp.tid()
    m = ms[i]
    p = ps[i]
    d2m, u, v = mesh_face_closest(mesh, i, m)
    d2p, u2, v2 = mesh_face_closest(mesh, i, p)
    rho = wp.length(p - m) + 1.0e-7 + 1.0e-6 * wp.max(wp.abs(m))
    dp = wp.sqrt(d2p)
    gap[i] = wp.max(wp.sqrt(d2m) - face_rounding(mesh, i) - rho - dp, 0.0)
    gap_raw[i] = wp.max(wp.sqrt(d2m) - rho - dp, 0.0)


@pytest.mark.parametrize("device", DEVICES)
def test_the_near_faces_skip_bound_holds_on_thin_faces(device):
    """d(p) >= d(m) - |p - m| holds in exact arithmetic; in float32 the closest point of a thin face
    rounds by much more than its coordinates' size suggests. On 100,000 random faces 5-15 cm long of
    aspect ratio 1 to 0.005, up to 1 m from the origin, with m up to 1 cm off and p up to 3 mm from
    m (half of them along the face normal towards the face): the skip's bound with sdf.face_rounding
    holds for every one, and without it fails for some (so the allowance is needed)."""
    rng = np.random.default_rng(11)
    n = 100_000
    c = rng.uniform(-1.0, 1.0, (n, 3)) * rng.choice([0.05, 1.0], (n, 1))
    e0 = rng.normal(size=(n, 3))
    e0 /= np.linalg.norm(e0, axis=1, keepdims=True)
    e1 = rng.normal(size=(n, 3))
    e1 -= (e1 * e0).sum(1, keepdims=True) * e0
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    length = rng.uniform(0.05, 0.15, (n, 1))
    aspect = rng.choice([1.0, 0.1, 0.03, 0.01, 0.005], (n, 1))
    tri = np.stack([c, c + e0 * length, c + e0 * length * rng.uniform(0, 1, (n, 1)) + e1 * length * aspect], 1)
    tri = tri.astype(np.float32).astype(float)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    on = (rng.dirichlet([1, 1, 1], n)[:, :, None] * tri).sum(1)
    along = rng.uniform(size=n) < 0.5
    out = np.where(along[:, None], normal * np.sign(rng.uniform(-1, 1, (n, 1))), rng.normal(size=(n, 3)))
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    off = rng.uniform(0.0, 1e-2, (n, 1))
    m = on + out * off
    step = np.minimum(rng.uniform(0.0, 3e-3, (n, 1)), off)
    p = np.where(along[:, None], m - out * step, m + rng.normal(size=(n, 3)) / np.sqrt(3) * step)
    mesh = wp.Mesh(wp.array(tri.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device=device),
                   wp.array(np.arange(3 * n, dtype=np.int32), dtype=int, device=device))
    gap = wp.zeros(n, dtype=float, device=device)
    gap_raw = wp.zeros(n, dtype=float, device=device)
    wp.launch(_skip_bound, n, [mesh.id, wp.array(m.astype(np.float32), dtype=wp.vec3, device=device),
                               wp.array(p.astype(np.float32), dtype=wp.vec3, device=device)], [gap, gap_raw],
              device=device)
    raw = gap_raw.numpy()
    assert (raw > 0).sum() > 10, "the sample holds no face whose rounding breaks the plain bound"
    assert not (gap.numpy() > 0).any(), f"{(gap.numpy() > 0).sum()} faces break the bound, by up to {gap.numpy().max()} m"


def test_a_contact_run_is_the_same_with_and_without_the_near_faces(monkeypatch):
    """The decision points' near-face search changes only the cost: the knife wedge pressed into the
    fingertip and the coarse 20-face mesh starting 4 mm deep in the palm, both marked by Objects.add,
    end with the same skin bit for bit as with the marking switched off (the BVH walk per sample);
    the 24-section cone mesh, whose tip fans too many faces, is left unmarked."""
    import physhand_mj as ph
    import physhand_mj.contact.objects as objects_mod
    from physhand_mj.cases import press_case, run_case

    asset = ph.load_asset()
    cases = (("knife", "fingertip", 0.002), ("coarse", "palm", -0.004))
    for kind, site, start in cases:
        case = press_case(kind, site=site, depth=0.004, start=start)
        objs = Objects("cpu", 1)
        objs.add(GeomType.MESH, None, vertices=case.vertices, faces=case.faces, name=kind)
        assert int(objs._host["size"][0][1]) == MESH_SIGN_PSEUDO_NEAR, kind
    cone = press_case("mesh_cone")
    objs = Objects("cpu", 1)
    objs.add(GeomType.MESH, None, vertices=cone.vertices, faces=cone.faces, name="cone")
    assert int(objs._host["size"][0][1]) == MESH_SIGN_PSEUDO
    skins = {}
    for marked in (True, False):
        if not marked:
            monkeypatch.setattr(objects_mod, "near_faces_pay", lambda mesh, seed=0: False)
        for kind, site, start in cases:
            r = run_case(press_case(kind, site=site, depth=0.004, start=start), ph.Config(device="cpu"), frames=6,
                         asset=asset)
            skins[kind, marked] = r["skin"]
    for kind, _, _ in cases:
        np.testing.assert_array_equal(skins[kind, True], skins[kind, False])
