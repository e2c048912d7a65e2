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
skin's pseudo normals (the skin is closed and consistently wound), confirmed by a local winding number.

The local winding number (``Config.feature_winding``). Pseudo normals are exact on a closed surface
that does not fold, but a grasp squeezes skin triangles until some turn over (their normal points
into the hand), and a feature point in front of such a triangle is taken as inside although it is
outside: a spurious push. The generalised winding number w(p) = sum of the triangles' solid angles
/ 4 pi (Jacobson et al. 2013) has no such failure, but its BVH data cost a refit per pass. Split the
closed skin into the triangles near p (its *patch*: every skin triangle within ``contact_frame_margin``
of p at the frame's start) and the rest:

    w(p) = (Omega_patch(p) + Omega_far(p)) / 4 pi,   Omega_far = 4 pi w_0(p) - Omega_patch,0(p)

where w_0 is Warp's fast winding number at the frame's start (an integer: -1 past a fold that turned the
skin inside out), once per frame. Every pass
sums the patch's solid angles exactly (Van Oosterom and Strackee) and keeps Omega_far from the
frame's start: the far triangles stay farther from p than the frame broadphase's margin minus the
frame's motion (the broadphase's own assumption), so their solid angle changes smoothly and little
(w moves by a few hundredths for a 5 mm slide), far from the 1/2 that decides. On the CPU the
patch's sum confirms only the points the pseudo normal takes as inside (a push is at stake); the
CUDA kernels scan the patch instead of the frame's whole triangle list and take every sign from it.
"""

import warp as wp

from physhand_mj.contact.inside import object_point
from physhand_mj.contact.query import accumulate, depth_weight

FOUR_PI = 12.566370614359172


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
def patch_angle(p: wp.vec3, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), pool: wp.array(dtype=int),
                start: int, n: int):
    """Sum of the solid angles (sr) at ``p`` of the skin triangles pool[start: start + n]."""
    s = float(0.0)
    for j in range(start, start + n):
        t = pool[j]
        s += solid_angle(x[faces[t, 0]] - p, x[faces[t, 1]] - p, x[faces[t, 2]] - p)
    return s


@wp.func
def within(p: wp.vec3, t: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), radius: float):
    """Whether skin triangle ``t`` comes within ``radius`` (m) of ``p``."""
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    bc = closest_on_triangle(a, b, c, p)
    return wp.length(bc[0] * a + bc[1] * b + (1.0 - bc[0] - bc[1]) * c - p) <= radius


@wp.kernel
def feature_patches(
    skin: wp.uint64,
    skin_w: wp.uint64,
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    feat: wp.array(dtype=int),
    feat_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    radius: float,
    margin: float,
    pool_count: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    slot: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
):
    """Once per frame, for the k-th listed feature point i (module docstring, the local winding
    number): its patch (the skin triangles whose boxes meet the cube of half-size ``radius`` m around
    it, from ``skin``'s BVH, that come within ``radius`` of it) appended to ``pool``, and Omega_far = 4 pi w_0 - Omega_patch with w_0
    ``skin_w``'s fast winding number (an integer, -1 to 1). ``slot[i] = k``. A patch that does not
    fit the pool gets length -1 (its point keeps the pseudo-normal sign)."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    i = feat[k]
    slot[i] = k
    p = object_point(i, pts, pts_geom, pose)
    lo = p - wp.vec3(radius)
    hi = p + wp.vec3(radius)
    n = int(0)
    t = int(0)
    q = wp.mesh_query_aabb(skin, lo, hi)
    while wp.mesh_query_aabb_next(q, t):
        if within(p, t, faces, x, radius):
            n += 1
    start = wp.atomic_add(pool_count, 0, n)
    if start + n > pool.shape[0]:
        patch_len[k] = -1
        return
    size = n
    n = int(0)
    q = wp.mesh_query_aabb(skin, lo, hi)
    while wp.mesh_query_aabb_next(q, t):
        if within(p, t, faces, x, radius) and n < size:  # (the same triangles as counted)
            pool[start + n] = t
            n += 1
    # w_0 is an integer off the surface, and not only 0 or 1: a squeezed skin folds inside out
    # (w = -1 at points past the fold, measured on the demo); Warp's query gives only its side of a
    # threshold, so ask at -1/2 and 1/2 (w_0 = 2 where the skin overlaps itself counts as 1: the
    # point stays inside unless the skin moves across it twice)
    w0 = float(-1.0)
    r = wp.mesh_query_point_sign_winding_number(skin_w, p, margin, 2.0, -0.5)
    if not r.result:
        w0 = 0.0  # no skin within margin (a listed feature has)
    elif r.sign < 0.0:
        w0 = 0.0
        r = wp.mesh_query_point_sign_winding_number(skin_w, p, margin, 2.0, 0.5)
        if r.sign < 0.0:
            w0 = 1.0
    patch_start[k] = start
    patch_len[k] = n
    far_angle[k] = FOUR_PI * w0 - patch_angle(p, faces, x, pool, start, n)


@wp.func
def winding_sign(p: wp.vec3, i: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                 slot: wp.array(dtype=int), pool: wp.array(dtype=int), patch_start: wp.array(dtype=int),
                 patch_len: wp.array(dtype=int), far_angle: wp.array(dtype=float), sign: float):
    """The side of feature point ``i`` at ``p`` by the local winding number (+1 outside the skin, -1
    inside); ``sign`` (the pseudo normal's) where its patch did not fit the pool."""
    k = slot[i]
    n = patch_len[k]
    if n < 0:
        return sign
    if patch_angle(p, faces, x, pool, patch_start[k], n) + far_angle[k] > 0.5 * FOUR_PI:
        return -1.0
    return 1.0


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
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    winding: int,
    slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
    side: wp.array(dtype=float),
):
    """Of the frame's listed features, append those inside the skin or less than ``keep`` (m)
    outside it (the stage's list). With ``winding`` (the CPU's local winding number, module
    docstring) a kept point the pseudo normal takes as inside gets its side checked once per stage:
    ``side[slot[i]]`` -1 inside, +1 outside, 0 not checked (the pseudo normal took it as outside)."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    q = closest_signed(skin, p, near, margin)
    if q.result:
        if q.sign * wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v)) < keep:
            out[wp.atomic_add(out_count, 0, 1)] = i
            if winding != 0:
                sd = float(0.0)
                if q.sign < 0.0:
                    sd = winding_sign(p, i, faces, x, slot, pool, patch_start, patch_len, far_angle, q.sign)
                side[slot[i]] = sd


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
    winding: int,
    slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    side: wp.array(dtype=float),
    delta: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=float),
    touched: wp.array(dtype=int),
    touched_count: wp.array(dtype=int),
    vertex_obj: wp.array(dtype=int),
):
    """For each listed feature point inside the skin (or closer than offset / 2 outside it): the
    correction of the module docstring on its closest skin triangle, into ``delta``/``hits``. With
    ``winding`` a point the pseudo normal takes as inside takes its side from the local winding
    number (module docstring; ``x`` the skin as the queries see it): the stage's check
    (``side``, :func:`stage_features`) where it made one, else one now (kept for the stage)."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    i = cand[k]
    g = pts_geom[i]
    p = object_point(i, pts, pts_geom, pose)
    q = closest_signed(skin, p, near, margin)
    if not q.result:
        return
    sign = q.sign
    if winding != 0 and sign < 0.0:
        ks = slot[i]
        sign = side[ks]
        if sign == 0.0:  # taken as outside when the stage began: check now, for the rest of the stage
            sign = winding_sign(p, i, faces, x, slot, pool, patch_start, patch_len, far_angle, q.sign)
            side[ks] = sign
    f, u, v, p0 = at_origin(i, p, q.face, q.u, q.v, pts, pts_geom, pose0, faces, x0)
    push_feature(p0, f, u, v, sign, geom_obj[g], faces, offset, max_step, x0, delta, hits, touched,
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


@wp.func
def closest_scan(p: wp.vec3, i: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), far: float, eps: float,
                 slot: wp.array(dtype=int), pool: wp.array(dtype=int), patch_start: wp.array(dtype=int),
                 patch_len: wp.array(dtype=int), far_angle: wp.array(dtype=float)):
    """:func:`closest_tiled` by one thread over feature point ``i``'s patch (batched worlds on CUDA:
    a thread per listed feature, Config.tiled_features None): the same closest point and the local
    winding number's sign (not found where the patch did not fit the pool: Contact warns)."""
    k = slot[i]
    n = patch_len[k]
    if n < 0:
        return False, int(0), float(0.0), float(0.0), float(1.0)
    d, f, acc, omega = scan_closest(p, 0, 1, faces, x, pool, patch_start[k], n, far, eps, 1)
    found, f, u, v, sign = finish_closest(p, d, f, acc, faces, x, far)
    sign = float(1.0)
    if omega + far_angle[k] > 0.5 * FOUR_PI:
        sign = -1.0
    return found, f, u, v, sign


