"""The independent self-penetration measure (issue 53): code the self-collision stage does not share.

A skin vertex has passed into another part of the hand when a point a little way out along its
outward normal lies inside the closed skin. Inside is decided by the exact generalised winding
number (Jacobson et al. 2013: the solid angles of every skin triangle summed, Van Oosterom and
Strackee's formula, no BVH, no approximation), so folds, turned-over triangles and the stage's own
rest filter cannot hide a penetration. At rest (the open hand) no offset point is inside at
0.2 mm; a fingertip pressed into the palm has its 0.2 mm and 1 mm offsets inside.

Also counted: inverted tets (signed volume below zero where the rest volume is positive), and skin
edges that pass through a skin triangle they share no vertex with (the skin intersecting itself:
every skin edge against every skin triangle, an exact segment-triangle test, brute force as well;
the closed skin at rest has none).

    offsets_inside(x, faces, offset)   -> (V,) bool: the skin vertices whose offset point is inside
    buried_vertices(x, faces, depth)   -> (V,) bool: the skin vertices with no point outside the closed
                                          skin at ``depth`` around them (no normal: every direction)
    crossing_depths(x, faces)          -> (E,) m over the skin's edges: how far each pokes through the
                                          deepest other triangle it crosses (0: none)
    crossing_edges(x, faces)           -> (E,) bool over the skin's edges: through another triangle
    self_penetration(x, faces, tets)   -> dict of counts at 0.2 mm and 1 mm, crossing edges (and those
                                          poking deeper than each offset), and inverted tets
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})

OFFSETS = (2.0e-4, 1.0e-3)  # m: the offsets the figures use (0.2 mm, 1 mm)


@wp.func
def _solid_angle(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> float:
    """The signed solid angle of triangle abc seen from p (Van Oosterom and Strackee 1983)."""
    ra = a - p
    rb = b - p
    rc = c - p
    la = wp.length(ra)
    lb = wp.length(rb)
    lc = wp.length(rc)
    num = wp.dot(ra, wp.cross(rb, rc))
    den = la * lb * lc + wp.dot(ra, rb) * lc + wp.dot(rb, rc) * la + wp.dot(rc, ra) * lb
    return 2.0 * wp.atan2(num, den)


@wp.kernel
def _winding(points: wp.array(dtype=wp.vec3), x: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=int),
             out: wp.array(dtype=float)):
    i = wp.tid()
    p = points[i]
    s = float(0.0)
    for t in range(faces.shape[0]):
        s += _solid_angle(p, x[faces[t, 0]], x[faces[t, 1]], x[faces[t, 2]])
    out[i] = s / (4.0 * wp.pi)


def winding_numbers(points: np.ndarray, x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(P,) the exact generalised winding number of the closed mesh (x, faces) at each point (1:
    inside a mesh whose faces wind outward, 0: outside). Brute force on the CPU: P x F solid angles."""
    d = "cpu"
    pts = wp.array(np.ascontiguousarray(points, np.float32), dtype=wp.vec3, device=d)
    xv = wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec3, device=d)
    fv = wp.array(np.ascontiguousarray(faces, np.int32), dtype=int, device=d)
    out = wp.zeros(len(points), dtype=float, device=d)
    wp.launch(_winding, len(points), inputs=[pts, xv, fv], outputs=[out], device=d)
    return out.numpy()


def vertex_normals(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals, pointing out of the closed skin (the faces' winding
    is checked by the mesh's signed volume, and the normals flipped if it is negative)."""
    x = np.asarray(x, np.float64)
    a, b, c = x[faces[:, 0]], x[faces[:, 1]], x[faces[:, 2]]
    fn = np.cross(b - a, c - a)
    n = np.zeros_like(x)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    if np.einsum("ij,ij->", a, np.cross(b, c)) < 0:  # 6 x the signed volume: inward winding
        n = -n
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def outward_winding(points: np.ndarray, x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """:func:`winding_numbers` signed so that inside the closed skin is +1 whichever way its faces
    wind (the sign of the enclosed volume)."""
    w = winding_numbers(points, x, faces)
    if np.einsum("ij,ij->", x[faces[:, 0]], np.cross(x[faces[:, 1]], x[faces[:, 2]])) < 0:
        w = -w
    return w


def offsets_inside(x: np.ndarray, faces: np.ndarray, offset: float) -> np.ndarray:
    """(V,) bool over the skin vertices used by ``faces``: the point ``offset`` m along the vertex's
    outward normal lies inside the closed skin (winding number above 1/2)."""
    x = np.asarray(x, np.float64)
    nrm = vertex_normals(x, faces)
    used = np.zeros(len(x), bool)
    used[faces.ravel()] = True
    w = outward_winding(x + offset * nrm, x, faces)
    return (w > 0.5) & used


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) unit directions spread evenly over the sphere (a Fibonacci lattice), in an order whose
    every leading run is spread too (a stride through the lattice), so a search may stop early."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    th = np.pi * (1.0 + 5.0 ** 0.5) * i
    d = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], axis=1)
    stride = next(s for s in (97, 89, 83, 79, 73) if np.gcd(s, n) == 1)
    return d[(np.arange(n) * stride) % n]


