"""The local winding number of the object's side: is a feature point inside the closed skin?

The local winding number (``Config.tuning.feature_winding``). Pseudo normals are exact on a closed surface
that does not fold, but a grasp squeezes skin triangles until some turn over (their normal points
into the hand), and a feature point in front of such a triangle is taken as inside although it is
outside: a spurious push. The generalised winding number w(p) = sum of the triangles' solid angles
/ 4 pi (Jacobson et al. 2013) has no such failure, but its BVH data cost a refit per pass. Split the
closed skin into the triangles near p (its *patch*: every skin triangle within d + s of p at the frame's
start, d its distance to the skin then and s its world's slack, at most ``contact_frame_margin``:
Config.tuning.feature_slack, slack.py) and the rest:

    w(p) = (Omega_patch(p) + Omega_far(p)) / 4 pi,   Omega_far = 4 pi w_0(p) - Omega_patch,0(p)

where w_0 is Warp's fast winding number at the frame's start (an integer: -1 past a fold that turned the
skin inside out), once per frame. Every pass
sums the patch's solid angles exactly (Van Oosterom and Strackee) and keeps Omega_far from the
frame's start: the far triangles stay farther from p than d + s minus the frame's motion (which
the frame checks against s: features.py), so their solid angle changes smoothly and little
(w moved by a few hundredths for a 5 mm slide with 1 cm patches; a move of delta across a patch's
rim of radius r changes it by about delta / 2r, under 1/4 while 2 delta < s <= r), far from the 1/2
that decides. On the CPU the
patch's sum confirms only the points the pseudo normal takes as inside (a push is at stake); the
CUDA kernels scan the patch instead of the frame's whole triangle list and take every sign from it.
"""

import warp as wp

from physhand_mj.contact.closest import (FOUR_PI, closest_on_triangle, closest_signed_tiled, finish_closest,
                                         scan_closest, solid_angle)
from physhand_mj.contact.inside import object_point, winding_number

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.struct
class Patches:
    """The listed feature points' patches as one kernel argument (data.FeatureLists' ``slot``,
    ``patch_pool``, ``patch_start``, ``patch_len`` and ``far_angle``, its ``patches``: made once
    with them, its pool again where the pool grows, after which the frames are recorded again).
    Without Config.feature_winding the feature list's arrays stand in (never read).

    slot (P,) int (per object point its listed feature's slot), pool (pool,) int (skin triangles),
    start (N,) int (per listed feature its patch's first entry in the pool), length (N,) int (its
    length, -1: no patch, it did not fit), far_angle (N,) float (the solid angle of the skin outside
    the patch)."""

    slot: wp.array(dtype=int)
    pool: wp.array(dtype=int)
    start: wp.array(dtype=int)
    length: wp.array(dtype=int)
    far_angle: wp.array(dtype=float)


def patches_of(slot, pool, start, length, far_angle) -> Patches:
    """A :class:`Patches` of the given arrays (held, not copied)."""
    s = Patches()
    s.slot, s.pool, s.start, s.length, s.far_angle = slot, pool, start, length, far_angle
    return s


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


# w_0's fast winding number (frame_winding): Warp's accuracy beta (a BVH node's dipole stands for its
# triangles beyond beta x its radius; the queries' default is 2) and the distance from an integer past
# which the answer is asked again at beta 2. At the 1.12 M listed points of 1,024 HOI box grasps, beta 1
# came within 0.060 of an integer (beta 2: 0.0024) at a fifth of the cost on an H100, a quarter on a
# CPU (benchmarks/feature_patch_split.py)
W0_ACCURACY = 1.0
W0_RETRY = 0.25


