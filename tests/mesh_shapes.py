"""Test meshes with sharp features (knife wedges, cone tips, a star prism's notches) and points and
small skin-sized triangles about them, shared by tests/test_mesh_sdf.py and tests/test_mesh_near_faces.py."""

import numpy as np
import trimesh


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


def small_triangles(mesh, n, seed, spread=1.2e-3, depth=(-2e-3, 4e-3)):
    """``n`` random triangles of ~``spread`` (m) about points ``depth`` (m) off ``mesh``'s surface
    (negative: inside), and n / 4 more about its sharp edges and tips, both sides, where it has any."""
    rng = np.random.default_rng(seed)
    pts, fi = trimesh.sample.sample_surface(mesh, n, seed=seed)
    centres = pts + mesh.face_normals[fi] * rng.uniform(*depth, (n, 1))
    if (mesh.face_adjacency_angles > np.radians(1.0)).any():  # (a smooth mesh has none)
        centres = np.concatenate([centres, near_features(mesh, n_edge=n // 8, n_vertex=n // 8, seed=seed)])
    return (centres[:, None, :] + rng.normal(size=(len(centres), 3, 3)) * spread).astype(np.float32)


def bowl_mesh() -> trimesh.Trimesh:
    """The HOI bowl's mesh as shipped (1,408 faces)."""
    from physhand_mj import scene_path

    return trimesh.load(scene_path("hoi_bowl").parent / "assets" / "bowl.stl")