def buried_vertices(x: np.ndarray, faces: np.ndarray, depth: float, directions: int = 64,
                    chunk: int = 16) -> np.ndarray:
    """(V,) bool: the skin vertices farther than ``depth`` from the air, sampled: every one of
    ``directions`` points ``depth`` m from the vertex (:func:`sphere_directions`) lies inside the
    closed skin. No normal is involved. :func:`offsets_inside` asks only along the vertex's
    area-weighted normal, which at a closed crease (two walls of skin facing each other, the vertex
    at the bottom) is the small difference of opposite normals and may point into the vertex's own
    flesh: such a vertex counts inside there though it borders the crease's air. A vertex pressed
    more than ``depth`` into another part (or a fold of its own skin) counts here; one at a crease's
    bottom does not. Only vertices whose normal offset is inside are searched (a buried vertex has
    every point at ``depth`` inside, so that one too), ``chunk`` directions at a time until one lies
    outside. 64 directions (~25 degrees apart) gave the counts of 256 within 2 (power without
    self-collision: 540 and 538 of 588 normal offsets inside; pinch 42 and 42)."""
    x = np.asarray(x, np.float64)
    cand = np.where(offsets_inside(x, faces, depth))[0]
    dirs = sphere_directions(directions)
    for k in range(0, directions, chunk):
        if len(cand) == 0:
            break
        d = dirs[k:k + chunk]
        pts = (x[cand][:, None, :] + depth * d[None, :, :]).reshape(-1, 3)
        w = outward_winding(pts, x, faces).reshape(len(cand), len(d))
        cand = cand[(w > 0.5).all(axis=1)]
    out = np.zeros(len(x), bool)
    out[cand] = True
    return out


