"""Points on object surfaces: the other side of a contact (DESIGN "Metrics", second measure).

The paper measures penetration from the skin's side (skin samples inside objects). A tip or an edge
can poke through a skin triangle between any skin samples, so the objects are also sampled on their
own surfaces and those points are tested against the closed skin (:mod:`physhand_mj.contact.inside`).
Per geom, in its local frame, three kinds of points (:class:`PointKind`):

- CORNER: where the surface is sharpest: a mesh's vertices, a box's corners, a cone's tip;
- EDGE: points along sharp edges every ``edge_spacing`` m: a mesh's edges whose faces meet at more
  than ``SHARP_DEG`` degrees, a box's 12 edges, a cylinder's two rims, a cone's base rim;
- SURFACE: an even sampling of the whole surface, about one point per ``surface_spacing``^2.

Features (corners and edges) are what the skin-side decision points can miss; the contact stage
also uses them to push the skin off a feature that pokes into it (query.py, ``feature_contact``).
Every point lies on the exact surface the SDF describes (analytic shapes are sampled from their
parametrisation, meshes on their triangles).
"""

from __future__ import annotations

import enum

import numpy as np

from physhand_mj.types import GeomType

SHARP_DEG = 20.0  # a mesh edge is sharp where its two faces' normals differ by more (degrees)


class PointKind(enum.IntEnum):
    SURFACE = 0
    EDGE = 1
    CORNER = 2


def _segment(a, b, spacing, subdivide: int = 1):
    """Midpoints of the segment's pieces of at most ``spacing``, each cut into ``subdivide`` (the check
    points' 4: for an even ``subdivide`` none of them is a midpoint of the undivided pieces, whatever
    the length)."""
    n = max(int(np.ceil(np.linalg.norm(np.subtract(b, a)) / spacing)), 1) * subdivide
    t = (np.arange(n) + 0.5) / n  # interior points; the endpoints are corners of their own
    return np.asarray(a, float)[None] + t[:, None] * (np.asarray(b, float) - np.asarray(a, float))[None]


def _circle(r, z, spacing, subdivide: int = 1, shift: float | None = None):
    """n points on a circle, at angles (k + shift) 2 pi / n: the check points' (subdivided, or a
    ``shift`` of 1/2) lie between the features' at angles k 2 pi / n (the cone's slant line at 0)."""
    n = max(int(np.ceil(2 * np.pi * r / spacing)), 8) * subdivide
    a = 2 * np.pi * (np.arange(n) + ((0.5 if subdivide > 1 else 0.0) if shift is None else shift)) / n
    return np.stack([r * np.cos(a), r * np.sin(a), np.full(n, z)], 1)


