"""Object features pushing the skin: the other side of the contact (corners, tips, sharp edges).

The skin-side decision points (query.py) find the lowest point of every skin triangle against the
objects' SDFs. A feature smaller than a triangle (a cone's tip, a knife edge, a thin plate's rim)
can poke through the triangle's interior with every sample of it outside: the skin's side cannot
see it. From the object's side the test is exact: a feature point p is inside the closed skin.
Then the skin triangle closest to p is moved so that p touches its interior from outside:

    q = sum_j w_j x_j  (closest skin point, barycentric w),  n = (p - q) / |p - q|  (into the hand)
    x_j <- x_j + w_j / (sum_k w_k^2) (|p - q| + offset) n

which moves q onto p + offset n (the minimum-norm correction of the three vertices that does so) and
pushes the skin into the hand, away from the object, whichever side of the object the skin is on.
In practice n is the triangle's inward normal (a push along p - q, tangential at an edge of the
triangle, would slide the skin along the object), and one pass moves q at most ``max_step``
(Config.contact_margin), so a feature that starts deep inside is worked out over passes and
substeps instead of throwing the skin across the hand.
Every contact pass applies these corrections (the depth-weighted mean per vertex, query.apply_contact)
and then Eq. 9's: one after the other, as Gauss-Seidel, since one mean of both let a rim's push and
Eq. 9 undo each other.

Work lists, so cost follows the features near the hand: once per frame the features within
``Config.contact_frame_margin`` of the skin are listed (a BVH query over the skin, refitted then);
every contact stage keeps of that list the features inside the skin or less than
``Config.contact_margin`` outside it (one signed query each: a pass moves the skin at most that far,
the same bound as the stage broadphase of triangles), and its passes test only those, refitting the
skin's BVH before each (no winding data: ~0.1 ms for 10k triangles on a CPU). Signs come from the
skin's pseudo normals (the skin is closed and consistently wound).
"""

import warp as wp

from physhand_mj.contact.inside import object_point
from physhand_mj.contact.query import accumulate, depth_weight


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


@wp.kernel
def near_features(
    skin: wp.uint64,
    feature: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    geom_count: wp.array(dtype=int),
    margin: float,
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
):
    """Append the feature points (indices into ``pts``) within ``margin`` (m) of the skin."""
    i = feature[wp.tid()]
    if pts_geom[i] >= geom_count[0]:
        return
    q = wp.mesh_query_point_no_sign(skin, object_point(i, pts, pts_geom, pose), margin)
    if q.result:
        out[wp.atomic_add(out_count, 0, 1)] = i


@wp.kernel
def stage_features(
    skin: wp.uint64,
    cand: wp.array(dtype=int),
    cand_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    margin: float,
    keep: float,
    near: float,
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
):
    """Of the frame's listed features, append those inside the skin or less than ``keep`` (m)
    outside it (the stage's list)."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    q = closest_signed(skin, p, near, margin)
    if q.result:
        if q.sign * wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v)) < keep:
            out[wp.atomic_add(out_count, 0, 1)] = i


@wp.func
def push_feature(p: wp.vec3, f: int, u: float, v: float, sign: float, obj: int, faces: wp.array2d(dtype=int),
                 offset: float, max_step: float, x: wp.array(dtype=wp.vec3), delta: wp.array(dtype=wp.vec3),
                 hits: wp.array(dtype=float), touched: wp.array(dtype=int), touched_count: wp.array(dtype=int),
                 vertex_obj: wp.array(dtype=int)):
    """The correction of the module docstring for feature point ``p`` whose closest skin point is
    (u, v, 1 - u - v) on skin triangle ``f`` (the point u x0 + v x1 + (1 - u - v) x2, Warp's mesh
    query convention), ``sign`` +1 outside the skin / -1 inside: into ``delta``/``hits`` when p is
    inside (or closer than offset / 2 outside) and inside the triangle's plane."""
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    w0 = u
    w1 = v
    w2 = 1.0 - u - v
    c = x[i0] * w0 + x[i1] * w1 + x[i2] * w2
    dist = wp.length(p - c)
    s = sign * dist  # > 0 outside the skin
    if s >= 0.5 * offset:
        return
    # along the triangle's inward normal m: far enough that p ends ``offset`` outside its plane
    # (a tangential push would slide the skin along the object), at most ``max_step`` per pass
    m = -wp.normalize(wp.cross(x[i1] - x[i0], x[i2] - x[i0]))
    need = wp.dot(p - c, m) + offset
    if need <= 0.0:
        return  # p is outside this triangle's plane: the skin's side handles it
    corr = m * wp.min(need, max_step)
    inv = 1.0 / (w0 * w0 + w1 * w1 + w2 * w2)
    # each vertex's say in its mean: the depth weight times its share (floored: a weight must be > 0)
    wd = depth_weight(need)
    v0 = wd * wp.max(w0, 1.0e-3)
    v1 = wd * wp.max(w1, 1.0e-3)
    v2 = wd * wp.max(w2, 1.0e-3)
    accumulate(i0, i1, i2, corr * (w0 * inv), corr * (w1 * inv), corr * (w2 * inv), v0, v1, v2, obj, delta,
               hits, touched, touched_count, vertex_obj)


