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

from mesh_shapes import CONVEX, cone, near_features, star_prism
from physhand_mj.contact import Objects
from physhand_mj.contact.sdf import geom_sdf, geom_sdf_grad
from physhand_mj.contact.sdf_mesh import MESH_SIGN_PSEUDO, MESH_SIGN_PSEUDO_NEAR, MESH_SIGN_WINDING, grid_node
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
    answering the points it proves farther than sdf_mesh.GRID_BAND outside)."""
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


# -- shapes with sharp features: tests/mesh_shapes.py

def inside_star(p, poly, height):
    inside = np.abs(p[:, 2]) < height / 2
    crossing = np.zeros(len(p), bool)
    for a, b in zip(poly, np.roll(poly, -1, 0)):
        straddle = (a[1] > p[:, 1]) != (b[1] > p[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x = a[0] + (p[:, 1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        crossing ^= straddle & (p[:, 0] < x)
    return inside & crossing


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


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("shape", ["cone30_tip", "wedge30_knife", "box"])
def test_pseudo_normal_table_gives_the_walks_bits(shape, device, monkeypatch):
    """A closed mesh keeps its faces' edge, vertex and face normals in a table (its ``velocities``,
    filled by the same functions): phi and gradient, off and on the surface (where the gradient is the
    pseudo normal itself), are those of a mesh without the table, bit for bit."""
    from physhand_mj.contact import objects

    mesh = CONVEX[shape]()
    edges = mesh.edges_unique
    p = np.concatenate([samples(mesh, seed=3), mesh.vertices, mesh.vertices[edges].mean(1)])
    with_table = mesh_sdf(mesh, p, device)
    monkeypatch.setattr(objects, "PSEUDO_NORMAL_TABLE", False)
    walked = mesh_sdf(mesh, p, device)
    assert np.array_equal(with_table[0], walked[0]) and np.array_equal(with_table[1], walked[1])
    m, _ = objects.prepare_mesh(mesh.vertices, mesh.faces, device=device)
    assert m.velocities is None or len(m.velocities) == 0, "the switch builds meshes without the table"
    monkeypatch.setattr(objects, "PSEUDO_NORMAL_TABLE", True)
    m, _ = objects.prepare_mesh(mesh.vertices, mesh.faces, device=device)
    assert len(m.velocities) == 7 * (len(m.indices) // 3)
    # the walk reaches every vertex and edge: no zero entry (each feature has a face of its own)
    assert np.linalg.norm(m.velocities.numpy(), axis=1).min() > 0.0
    # a mesh with velocities of another length (per vertex) is not taken for a table: it walks
    pts = wp.array(m.points.numpy(), dtype=wp.vec3, device=device)
    other = wp.Mesh(points=pts, indices=wp.array(m.indices.numpy(), dtype=wp.int32, device=device),
                    velocities=wp.full(len(pts), wp.vec3(1.0, 0.0, 0.0), dtype=wp.vec3, device=device))
    size = wp.vec3(1.0, float(MESH_SIGN_PSEUDO), 0.0)
    phi = wp.zeros(len(p), dtype=float, device=device)
    grad = wp.zeros(len(p), dtype=wp.vec3, device=device)
    wp.launch(_eval, len(p), inputs=[size, wp.vec2ul(other.id, 0), wp.array(p.astype(np.float32), dtype=wp.vec3,
                                                                              device=device)],
              outputs=[phi, grad], device=device)
    assert np.array_equal(phi.numpy().astype(float), walked[0]) and np.array_equal(grad.numpy().astype(float), walked[1])


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
    from physhand_mj.bench.cases import wedge

    if shape == "plate":
        m = trimesh.creation.box(extents=(0.024, 0.024, 0.001))
    elif shape == "shell":
        outer, inner = trimesh.creation.icosphere(4, 0.012), trimesh.creation.icosphere(4, 0.010)
        inner.invert()
        m = trimesh.util.concatenate([outer, inner])
    elif shape == "sphere":
        m = trimesh.creation.icosphere(4, 0.010)
    else:
        m = trimesh.Trimesh(*wedge())
    objs = Objects("cpu", 1)
    objs.add(GeomType.MESH, None, vertices=m.vertices, faces=m.faces, name=shape, mesh_range=0.05)
    half = float(objs.size.numpy()[0, 2]) * 1e3
    assert half == pytest.approx(half_mm, rel=0.03, abs=1e-9), half


@pytest.mark.parametrize("shape", ["icosphere0", "wedge30_knife"])
@pytest.mark.parametrize("device", DEVICES)
def test_the_distance_grid_answers_only_far_points_with_a_lower_bound(shape, device):
    """objects.mesh_grid: the query the contact runs equals the exact BVH query bit for bit wherever
    that is below sdf_mesh.GRID_BAND (inside, on and near the surface); farther out it may answer a lower
    bound (never above the exact distance, never below the band, within the grid's node diagonal)
    without the BVH walk, which it does for most far points; off the grid (more than GRID_PAD out of
    the mesh's box) it answers GRID_PAD, again a lower bound."""
    from physhand_mj.contact.objects import GRID_PAD
    from physhand_mj.contact.sdf_mesh import GRID_BAND

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


@wp.kernel
def _node(ids: wp.array(dtype=wp.vec2ul), p: wp.array(dtype=wp.vec3), dc: wp.array(dtype=float),
          dist: wp.array(dtype=float)):
    i = wp.tid()
    a, b = grid_node(ids[0][1], p[i])
    dc[i] = a
    dist[i] = b


@pytest.mark.parametrize("device", DEVICES)
def test_the_grids_bounds_list_the_triangles_the_exact_distance_lists(device):
    """broadphase.find_active with a mesh's grid (its lower bound rejects, its upper bound, the
    nearest node's distance plus the way to it, accepts; only the rest asks the exact distance) lists
    the triangles that the exact distance alone lists, with the same masks, at the frame's and the
    stage's margins; the upper bound decides most of the near ones."""
    from physhand_mj.contact import broadphase
    from physhand_mj.contact.broadphase import NO_LIST, find_active, tri_list

    mesh = CONVEX["wedge30_knife"]()
    rng = np.random.default_rng(5)
    surf, _ = trimesh.sample.sample_surface(mesh, 4000, seed=3)
    c = surf + rng.normal(0.0, 4e-3, surf.shape)  # small triangles (1-3 mm) about the surface, both sides
    tri = c[:, None] + rng.normal(0.0, 1.2e-3, (len(c), 3, 3))
    x = wp.array(tri.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device=device)
    faces = wp.array(np.arange(3 * len(c), dtype=np.int32).reshape(-1, 3), dtype=int, device=device)
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name="knife")
    assert int(objs._host["mesh"][0][1]) != 0  # (it has a grid)
    n = len(c)

    def listed(geoms, margin):
        out = [wp.zeros(n, dtype=int, device=device) for _ in range(2)] + [wp.zeros(1, dtype=int, device=device)]
        wp.launch(find_active, n, inputs=[faces, x, geoms, n, 1, margin, NO_LIST, *[None] * 4],
                  outputs=[tri_list(out[0], out[1]), out[2], NO_LIST, None], device=device)
        k = int(out[2].numpy()[0])
        return dict(zip(out[0].numpy()[:k].tolist(), out[1].numpy()[:k].tolist()))

    for margin in (5e-4, 1e-2):
        exact, grid = listed(objs.geoms_exact, margin), listed(objs.geoms, margin)
        assert 200 < len(exact) < n, (margin, len(exact))
        assert grid == exact, margin
        if margin == 1e-2:  # the upper bound alone decides most of the listed triangles (the path is taken)
            m, r = tri.mean(axis=1), np.linalg.norm(tri - tri.mean(axis=1)[:, None], axis=2).max(axis=1)
            dc, dist = wp.zeros(n, dtype=float, device=device), wp.zeros(n, dtype=float, device=device)
            wp.launch(_node, n, inputs=[objs.mesh, wp.array(m.astype(np.float32), dtype=wp.vec3, device=device)],
                      outputs=[dc, dist], device=device)
            sure = dc.numpy() + dist.numpy() - r <= margin
            assert broadphase.USE_GRID_UPPER and sure.sum() > 0.5 * len(exact), (sure.sum(), len(exact))
            assert set(np.flatnonzero(sure)) <= set(exact)


def test_a_contact_run_is_the_same_with_and_without_the_distance_grid():
    """Config.execution.mesh_grid changes only the cost: a mesh cone pressed into the palm, a coarse mesh
    starting 4 mm deep at the fingertip end with the same skin, bit for bit (measured on all 16 mesh
    hard cases: docs/contact.md; the knife 20 mm through the fingertip: tests/stress)."""
    import physhand_mj as ph
    from physhand_mj.bench.cases import press_case, run_case

    asset = ph.load_asset()
    for kind, site, depth, start, frames in (("mesh_cone", "palm", 0.004, 0.002, 6),
                                             ("coarse", "fingertip", 0.004, -0.004, 6)):
        skins = [run_case(press_case(kind, site=site, depth=depth, start=start),
                          ph.Config(device="cpu", execution=ph.Execution(mesh_grid=g)), frames=frames, asset=asset)["skin"] for g in (0.0, 2e-3)]
        np.testing.assert_array_equal(skins[0], skins[1])
    with pytest.raises(ValueError, match="mesh_grid"):
        ph.Config(execution=ph.Execution(mesh_grid=-1e-3)).validate()


def test_object_points_of_repeated_geoms_are_each_the_points_of_one_geom_alone():
    """A batch's worlds repeat their geoms: ObjectPoints samples each distinct shape once (a mesh's
    even sampling takes ~0.3 s; a 4,096-world batch spent minutes on it) and gives every copy the
    points a lone geom gets, for meshes and primitives alike; different sizes stay different."""
    from physhand_mj.contact.inside import ObjectPoints

    box = trimesh.creation.box((0.04, 0.03, 0.02))

    def objects(n_copies):
        objs = Objects("cpu", 3 * n_copies)
        for c in range(n_copies):
            objs.add(GeomType.MESH, None, pos=(c, 0, 0), vertices=box.vertices, faces=box.faces, name=f"m{c}")
            objs.add(GeomType.SPHERE, (0.01 + 0.01 * c,), name=f"s{c}")
            objs.add(GeomType.BOX, (0.01, 0.02, 0.03), name=f"b{c}")
        return objs

    one, three = ObjectPoints(objects(1)), ObjectPoints(objects(3))
    assert len(three) > 0
    for g in range(3):
        lone = one.pts_host[one.geom_host == g]
        for c in range(3):
            copy = three.pts_host[three.geom_host == 3 * c + g]
            if g == 1 and c > 0:  # a larger sphere: its own points
                assert len(copy) > len(lone)
            else:
                np.testing.assert_array_equal(copy, lone)
                np.testing.assert_array_equal(three.kind_host[three.geom_host == 3 * c + g],
                                              one.kind_host[one.geom_host == g])