@wp.func
def closest_tiled(p: wp.vec3, i: int, lane: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                  tris: wp.array(dtype=int), tri_count: wp.array(dtype=int), far: float, eps: float, winding: int,
                  slot: wp.array(dtype=int), pool: wp.array(dtype=int), patch_start: wp.array(dtype=int),
                  patch_len: wp.array(dtype=int), far_angle: wp.array(dtype=float)):
    """:func:`closest_signed_tiled` for feature point ``i`` at ``p``: with ``winding`` over its patch
    (the triangles near it, module docstring) with the local winding number's sign; else (or where
    its patch did not fit the pool) over the frame's list ``tris`` with the pseudo-normal sign."""
    if winding != 0:  # (slot is read only then: off, a stand-in array is passed)
        k = slot[i]
        n = patch_len[k]
        if n >= 0:
            found, f, u, v, sign, omega = closest_signed_tiled(p, lane, faces, x, pool, patch_start[k], n, far, eps, 1)
            sign = float(1.0)
            if omega + far_angle[k] > 0.5 * FOUR_PI:
                sign = -1.0
            return found, f, u, v, sign
    found, f, u, v, sign, omega = closest_signed_tiled(p, lane, faces, x, tris, 0, tri_count[0], far, eps, 0)
    return found, f, u, v, sign