def _sphere(n):
    """n nearly even unit vectors (Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    a = np.pi * (1 + 5 ** 0.5) * k
    s = np.sqrt(np.maximum(1 - z * z, 0))
    return np.stack([s * np.cos(a), s * np.sin(a), z], 1)


def _disc(r, z, spacing):
    n = max(int(np.pi * r * r / spacing ** 2), 4)
    k = np.arange(n) + 0.5
    rho = r * np.sqrt(k / n)
    a = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([rho * np.cos(a), rho * np.sin(a), np.full(n, z)], 1)


def _side(r_of_z, z0, z1, spacing, slant=1.0, shift: float = 0.0):
    """Points on a surface of revolution r(z), z in [z0, z1], about one per spacing^2 (rings at
    angles (k + shift) 2 pi / n: _circle)."""
    h = abs(z1 - z0) * slant
    rows = max(int(np.ceil(h / spacing)), 1)
    pts = []
    for i in range(rows):
        z = z0 + (z1 - z0) * (i + 0.5) / rows
        r = r_of_z(z)
        if r > 0:
            pts.append(_circle(r, z, spacing, shift=shift))
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def primitive_points(gtype: GeomType, size, edge_spacing: float = 5e-4, surface_spacing: float = 1e-3,
                     edge_subdivide: int = 1):
    """(points (P, 3) m, kinds (P,) int) on the surface of an analytic geom (MuJoCo sizes); edges in
    pieces of at most ``edge_spacing``, each cut into ``edge_subdivide`` (_segment)."""
    s = np.resize(np.asarray(size, float), 3)
    out, kinds = [], []

    def put(p, kind):
        p = np.asarray(p, float).reshape(-1, 3)
        out.append(p)
        kinds.append(np.full(len(p), int(kind), np.int32))

    if gtype == GeomType.SPHERE:
        n = max(int(4 * np.pi * s[0] ** 2 / surface_spacing ** 2), 32)
        put(s[0] * _sphere(n), PointKind.SURFACE)
    elif gtype == GeomType.ELLIPSOID:
        r = s.max()
        n = max(int(4 * np.pi * r ** 2 / surface_spacing ** 2), 32)
        put(_sphere(n) * s[None], PointKind.SURFACE)  # a scaled unit sphere lies on the ellipsoid
    elif gtype == GeomType.CAPSULE:
        r, h = s[0], s[1]
        put(_side(lambda z: r, -h, h, surface_spacing), PointKind.SURFACE)
        n = max(int(4 * np.pi * r ** 2 / surface_spacing ** 2), 32)
        u = r * _sphere(n)
        put(u + np.where(u[:, 2:] >= 0, h, -h) * np.array([0, 0, 1.0]), PointKind.SURFACE)
    elif gtype == GeomType.BOX:
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * s
        put(corners, PointKind.CORNER)
        for i in range(8):
            for j in range(i + 1, 8):
                if np.count_nonzero(corners[i] != corners[j]) == 1:
                    put(_segment(corners[i], corners[j], edge_spacing, edge_subdivide), PointKind.EDGE)
        for ax in range(3):
            u, v = [a for a in range(3) if a != ax]
            nu = max(int(np.ceil(2 * s[u] / surface_spacing)), 1)
            nv = max(int(np.ceil(2 * s[v] / surface_spacing)), 1)
            gu = -s[u] + 2 * s[u] * (np.arange(nu) + 0.5) / nu
            gv = -s[v] + 2 * s[v] * (np.arange(nv) + 0.5) / nv
            uu, vv = np.meshgrid(gu, gv, indexing="ij")
            for sign in (-1, 1):
                p = np.zeros((uu.size, 3))
                p[:, u], p[:, v], p[:, ax] = uu.ravel(), vv.ravel(), sign * s[ax]
                put(p, PointKind.SURFACE)
    elif gtype == GeomType.CYLINDER:
        r, h = s[0], s[1]
        for z in (-h, h):
            put(_circle(r, z, edge_spacing, edge_subdivide), PointKind.EDGE)
            put(_disc(r, z, surface_spacing), PointKind.SURFACE)
        put(_side(lambda z: r, -h, h, surface_spacing), PointKind.SURFACE)
    elif gtype == GeomType.CONE:  # tip at the origin, base disc of radius r at z = -h
        r, h = s[0], s[1]
        put([[0.0, 0.0, 0.0]], PointKind.CORNER)
        put(_circle(r, -h, edge_spacing, edge_subdivide), PointKind.EDGE)
        put(_disc(r, -h, surface_spacing), PointKind.SURFACE)
        # (the check set's rings off the slant line's angle: none of its points is a feature point)
        put(_side(lambda z: r * (-z) / h, -h, 0.0, surface_spacing, slant=np.hypot(r, h) / h,
                  shift=0.5 if edge_subdivide > 1 else 0.0), PointKind.SURFACE)
        # the tip's neighbourhood densely along the slant (a tip pokes through with its last millimetres)
        put(_segment([0, 0, 0], [r, 0, -h], edge_spacing, edge_subdivide)[: max(int(4e-3 / edge_spacing), 1) * edge_subdivide],
            PointKind.EDGE)
    elif gtype == GeomType.PLANE:
        pass  # unbounded: measured from the skin's side only
    else:
        raise ValueError(f"no surface sampling rule for {gtype!r}")
    if not out:
        return np.zeros((0, 3)), np.zeros(0, np.int32)
    return np.concatenate(out), np.concatenate(kinds)


def mesh_points(vertices, faces, edge_spacing: float = 5e-4, surface_spacing: float = 1e-3, seed: int = 0,
                edge_subdivide: int = 1):
    """(points (P, 3) m, kinds (P,) int) on a triangle mesh: its vertices, its sharp edges, an even
    sampling of its faces (deterministic for ``seed``)."""
    import trimesh

    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    tm = trimesh.Trimesh(v, f, process=False)
    out = [v]
    kinds = [np.full(len(v), int(PointKind.CORNER), np.int32)]
    if len(tm.face_adjacency):
        sharp = np.degrees(tm.face_adjacency_angles) > SHARP_DEG
        edges = tm.face_adjacency_edges[sharp]
    else:
        edges = np.zeros((0, 2), int)
    # boundary edges of open meshes are sharp too
    unique, counts = np.unique(np.sort(tm.edges, axis=1), axis=0, return_counts=True)
    edges = np.concatenate([edges, unique[counts == 1]])
    for a, b in edges:
        seg = _segment(v[a], v[b], edge_spacing, edge_subdivide)
        out.append(seg)
        kinds.append(np.full(len(seg), int(PointKind.EDGE), np.int32))
    area = float(tm.area)
    n = int(area / surface_spacing ** 2)
    if n > 0:
        rng_state = np.random.get_state()
        np.random.seed(seed)  # trimesh samples with numpy's global generator
        try:
            pts = trimesh.sample.sample_surface_even(tm, n, radius=0.5 * surface_spacing, seed=seed)[0]
        except TypeError:  # older trimesh without the seed argument
            pts = trimesh.sample.sample_surface_even(tm, n, radius=0.5 * surface_spacing)[0]
        np.random.set_state(rng_state)
        out.append(pts)
        kinds.append(np.full(len(pts), int(PointKind.SURFACE), np.int32))
    return np.concatenate(out), np.concatenate(kinds)
