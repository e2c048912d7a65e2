"""Closest skin point to an object point without a BVH: the exact triangle scans of the object's side
(features.py). :func:`closest_signed` asks Warp's BVH (CPU); :func:`scan_closest` /
:func:`finish_closest` scan a list of skin triangles as Warp's query tests a BVH leaf, a block of
lanes (:func:`closest_signed_tiled`, tile reductions) or one thread at a time, summing on request
each listed triangle's solid angle (:func:`solid_angle`, the local winding number's term)."""

import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

NO_FACE = 2147483647  # a lane that found no triangle (larger than any face index)
FOUR_PI = 12.566370614359172  # (the local winding number's, contact/winding.py)


@wp.func
def solid_angle(a: wp.vec3, b: wp.vec3, c: wp.vec3):
    """Signed solid angle (sr) of triangle (a, b, c), vertices relative to the query point (Van
    Oosterom and Strackee 1983): its sum over a closed, outward (counter-clockwise) wound surface is
    4 pi inside and 0 outside."""
    la = wp.length(a)
    lb = wp.length(b)
    lc = wp.length(c)
    num = wp.dot(a, wp.cross(b, c))
    den = la * lb * lc + wp.dot(a, b) * lc + wp.dot(b, c) * la + wp.dot(c, a) * lb
    return 2.0 * wp.atan2(num, den)


@wp.func
def closest_signed(skin: wp.uint64, p: wp.vec3, near: float, far: float):
    """The closest skin point to ``p`` within ``far`` (m), signed by the skin's pseudo normals:
    asked within ``near`` first, since a BVH query's cost grows with its radius (on a GPU one thread
    walks the tree: 150 us per launch at a 1 cm radius on the demo, H100) and the features a pass
    tests lie within ~contact_margin of the skin; the same answer when found there."""
    q = wp.mesh_query_point_sign_normal(skin, p, near)
    if not q.result and far > near:
        q = wp.mesh_query_point_sign_normal(skin, p, far)
    return q