@wp.func
def frame_winding(skin_w: wp.uint64, p: wp.vec3, dist: float, margin: float):
    """w_0 at ``p``, ``dist`` (m) from the skin: Warp's fast winding number of the skin ``skin_w``
    rounded to -1, 0 or 1; 0 farther than ``margin`` (m) from the skin.

    w_0 is an integer off the surface, and not only 0 or 1: a squeezed skin folds inside out (w = -1
    at points past the fold, measured on the demo); rounded as Warp's sign queries would at the
    thresholds -1/2 and 1/2 (``wp.mesh_query_point_sign_winding_number(skin_w, p, margin, 2.0, -0.5)``
    then ``0.5``; w_0 = 2 where the skin overlaps itself counts as 1: the point stays inside unless the
    skin moves across it twice). Only the integer matters, so the winding number is first summed
    coarsely (W0_ACCURACY) and again at the queries' accuracy where that sum lies more than W0_RETRY
    from an integer; the distance is the caller's (a listed feature's, from its closest-point
    search), not searched again (tests/test_winding.py: equal to the two queries)."""
    if dist > margin:
        return 0.0
    wn = winding_number(skin_w, p, W0_ACCURACY)
    if not (wp.abs(wn - wp.round(wn)) <= W0_RETRY):  # (a NaN asks again too)
        wn = winding_number(skin_w, p, 2.0)
    if not (wn > -0.5):  # (the queries' test: sign -1 where w > threshold)
        return -1.0
    if wn > 0.5:
        return 1.0
    return 0.0


@wp.func
def patch_radius(most: float, dist: float, slack: float):
    """The patch radius (m) of a feature point ``dist`` from the skin at the frame's start in a world
    listed with ``slack`` (Config.tuning.feature_slack, slack.py): dist + slack, at most ``most``."""
    return wp.min(most, dist + slack)