@wp.kernel
def _crossing(x: wp.array(dtype=wp.vec3), edges: wp.array2d(dtype=int), faces: wp.array2d(dtype=int),
              lo: wp.array(dtype=wp.vec3), hi: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    e = wp.tid()
    i = edges[e, 0]
    j = edges[e, 1]
    p = x[i]
    q = x[j]
    elo = wp.min(p, q)
    ehi = wp.max(p, q)
    d = q - p
    deepest = float(0.0)
    for t in range(faces.shape[0]):
        l = lo[t]
        h = hi[t]
        if h[0] < elo[0] or l[0] > ehi[0] or h[1] < elo[1] or l[1] > ehi[1] or h[2] < elo[2] or l[2] > ehi[2]:
            continue
        a = faces[t, 0]
        b = faces[t, 1]
        c = faces[t, 2]
        if a == i or a == j or b == i or b == j or c == i or c == j:
            continue
        # Moller-Trumbore: p + s d = x_a + u (x_b - x_a) + v (x_c - x_a), 0 < s < 1, u, v >= 0, u + v <= 1
        e1 = x[b] - x[a]
        e2 = x[c] - x[a]
        pv = wp.cross(d, e2)
        det = wp.dot(e1, pv)
        if wp.abs(det) < 1.0e-20:
            continue
        inv = 1.0 / det
        tv = p - x[a]
        u = wp.dot(tv, pv) * inv
        if u < 0.0 or u > 1.0:
            continue
        qv = wp.cross(tv, e1)
        v = wp.dot(d, qv) * inv
        if v < 0.0 or u + v > 1.0:
            continue
        sv = wp.dot(e2, qv) * inv
        if sv > 0.0 and sv < 1.0:
            # how far the edge pokes through: its shorter part beyond the triangle's plane, along the
            # triangle's normal (> 0 for any crossing: both ends lie off the plane)
            n = wp.normalize(wp.cross(e1, e2))
            poke = wp.max(wp.min(wp.abs(wp.dot(p - x[a], n)), wp.abs(wp.dot(q - x[a], n))), 1.0e-12)
            deepest = wp.max(deepest, poke)
    out[e] = deepest


def skin_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) the skin's edges (each once, the lower vertex first)."""
    f = np.asarray(faces, np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def crossing_depths(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(E,) float over :func:`skin_edges`, m: 0 where the edge passes through no skin triangle that
    shares no vertex with it (exact segment-triangle test, float32, brute force on the CPU); else how
    far it pokes through the deepest one it crosses: the shorter of its two parts either side of the
    triangle's plane, measured along the triangle's normal (an edge grazing a triangle's plane: near
    0; an edge crossing square to it, half through: half its length)."""
    d = "cpu"
    x = np.asarray(x, np.float32)
    faces = np.ascontiguousarray(faces, np.int32)
    tri = x[faces]
    edges = skin_edges(faces).astype(np.int32)
    out = wp.zeros(len(edges), dtype=float, device=d)
    wp.launch(_crossing, len(edges), inputs=[wp.array(x, dtype=wp.vec3, device=d), wp.array(edges, dtype=int, device=d),
                                            wp.array(faces, dtype=int, device=d),
                                            wp.array(tri.min(axis=1), dtype=wp.vec3, device=d),
                                            wp.array(tri.max(axis=1), dtype=wp.vec3, device=d)],
              outputs=[out], device=d)
    return out.numpy().astype(np.float64)


def crossing_edges(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(E,) bool over :func:`skin_edges`: the edge passes through the interior of a skin triangle
    that shares no vertex with it (:func:`crossing_depths` above 0)."""
    return crossing_depths(x, faces) > 0.0


def inverted_mask(x: np.ndarray, tets: np.ndarray, rest_x: np.ndarray) -> np.ndarray:
    """(T,) bool: the tets whose signed volume has the opposite sign of (or is zero against) their
    rest volume."""
    def vol(p):
        p = np.asarray(p, np.float64)
        a, b, c, d = (p[tets[:, k]] for k in range(4))
        return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))

    v0 = vol(rest_x)
    return (vol(x) * np.sign(v0) <= 0) & (v0 != 0)


def inverted_tets(x: np.ndarray, tets: np.ndarray, rest_x: np.ndarray) -> int:
    """How many tets are inverted (:func:`inverted_mask`)."""
    return int(inverted_mask(x, tets, rest_x).sum())


def self_penetration(x: np.ndarray, faces: np.ndarray, tets: np.ndarray | None = None,
                     rest_x: np.ndarray | None = None, offsets=OFFSETS, buried: float | None = None) -> dict:
    """The measure's counts: ``inside_<um>um`` (skin vertices whose offset point is inside the closed
    skin) per offset, ``crossing_edges`` (skin edges through another skin triangle),
    ``crossing_over_<um>um`` per offset (those poking through it farther than the offset:
    :func:`crossing_depths`) and ``crossing_depth_max_um``, and with ``tets`` and ``rest_x`` (all
    vertices, skin first) ``inverted_tets``; with ``buried`` (m) also ``buried_<um>um``
    (:func:`buried_vertices` at that depth)."""
    ns = int(faces.max()) + 1
    out = {f"inside_{int(round(o * 1e6))}um": int(offsets_inside(np.asarray(x)[:ns], faces, o).sum())
           for o in offsets}
    if buried is not None:
        out[f"buried_{int(round(buried * 1e6))}um"] = int(buried_vertices(np.asarray(x)[:ns], faces, buried).sum())
    depth = crossing_depths(np.asarray(x)[:ns], faces)
    out["crossing_edges"] = int((depth > 0.0).sum())
    out.update({f"crossing_over_{int(round(o * 1e6))}um": int((depth > o).sum()) for o in offsets})
    out["crossing_depth_max_um"] = round(float(depth.max(initial=0.0)) * 1e6, 1)
    if tets is not None and rest_x is not None:
        out["inverted_tets"] = inverted_tets(x, tets, rest_x)
    return out