@wp.func
def closest_on_triangle(a: wp.vec3, b: wp.vec3, c: wp.vec3, p: wp.vec3):
    """Barycentric (u, v) of the point of triangle (a, b, c) closest to ``p``: the point is
    u a + v b + (1 - u - v) c (Ericson, Real-Time Collision Detection 5.1.5; Warp's
    closest_point_to_triangle, warp/native/intersect.h, branch for branch)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return wp.vec2(1.0, 0.0)  # vertex a
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return wp.vec2(0.0, 1.0)  # vertex b
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)  # edge ab
        return wp.vec2(1.0 - v, v)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= 0.0 and d5 <= d6:
        return wp.vec2(0.0, 0.0)  # vertex c
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)  # edge ac
        return wp.vec2(1.0 - w, 0.0)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))  # edge bc
        v = 1.0 - w
        return wp.vec2(1.0 - v - w, v)
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return wp.vec2(1.0 - v - w, v)


@wp.func
def pseudo_weight(a: wp.vec3, b: wp.vec3, c: wp.vec3, q: wp.vec3, eps: float):
    """Warp's angle weight of triangle (a, b, c) in the pseudo normal at its point q closest to a
    query point (mesh_query_point_sign_normal): the triangle's angle at a vertex within ``eps``
    (m) of q, pi on an edge within ``eps``, 2 pi inside."""
    e0 = b - a
    e1 = c - a
    e2 = c - b
    eps_sq = eps * eps
    cp = q - a
    cq = q - b
    cr = q - c
    len_cp_sq = wp.length_sq(cp)
    len_cq_sq = wp.length_sq(cq)
    len_cr_sq = wp.length_sq(cr)
    weight = float(0.0)
    if len_cp_sq < eps_sq:
        weight = wp.acos(wp.dot(wp.normalize(e0), wp.normalize(e1)))
    elif len_cq_sq < eps_sq:
        weight = wp.acos(wp.dot(wp.normalize(e2), wp.normalize(-e0)))
    elif len_cr_sq < eps_sq:
        weight = wp.acos(wp.dot(wp.normalize(-e1), wp.normalize(-e2)))
    else:
        e0_sq = wp.dot(e0, e0)
        e1_sq = wp.dot(e1, e1)
        e2_sq = wp.dot(e2, e2)
        e0cp = wp.dot(e0, cp)
        e2cq = wp.dot(e2, cq)
        e1cp = wp.dot(e1, cp)
        if (len_cp_sq * e0_sq - e0cp * e0cp < eps_sq * e0_sq or len_cq_sq * e2_sq - e2cq * e2cq < eps_sq * e2_sq
                or len_cp_sq * e1_sq - e1cp * e1cp < eps_sq * e1_sq):
            weight = 3.14159265359
        else:
            weight = 2.0 * 3.14159265359
    return weight


@wp.func
def scan_closest(p: wp.vec3, lane: int, lanes: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                 tris: wp.array(dtype=int), start: int, n: int, far: float, eps: float, angles: int):
    """One lane's share of :func:`closest_signed_tiled`: entries lane, lane + lanes, ... of
    ``tris[start: start + n]``; returns (closest distance within ``far`` or far, its face or
    NO_FACE, the angle-weighted normal sum of the triangles within ``eps`` of it, the solid-angle
    sum with ``angles``)."""
    best = far
    face = int(NO_FACE)
    acc = wp.vec3(0.0)
    omega = float(0.0)
    j = start + lane
    end = start + n
    while j < end:
        t = tris[j]
        j += lanes
        a = x[faces[t, 0]]
        b = x[faces[t, 1]]
        c = x[faces[t, 2]]
        if angles != 0:  # every listed triangle, slivers too
            omega += solid_angle(a - p, b - p, c - p)
        e0 = b - a
        e1 = c - a
        e2 = c - b
        normal = wp.cross(e0, e1)
        if wp.length(normal) / (wp.dot(e0, e0) + wp.dot(e1, e1) + wp.dot(e2, e2)) < 1.0e-6:
            continue  # a sliver (Warp skips them)
        bc = closest_on_triangle(a, b, c, p)
        w = 1.0 - bc[0] - bc[1]
        q = bc[0] * a + bc[1] * b + w * c
        dist = wp.sqrt(wp.length_sq(q - p))
        if dist < best + eps:
            weight = pseudo_weight(a, b, c, q, eps)
            if dist > best - eps:  # as close as the lane's best: add to its normal
                acc = acc + weight * wp.normalize(normal)
                if dist < best or (dist == best and t < face):
                    best = dist
                    face = t
            else:  # closer by more than eps: start over
                best = dist
                face = t
                acc = weight * wp.normalize(normal)
    return best, face, acc, omega


@wp.func
def finish_closest(p: wp.vec3, d: float, f: int, normal_sum: wp.vec3, faces: wp.array2d(dtype=int),
                   x: wp.array(dtype=wp.vec3), far: float):
    """(found, face, u, v, sign) of the closest distance ``d`` on face ``f`` with the pseudo-normal
    sum ``normal_sum`` (Warp's outputs, computed as it does)."""
    if d >= far or f == NO_FACE:
        return False, int(0), float(0.0), float(0.0), float(1.0)
    a = x[faces[f, 0]]
    b = x[faces[f, 1]]
    c = x[faces[f, 2]]
    bc = closest_on_triangle(a, b, c, p)
    min_v = bc[1]
    min_w = 1.0 - bc[0] - bc[1]
    u = 1.0 - min_v - min_w
    sign = float(-1.0)
    if wp.dot(normal_sum, p - (a * u + b * min_v + c * min_w)) > 0.0:
        sign = 1.0
    return True, f, u, min_v, sign


@wp.func
def closest_signed_tiled(p: wp.vec3, lane: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                         tris: wp.array(dtype=int), start: int, n: int, far: float, eps: float, angles: int):
    """:func:`closest_signed` for a block: the closest point to ``p`` on the skin triangles listed in
    ``tris[start: start + n]`` within ``far`` (m), as (found, face, u, v, sign, omega) with Warp's
    conventions (the point u x0 + v x1 + (1 - u - v) x2 of face ``face``; sign +1 outside the skin,
    -1 inside) and, with ``angles``, the sum of the listed triangles' solid angles at p (sr, the
    local winding number's patch term; 0 without). Every thread of the block calls it (block
    reductions) and gets the same answer.

    Lane ``lane`` tests the list's entries lane, lane + block_dim, ... exactly as Warp's
    mesh_query_point_sign_normal tests a BVH leaf's triangles (slivers skipped; the same closest
    point and distance): it keeps its closest triangle (ties: the lowest face index) and, as Warp
    does, the angle-weighted sum of the normals of the triangles within ``eps`` (m) of its running
    minimum. The block's minimum distance d wins (ties: the lowest face index); the sign sums the
    normal sums of the lanes whose minimum is within ``eps`` of d, i.e. of the triangles within
    ~eps of d (Warp's own sum depends on the order it meets them in), and is +1 where the sum points
    from the closest point towards p (Warp's rule). On the CPU a block is one thread (block_dim 1),
    which then scans the whole list."""
    best, face, acc, omega = scan_closest(p, lane, wp.block_dim(), faces, x, tris, start, n, far, eps, angles)
    d = wp.tile_min(wp.tile(best))[0]
    near_face = int(NO_FACE)
    near_acc = wp.vec3(0.0)
    if best == d:
        near_face = face
    if best < d + eps:
        near_acc = acc
    f = wp.tile_min(wp.tile(near_face))[0]
    normal_sum = wp.tile_sum(wp.tile(near_acc, preserve_type=True))[0]
    total = float(0.0)
    if angles != 0:
        total = wp.tile_sum(wp.tile(omega))[0]
    found, f, u, v, sign = finish_closest(p, d, f, normal_sum, faces, x, far)
    return found, f, u, v, sign, total
