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
    f = q.face
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    w0 = q.u
    w1 = q.v
    w2 = 1.0 - q.u - q.v
    c = x[i0] * w0 + x[i1] * w1 + x[i2] * w2
    dist = wp.length(p - c)
    s = q.sign * dist  # > 0 outside the skin
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
    accumulate(i0, i1, i2, corr * (w0 * inv), corr * (w1 * inv), corr * (w2 * inv), v0, v1, v2, geom_obj[g], delta,
               hits, touched, touched_count, vertex_obj)