@wp.func
def near_angle(p: wp.vec3, t: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), radius: float):
    """Whether skin triangle ``t`` comes within ``radius`` (m) of ``p`` (:func:`within`), and its solid
    angle (sr) at ``p`` (0 when it does not)."""
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    bc = closest_on_triangle(a, b, c, p)
    if wp.length(bc[0] * a + bc[1] * b + (1.0 - bc[0] - bc[1]) * c - p) <= radius:
        return True, solid_angle(a - p, b - p, c - p)
    return False, 0.0


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
    feat_dist: wp.array(dtype=float),
    slack: wp.array(dtype=float),
    geoms_per_world: int,
    most: int,
    pool_count: wp.array(dtype=int),
    patches: Patches,
):
    """Once per frame, for the k-th listed feature point i (module docstring, the local winding
    number): its patch (the skin triangles whose boxes meet the cube of half-size r around it, from
    ``skin``'s BVH, that come within r of it; r = :func:`patch_radius`) written to ``patches.pool``, and
    Omega_far = 4 pi w_0 - Omega_patch with w_0 ``skin_w``'s fast winding number (an integer, -1 to
    1). ``patches.slot[i] = k``.

    One walk of the BVH writes the patch to its own slot, pool[k c: (k + 1) c] (k < the listed
    count n, c = min(``most``, pool size // 2 n): the list's slots fill at most the pool's lower
    half), and sums its solid angles; a patch of more than c triangles is written again by a second
    walk at the pool's top (``pool_count[1]`` entries taken from the end down, never into the list's
    slots). A patch that does not fit gets length -1 (its point keeps the pseudo-normal sign) and
    counts in ``pool_count[2]``; ``pool_count[0]`` sums every patch's length (what a packed pool
    would need)."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    i = feat[k]
    pool = patches.pool
    patches.slot[i] = k
    p = object_point(i, pts, pts_geom, pose)
    r = patch_radius(radius, feat_dist[k], slack[pts_geom[i] // geoms_per_world])
    lo = p - wp.vec3(r)
    hi = p + wp.vec3(r)
    cap = wp.min(most, pool.shape[0] // wp.max(2 * feat_count[0], 1))
    start = k * cap
    n = int(0)
    t = int(0)
    omega = float(0.0)
    q = wp.mesh_query_aabb(skin, lo, hi)
    while wp.mesh_query_aabb_next(q, t):
        near, w = near_angle(p, t, faces, x, r)
        if near:
            if n < cap:
                pool[start + n] = t
            omega += w
            n += 1
    wp.atomic_add(pool_count, 0, n)
    if n > cap:  # (no start + n below: it wraps past 2^31; so do the counters)
        top = pool_count[1]  # (a full top fails unasked: the counter stays below 2^31 however many ask)
        if top <= pool.shape[0]:
            top = wp.atomic_add(pool_count, 1, n)
        if top < 0 or top > pool.shape[0] - n or pool.shape[0] - top - n < feat_count[0] * cap:
            patches.length[k] = -1
            wp.atomic_add(pool_count, 2, 1)
            return
        start = pool.shape[0] - top - n
        size = n
        n = int(0)
        q = wp.mesh_query_aabb(skin, lo, hi)
        while wp.mesh_query_aabb_next(q, t):
            near, w = near_angle(p, t, faces, x, r)
            if near and n < size:  # (the same test on the same triangles as the first walk)
                pool[start + n] = t
                n += 1
    patches.start[k] = start
    patches.length[k] = n
    patches.far_angle[k] = FOUR_PI * frame_winding(skin_w, p, feat_dist[k], margin) - omega


@wp.func
def winding_sign(p: wp.vec3, i: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), patches: Patches,
                 sign: float):
    """The side of feature point ``i`` at ``p`` by the local winding number (+1 outside the skin, -1
    inside); ``sign`` (the pseudo normal's) where its patch did not fit the pool."""
    k = patches.slot[i]
    n = patches.length[k]
    if n < 0:
        return sign
    if patch_angle(p, faces, x, patches.pool, patches.start[k], n) + patches.far_angle[k] > 0.5 * FOUR_PI:
        return -1.0
    return 1.0


@wp.func
def closest_scan(p: wp.vec3, i: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), far: float, eps: float,
                 patches: Patches):
    """:func:`closest_tiled` by one thread over feature point ``i``'s patch (batched worlds on CUDA:
    a thread per listed feature, Config.execution.tiled_features None): the same closest point and the local
    winding number's sign (not found where the patch did not fit the pool: Contact warns)."""
    k = patches.slot[i]
    n = patches.length[k]
    if n < 0:
        return False, int(0), float(0.0), float(0.0), float(1.0)
    d, f, acc, omega = scan_closest(p, 0, 1, faces, x, patches.pool, patches.start[k], n, far, eps, 1)
    found, f, u, v, sign = finish_closest(p, d, f, acc, faces, x, far)
    sign = float(1.0)
    if omega + patches.far_angle[k] > 0.5 * FOUR_PI:
        sign = -1.0
    return found, f, u, v, sign


@wp.func
def closest_tiled(p: wp.vec3, i: int, lane: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                  tris: wp.array(dtype=int), tri_count: wp.array(dtype=int), far: float, eps: float, winding: int,
                  patches: Patches):
    """:func:`closest_signed_tiled` for feature point ``i`` at ``p``: with ``winding`` over its patch
    (the triangles near it, module docstring) with the local winding number's sign; else (or where
    its patch did not fit the pool) over the frame's list ``tris`` with the pseudo-normal sign."""
    if winding != 0:  # (the patches are read only then: off, stand-in arrays are passed)
        k = patches.slot[i]
        n = patches.length[k]
        if n >= 0:
            found, f, u, v, sign, omega = closest_signed_tiled(p, lane, faces, x, patches.pool, patches.start[k], n, far,
                                                               eps, 1)
            sign = float(1.0)
            if omega + patches.far_angle[k] > 0.5 * FOUR_PI:
                sign = -1.0
            return found, f, u, v, sign
    found, f, u, v, sign, omega = closest_signed_tiled(p, lane, faces, x, tris, 0, tri_count[0], far, eps, 0)
    return found, f, u, v, sign