@wp.func
def at_origin(i: int, p: wp.vec3, f: int, u: float, v: float, pts: wp.array(dtype=wp.vec3),
              pts_geom: wp.array(dtype=int), pose0: wp.array(dtype=wp.transform), faces: wp.array2d(dtype=int),
              x0: wp.array(dtype=wp.vec3)):
    """Batched worlds query their object side moved to their place on a grid (Contact.set_query_offsets);
    the push is computed where the world is solved: feature point ``i`` with the unshifted poses
    ``pose0``, and its closest point on face ``f`` of the unshifted skin ``x0`` again (as Warp's query
    computes it, :func:`closest_on_triangle`), so a shifted world pushes as its serial run does. A
    world that is not shifted (p equal at both places) keeps the query's (u, v). Returns (f, u, v, p0)."""
    p0 = object_point(i, pts, pts_geom, pose0)
    if p0[0] == p[0] and p0[1] == p[1] and p0[2] == p[2]:
        return f, u, v, p0
    bc = closest_on_triangle(x0[faces[f, 0]], x0[faces[f, 1]], x0[faces[f, 2]], p0)
    min_v = bc[1]
    min_w = 1.0 - bc[0] - bc[1]
    return f, 1.0 - min_v - min_w, min_v, p0


@wp.kernel
def feature_contact(
    skin: wp.uint64,
    faces: wp.array2d(dtype=int),
    cand: wp.array(dtype=int),
    cand_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    geom_obj: wp.array(dtype=int),
    margin: float,
    offset: float,
    max_step: float,
    near: float,
    x: wp.array(dtype=wp.vec3),
    pose0: wp.array(dtype=wp.transform),
    x0: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=float),
    touched: wp.array(dtype=int),
    touched_count: wp.array(dtype=int),
    vertex_obj: wp.array(dtype=int),
):
    """For each listed feature point inside the skin (or closer than offset / 2 outside it): the
    correction of the module docstring on its closest skin triangle, into ``delta``/``hits``."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    i = cand[k]
    g = pts_geom[i]
    p = object_point(i, pts, pts_geom, pose)
    q = closest_signed(skin, p, near, margin)
    if not q.result:
        return
    f, u, v, p0 = at_origin(i, p, q.face, q.u, q.v, pts, pts_geom, pose0, faces, x0)
    push_feature(p0, f, u, v, q.sign, geom_obj[g], faces, offset, max_step, x0, delta, hits, touched,
                 touched_count, vertex_obj)


# -- CUDA: a block per feature ---------------------------------------------------------------------
# One thread walking the skin's BVH per feature is latency-bound on a GPU (a pass tests ~100
# features: 80 launches of feature_contact took 8.8 ms of an 18 ms demo frame on an H100, plus a
# BVH refit before each). The tiled kernels give each listed feature a block of FEATURE_LANES
# threads that scan the frame's broadphase list of skin triangles (contact.py ``cand``: every
# triangle that can come within ``Config.contact_frame_margin`` of an object in the frame, so every
# triangle within that radius of an object point, the BVH query's radius) with exact
# closest-point tests, and block reductions pick the closest. They read the skin positions
# directly: no BVH, no refit.

FEATURE_LANES = 128  # threads per listed feature in the CUDA tiled kernels (lanes stride the triangle list)
NO_FACE = 2147483647  # a lane that found no triangle (larger than any face index)


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
def closest_signed_tiled(p: wp.vec3, lane: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                         tris: wp.array(dtype=int), tri_count: wp.array(dtype=int), far: float, eps: float):
    """:func:`closest_signed` for a block: the closest point to ``p`` on the skin triangles listed in
    ``tris`` (``tri_count[0]`` of them) within ``far`` (m), as (found, face, u, v, sign) with Warp's
    conventions (the point u x0 + v x1 + (1 - u - v) x2 of face ``face``; sign +1 outside the skin,
    -1 inside). Every thread of the block calls it (block reductions) and gets the same answer.

    Lane ``lane`` tests the list's entries lane, lane + block_dim, ... exactly as Warp's
    mesh_query_point_sign_normal tests a BVH leaf's triangles (slivers skipped; the same closest
    point and distance): it keeps its closest triangle (ties: the lowest face index) and, as Warp
    does, the angle-weighted sum of the normals of the triangles within ``eps`` (m) of its running
    minimum. The block's minimum distance d wins (ties: the lowest face index); the sign sums the
    normal sums of the lanes whose minimum is within ``eps`` of d, i.e. of the triangles within
    ~eps of d (Warp's own sum depends on the order it meets them in), and is +1 where the sum points
    from the closest point towards p (Warp's rule). On the CPU a block is one thread (block_dim 1),
    which then scans the whole list."""
    lanes = wp.block_dim()
    best = far
    face = int(NO_FACE)
    acc = wp.vec3(0.0)
    n = tri_count[0]
    j = lane
    while j < n:
        t = tris[j]
        j += lanes
        a = x[faces[t, 0]]
        b = x[faces[t, 1]]
        c = x[faces[t, 2]]
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
    d = wp.tile_min(wp.tile(best))[0]
    near_face = int(NO_FACE)
    near_acc = wp.vec3(0.0)
    if best == d:
        near_face = face
    if best < d + eps:
        near_acc = acc
    f = wp.tile_min(wp.tile(near_face))[0]
    normal_sum = wp.tile_sum(wp.tile(near_acc, preserve_type=True))[0]
    if d >= far or f == NO_FACE:
        return False, int(0), float(0.0), float(0.0), float(1.0)
    a = x[faces[f, 0]]
    b = x[faces[f, 1]]
    c = x[faces[f, 2]]
    bc = closest_on_triangle(a, b, c, p)
    min_v = bc[1]
    min_w = 1.0 - bc[0] - bc[1]
    u = 1.0 - min_v - min_w  # Warp's outputs, computed as it does
    sign = float(-1.0)
    if wp.dot(normal_sum, p - (a * u + b * min_v + c * min_w)) > 0.0:
        sign = 1.0
    return True, f, u, min_v, sign


@wp.kernel
def stage_features_tiled(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    tris: wp.array(dtype=int),
    tri_count: wp.array(dtype=int),
    cand: wp.array(dtype=int),
    cand_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    margin: float,
    keep: float,
    eps: float,
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
):
    """:func:`stage_features` with a block per listed feature (launch (n, FEATURE_LANES) with
    block_dim FEATURE_LANES on CUDA; (n, 1) on the CPU): the closest point by
    :func:`closest_signed_tiled` over the skin triangles ``tris`` (the frame's broadphase list)."""
    k, lane = wp.tid()
    if k >= cand_count[0]:
        return  # uniform over the block: k is the block's feature
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_signed_tiled(p, lane, faces, x, tris, tri_count, margin, eps)
    if lane != 0 or not found:
        return
    c = x[faces[f, 0]] * u + x[faces[f, 1]] * v + x[faces[f, 2]] * (1.0 - u - v)
    if sign * wp.length(p - c) < keep:
        out[wp.atomic_add(out_count, 0, 1)] = i


@wp.kernel
def feature_contact_tiled(
    faces: wp.array2d(dtype=int),
    tris: wp.array(dtype=int),
    tri_count: wp.array(dtype=int),
    cand: wp.array(dtype=int),
    cand_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    geom_obj: wp.array(dtype=int),
    margin: float,
    offset: float,
    max_step: float,
    eps: float,
    x: wp.array(dtype=wp.vec3),
    pose0: wp.array(dtype=wp.transform),
    x0: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=float),
    touched: wp.array(dtype=int),
    touched_count: wp.array(dtype=int),
    vertex_obj: wp.array(dtype=int),
):
    """:func:`feature_contact` with a block per listed feature (launched as
    :func:`stage_features_tiled`): the closest point by :func:`closest_signed_tiled`, then lane 0
    applies the same correction (:func:`push_feature`)."""
    k, lane = wp.tid()
    if k >= cand_count[0]:
        return  # uniform over the block
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_signed_tiled(p, lane, faces, x, tris, tri_count, margin, eps)
    if lane != 0 or not found:
        return
    f0, u0, v0, p0 = at_origin(i, p, f, u, v, pts, pts_geom, pose0, faces, x0)
    push_feature(p0, f0, u0, v0, sign, geom_obj[pts_geom[i]], faces, offset, max_step, x0, delta, hits, touched,
                 touched_count, vertex_obj)
