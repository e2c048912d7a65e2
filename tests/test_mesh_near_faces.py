"""The decision points' mesh query over a skin triangle's near faces (sdf_mesh.mesh_near_faces,
sdf_mesh.mesh_near_closest, sdf_mesh_near; docs/contact.md, "The decision points' near faces"): the BVH
query's phi at every lattice sample, the pruned loop's answers equal to the plain loop's, its skip
bound on thin faces, and a contact run the same with and without the search."""

import numpy as np
import pytest
import trimesh
import warp as wp

from mesh_shapes import CONVEX, bowl_mesh, small_triangles, star_prism
from physhand_mj.contact import Objects
from physhand_mj.contact.broadphase import triangle_bound
from physhand_mj.contact.sdf import geom_sdf
from physhand_mj.contact.sdf_mesh import (MESH_SIGN_PSEUDO, MESH_SIGN_PSEUDO_NEAR, face_rounding, mesh_face_closest,
                                          mesh_near_closest, mesh_near_faces, mesh_near_first, mesh_near_ids,
                                          sdf_mesh_near)
from physhand_mj.types import GeomType

DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])


@wp.func
def _listed(tri: wp.array(dtype=wp.vec3), t: int, mesh: wp.uint64, query_range: float):
    """Triangle t's corners, its centre m and its near faces (ids, lower distances, count)."""
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    m, r = triangle_bound(a, b, c)
    ids, dist, n = mesh_near_faces(mesh, m, r, query_range)
    return a, b, c, m, ids, dist, n


@wp.func
def _lattice_point(a: wp.vec3, b: wp.vec3, c: wp.vec3, i: int, j: int, order: int):
    u = float(i) / float(order)
    v = float(j) / float(order)
    return a * (1.0 - u - v) + b * u + c * v


@wp.kernel
def _near_lattice(size: wp.vec3, mesh: wp.uint64, tri: wp.array(dtype=wp.vec3), order: int,
                  exact: wp.array2d(dtype=float), near: wp.array2d(dtype=float), n_near: wp.array(dtype=int)):
    """Every point of an order-``order`` lattice on triangle t: the BVH query (geom_sdf, no grid) and
    the query over the triangle's near faces (sdf_mesh.mesh_near_faces / sdf_mesh_near, as query.py's
    decision points ask); n_near[t]: how many faces (-1: too many, the BVH then)."""
    t = wp.tid()
    a, b, c, m, ids, dist, n = _listed(tri, t, mesh, size[0])
    n_near[t] = n
    k = int(0)
    for i in range(order + 1):
        for j in range(order + 1 - i):
            p = _lattice_point(a, b, c, i, j, order)
            exact[t, k] = geom_sdf(int(GeomType.MESH), p, size, wp.vec2ul(mesh, wp.uint64(0)))
            if n >= 0:
                near[t, k] = sdf_mesh_near(p, size, mesh, ids, dist, n, mesh_near_first(dist, n), m)
            k += 1


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("shape", ["bowl", "wedge30_knife", "cone30_tip", "star", "hull40"])
def test_near_faces_answer_every_sample_as_the_bvh_does(shape, device):
    """The decision points' mesh query (sdf_mesh.mesh_near_faces, then sdf_mesh_near per lattice sample):
    the faces within d(m) + 2 r of a triangle's centroid hold every sample's closest face, and Warp's
    own leaf test over them returns the BVH query's phi (bit for bit but at exact ties), inside and outside, at knife
    edges, cone tips, a star's notches and the HOI bowl; a dense mesh overflows the capacity and
    falls back to the BVH, and Objects.add marks only meshes whose near faces are few
    (objects.near_faces_pay) for the decision points' search."""
    from physhand_mj.contact.sdf_mesh import MESH_NEAR_CAP
    if shape == "bowl":
        mesh = bowl_mesh()
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
    sdf_mesh.mesh_near_closest and by the plain loop."""
    t = wp.tid()
    a, b, c, m, ids, dist, n = _listed(tri, t, mesh, size[0])
    n_near[t] = n
    if n < 0:
        return
    k = int(0)
    for i in range(order + 1):
        for j in range(order + 1 - i):
            p = _lattice_point(a, b, c, i, j, order)
            f, u, v, d2 = mesh_near_closest(p, size, mesh, ids, dist, n, mesh_near_first(dist, n), m)
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
    """sdf_mesh.mesh_near_closest tests the face nearest the triangle's centre first and skips the faces its
    distance bound proves farther than the best so far: the same face, barycentrics and distance as
    testing every listed face in order, bit for bit, on the order-9 lattice, inside and outside;
    ties included (points over a box's face diagonals, equally close to its two triangles), and thin
    faces, whose closest points round worst (a needle of 10 x 0.15 x 0.15 cm at 0.3 m from the
    origin: faces of aspect 0.015). Fails with the bound's |p - m| left out, and on the needle with
    the faces' rounding allowance (sdf_mesh.face_rounding) left out."""
    if shape == "bowl":
        mesh = bowl_mesh()
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
    """How far the computed distance of p to face i falls short of the bound sdf_mesh.mesh_near_closest
    skips by (the listed lower distance from m less |p - m| and its slack), with and without the
    face's rounding allowance (sdf_mesh.face_rounding); 0 where the bound holds."""
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
    m (half of them along the face normal towards the face): the skip's bound with sdf_mesh.face_rounding
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
    # (44 such faces on the CPU, 10 on an H100: CUDA contracts the closest point's arithmetic into FMAs)
    assert (raw > 0).any(), "the sample holds no face whose rounding breaks the plain bound"
    assert not (gap.numpy() > 0).any(), f"{(gap.numpy() > 0).sum()} faces break the bound, by up to {gap.numpy().max()} m"


def test_a_contact_run_is_the_same_with_and_without_the_near_faces(monkeypatch):
    """The decision points' near-face search changes only the cost: the knife wedge pressed into the
    fingertip and the coarse 20-face mesh starting 4 mm deep in the palm, both marked by Objects.add,
    end with the same skin bit for bit as with the marking switched off (the BVH walk per sample);
    the 24-section cone mesh, whose tip fans too many faces, is left unmarked."""
    import physhand_mj as ph
    import physhand_mj.contact.objects as objects_mod
    from physhand_mj.bench.cases import press_case, run_case

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