@wp.kernel
def feature_patches_tiled(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    feat: wp.array(dtype=int),
    feat_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    radius: float,
    tris_per_world: int,
    geoms_per_world: int,
    pool_count: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    slot: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    patch_fill: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
):
    """:func:`feature_patches` with a block per listed feature (CUDA; launch (n, FEATURE_LANES)):
    the lanes scan every skin triangle of the feature's world, so Omega_far is the far triangles'
    own solid-angle sum (no winding-number BVH, no integer w_0), and append the patch's triangles
    (in no fixed order; ``patch_fill`` zeroed per frame). On the CPU (block_dim 1) one thread scans
    them all."""
    k, lane = wp.tid()
    if k >= feat_count[0]:
        return  # uniform over the block
    i = feat[k]
    p = object_point(i, pts, pts_geom, pose)
    lanes = wp.block_dim()
    first = (pts_geom[i] // geoms_per_world) * tris_per_world
    total = float(0.0)
    near = float(0.0)
    cnt = int(0)
    j = first + lane
    while j < first + tris_per_world:
        t = j
        j += lanes
        a = x[faces[t, 0]]
        b = x[faces[t, 1]]
        c = x[faces[t, 2]]
        w = solid_angle(a - p, b - p, c - p)
        total += w
        if within(p, t, faces, x, radius):
            near += w
            cnt += 1
    n = wp.tile_sum(wp.tile(cnt))[0]
    far = wp.tile_sum(wp.tile(total))[0] - wp.tile_sum(wp.tile(near))[0]
    mine = int(-1)
    if lane == 0:
        mine = wp.atomic_add(pool_count, 0, n)
    start = wp.tile_max(wp.tile(mine))[0]
    if start + n > pool.shape[0]:
        if lane == 0:
            slot[i] = k
            patch_len[k] = -1
        return
    j = first + lane
    while j < first + tris_per_world:
        t = j
        j += lanes
        if within(p, t, faces, x, radius):
            pool[start + wp.atomic_add(patch_fill, k, 1)] = t
    if lane == 0:
        slot[i] = k
        patch_start[k] = start
        patch_len[k] = n
        far_angle[k] = far


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
    winding: int,
    slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
):
    """:func:`stage_features` with a block per listed feature (launch (n, FEATURE_LANES) with
    block_dim FEATURE_LANES on CUDA; (n, 1) on the CPU): the closest point by :func:`closest_tiled`
    (the feature's patch, or the skin triangles ``tris``: the frame's broadphase list)."""
    k, lane = wp.tid()
    if k >= cand_count[0]:
        return  # uniform over the block: k is the block's feature
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_tiled(p, i, lane, faces, x, tris, tri_count, margin, eps, winding, slot, pool,
                                         patch_start, patch_len, far_angle)
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
    winding: int,
    slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    delta: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=float),
    touched: wp.array(dtype=int),
    touched_count: wp.array(dtype=int),
    vertex_obj: wp.array(dtype=int),
):
    """:func:`feature_contact` with a block per listed feature (launched as
    :func:`stage_features_tiled`): the closest point by :func:`closest_tiled`, then lane 0 applies
    the same correction (:func:`push_feature`)."""
    k, lane = wp.tid()
    if k >= cand_count[0]:
        return  # uniform over the block
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_tiled(p, i, lane, faces, x, tris, tri_count, margin, eps, winding, slot, pool,
                                         patch_start, patch_len, far_angle)
    if lane != 0 or not found:
        return
    f0, u0, v0, p0 = at_origin(i, p, f, u, v, pts, pts_geom, pose0, faces, x0)
    push_feature(p0, f0, u0, v0, sign, geom_obj[pts_geom[i]], faces, offset, max_step, x0, delta, hits, touched,
                 touched_count, vertex_obj)


# -- CUDA batches: a thread per listed feature over its patch ---------------------------------------
# A block per feature fills a batch's launch with idle and reduction-bound blocks (the HOI box at W =
# 256: 140k listed features, feature_contact_tiled 55 ms of a 135 ms frame on an H100); one thread
# scanning the feature's ~170 patch triangles has the parallelism of the batch's features.


@wp.kernel
def stage_features_scan(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    cand: wp.array(dtype=int),
    cand_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    margin: float,
    keep: float,
    eps: float,
    slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
):
    """:func:`stage_features_tiled` with a thread per listed feature (:func:`closest_scan`)."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_scan(p, i, faces, x, margin, eps, slot, pool, patch_start, patch_len, far_angle)
    if not found:
        return
    c = x[faces[f, 0]] * u + x[faces[f, 1]] * v + x[faces[f, 2]] * (1.0 - u - v)
    if sign * wp.length(p - c) < keep:
        out[wp.atomic_add(out_count, 0, 1)] = i


@wp.kernel
def feature_contact_scan(
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
    eps: float,
    x: wp.array(dtype=wp.vec3),
    pose0: wp.array(dtype=wp.transform),
    x0: wp.array(dtype=wp.vec3),
    slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    delta: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=float),
    touched: wp.array(dtype=int),
    touched_count: wp.array(dtype=int),
    vertex_obj: wp.array(dtype=int),
):
    """:func:`feature_contact_tiled` with a thread per listed feature (:func:`closest_scan`)."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    i = cand[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_scan(p, i, faces, x, margin, eps, slot, pool, patch_start, patch_len, far_angle)
    if not found:
        return
    f0, u0, v0, p0 = at_origin(i, p, f, u, v, pts, pts_geom, pose0, faces, x0)
    push_feature(p0, f0, u0, v0, sign, geom_obj[pts_geom[i]], faces, offset, max_step, x0, delta, hits, touched,
                 touched_count, vertex_obj)
