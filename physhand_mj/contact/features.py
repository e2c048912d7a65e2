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
(Config.tuning.contact_margin), so a feature that starts deep inside is worked out over passes and
substeps instead of throwing the skin across the hand.
Every contact pass applies these corrections (the depth-weighted mean per vertex, query.apply_contact)
and then Eq. 9's: one after the other, as Gauss-Seidel, since one mean of both let a rim's push and
Eq. 9 undo each other.

Work lists, so cost follows the features near the hand: once per frame the features within
``Config.contact_frame_margin`` of the skin are listed (a BVH query over the skin, refitted then);
every contact stage keeps of that list the features inside the skin or less than
``Config.tuning.contact_margin`` outside it (one signed query each: a pass moves the skin at most that far,
the same bound as the stage broadphase of triangles), and its passes test only those, refitting the
skin's BVH before each (no winding data: ~0.1 ms for 10k triangles on a CPU). Signs come from the
skin's pseudo normals (the skin is closed and consistently wound), confirmed by a local winding number.

How far the lists reach (``Config.tuning.feature_slack``, since 2026-11-27): :mod:`physhand_mj.contact.slack`.
"""

import functools

import warp as wp

from physhand_mj.contact.closest import closest_on_triangle, closest_signed
from physhand_mj.contact.inside import object_point
from physhand_mj.contact.query import PushSums, accumulate, depth_weight
from physhand_mj.contact.winding import Patches, closest_scan, closest_tiled, winding_sign

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

WALL_COS = wp.constant(0.1)  # a wall's face point pushes a skin triangle whose inward normal is within 90 degrees of its own


@wp.kernel
def near_features(
    skin: wp.uint64,
    feature: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    geom_count: wp.array(dtype=int),
    margin: float,
    keep: float,
    slack: wp.array(dtype=float),
    share: float,
    geoms_per_world: int,
    out: wp.array(dtype=int),
    out_count: wp.array(dtype=int),
    out_dist: wp.array(dtype=float),
    pt_dist: wp.array(dtype=float),
    pt_face: wp.array(dtype=int),
    world_count: wp.array(dtype=int),
):
    """Append the feature points (indices into ``pts``) within ``keep`` (m) plus ``share`` of their
    world's ``slack`` s (m, the skin's motion a frame allows for: Config.tuning.feature_slack; the share:
    Config.feature_list_share) of the skin, and those farther but within ``margin`` (m) that the
    skin's pseudo normals put inside it (a deep point is pushed however far the slack is), with
    their distance to the skin (``out_dist``, m, in list order; by point ``pt_dist``, signed by the
    pseudo normals, negative inside, and ``pt_face``, the closest skin triangle; per world the
    points listed, ``world_count``). Every distance is capped at ``margin``, and a slack at the
    margin lists every point within it (the lists before the slack). A point farther than
    its list's reach but within keep + s is measured and not listed: ``pt_dist`` its distance,
    ``pt_face`` -1 (the frame's check, slack.certify_features, asks what move could bring it within
    keep); the others keep the slack.UNLISTED the frame starts them with."""
    i = feature[wp.tid()]
    if pts_geom[i] >= geom_count[0]:
        return
    p = object_point(i, pts, pts_geom, pose)
    s = slack[pts_geom[i] // geoms_per_world]
    ask = wp.min(margin, keep + s)
    q = wp.mesh_query_point_sign_normal(skin, p, ask)
    listed = False
    d = float(0.0)
    if q.result:
        d = wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v))
        lim = margin  # (a slack at the margin: every point within it, the lists before the slack)
        if s < margin:
            lim = wp.min(margin, keep + share * s)
        listed = d <= lim or q.sign < 0.0
        if not listed:  # (outside, in the band the list leaves out)
            pt_dist[i] = d
            pt_face[i] = -1
    elif ask < margin:
        q = wp.mesh_query_point_sign_normal(skin, p, margin)
        listed = q.result and q.sign < 0.0
        if listed:
            d = wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v))
    if listed:
        k = wp.atomic_add(out_count, 0, 1)
        out[k] = i
        out_dist[k] = d
        pt_dist[i] = wp.where(q.sign < 0.0, -d, d)
        pt_face[i] = q.face
        wp.atomic_add(world_count, pts_geom[i] // geoms_per_world, 1)


@wp.func
def push_feature(p: wp.vec3, f: int, u: float, v: float, sign: float, obj: int, faces: wp.array2d(dtype=int),
                 offset: float, max_step: float, x: wp.array(dtype=wp.vec3), sums: PushSums,
                 touched_count: wp.array(dtype=int), normal: wp.vec3):
    """The correction of the module docstring for feature point ``p`` whose closest skin point is
    (u, v, 1 - u - v) on skin triangle ``f`` (the point u x0 + v x1 + (1 - u - v) x2, Warp's mesh
    query convention), ``sign`` +1 outside the skin / -1 inside: into ``sums`` when p is
    inside (or closer than offset / 2 outside) and inside the triangle's plane. A wall's face point
    (``normal``: its world outward normal; zero for a feature) pushes only a triangle whose inward
    normal it faces (WALL_COS): the face the skin must end against, not the one it must end away from."""
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
    if wp.length(normal) > 0.0:  # a wall's face point: through the wall, along its normal
        cn = wp.dot(normal, m)
        if cn <= WALL_COS:
            return
        corr = normal * wp.min(need / cn, max_step)
    inv = 1.0 / (w0 * w0 + w1 * w1 + w2 * w2)
    # each vertex's say in its mean: the depth weight times its share (floored: a weight must be > 0)
    wd = depth_weight(need)
    v0 = wd * wp.max(w0, 1.0e-3)
    v1 = wd * wp.max(w1, 1.0e-3)
    v2 = wd * wp.max(w2, 1.0e-3)
    accumulate(i0, i1, i2, corr * (w0 * inv), corr * (w1 * inv), corr * (w2 * inv), v0, v1, v2, obj, sums,
               touched_count)


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


# -- CUDA batches: a thread per listed feature over its patch ---------------------------------------
# A block per feature fills a batch's launch with idle and reduction-bound blocks (the HOI box at W =
# 256: 140k listed features, feature_contact_tiled 55 ms of a 135 ms frame on an H100); one thread
# scanning the feature's ~170 patch triangles has the parallelism of the batch's features.

SEARCHES = ("bvh", "tiled", "scan")


@functools.cache  # (one kernel per (search, stage), made once: Warp hashes the module's kernels)
def feature_kernel(search: str, stage: bool):
    """The feature kernel that finds each listed feature's closest skin point by ``search`` and,
    with ``stage``, lists the stage's features (:func:`stage_features` ...), else pushes (:func:`feature_contact` ...):

    - "bvh": the skin's BVH (``skin``, refitted; ``near``), a thread per feature (the CPU);
    - "tiled": a block of FEATURE_LANES lanes per feature (:func:`closest_tiled`: its patch with
      ``winding``, else the frame's triangle list ``tris``), launched (stride, FEATURE_LANES) with
      block_dim FEATURE_LANES on CUDA, (stride, 1) on the CPU, block b taking entries b, b + stride,
      ... (launch.tiled_blocks);
    - "scan": a thread per feature over its patch (:func:`closest_scan`; CUDA batches).

    Every variant takes the same arguments (:func:`feature_inputs`); the ones its search does not
    read may be None (0 for ``skin``)."""
    if search not in SEARCHES:
        raise ValueError(f"feature_kernel: search must be one of {SEARCHES}, got {search!r}")
    BVH = search == "bvh"
    TILED = search == "tiled"
    # a BVH stage only lists (and takes the sides of) its features; the others push them as the
    # stage's first pass would in the same launch (its skin is the one the list is made on)
    STAGE = bool(stage)
    PUSH = not STAGE or not BVH

    def kernel(
        # Skin:
        skin: wp.uint64,
        faces: wp.array2d(dtype=int),
        x: wp.array(dtype=wp.vec3),
        tris: wp.array(dtype=int),
        tri_count: wp.array(dtype=int),
        # The list walked:
        cand: wp.array(dtype=int),
        cand_count: wp.array(dtype=int),
        stride: int,
        # Objects:
        pts: wp.array(dtype=wp.vec3),
        pts_geom: wp.array(dtype=int),
        pts_normal: wp.array(dtype=wp.vec3),
        pose: wp.array(dtype=wp.transform),
        geom_obj: wp.array(dtype=int),
        # Contact in:
        margin: float,
        keep: float,
        near: float,
        eps: float,
        offset: float,
        max_step: float,
        pose0: wp.array(dtype=wp.transform),
        x0: wp.array(dtype=wp.vec3),
        winding: int,
        patches: Patches,
        side: wp.array(dtype=float),
        # Contact out:
        out: wp.array(dtype=int),
        out_count: wp.array(dtype=int),
        sums: PushSums,
        touched_count: wp.array(dtype=int),
    ):
        if wp.static(TILED):
            blk, lane = wp.tid()
            k = blk
            n = cand_count[0]
            step = stride
        else:  # (a thread per entry: Warp's grid-stride loop walks the list)
            k = wp.tid()
            lane = int(0)
            n = wp.min(k + 1, cand_count[0])
            step = int(1)
        while k < n:  # (tiled: uniform over the block, k is the block's feature; every lane reaches the block reductions)
            i = cand[k]
            p = object_point(i, pts, pts_geom, pose)
            if wp.static(BVH):
                q = closest_signed(skin, p, near, margin)
                found = q.result
                f = q.face
                u = q.u
                v = q.v
                sign = q.sign
            elif wp.static(TILED):
                found, f, u, v, sign = closest_tiled(p, i, lane, faces, x, tris, tri_count, margin, eps, winding,
                                                     patches)
            else:
                found, f, u, v, sign = closest_scan(p, i, faces, x, margin, eps, patches)
            if lane == 0 and found:
                push = True
                if wp.static(STAGE):  # the stage's list: inside the skin or less than keep outside it
                    c = wp.vec3(0.0)
                    if wp.static(BVH):
                        c = wp.mesh_eval_position(skin, f, u, v)
                    else:
                        c = x[faces[f, 0]] * u + x[faces[f, 1]] * v + x[faces[f, 2]] * (1.0 - u - v)
                    push = sign * wp.length(p - c) < keep
                    if push:
                        out[wp.atomic_add(out_count, 0, 1)] = i
                        if wp.static(BVH and STAGE):  # the side of a point the pseudo normal takes as inside
                            if winding != 0:
                                sd = float(0.0)
                                if sign < 0.0:
                                    sd = winding_sign(p, i, faces, x, patches, sign)
                                side[patches.slot[i]] = sd
                elif wp.static(BVH):  # the stage's side where it took one, else one now (kept for the stage)
                    if winding != 0 and sign < 0.0:
                        ks = patches.slot[i]
                        s0 = sign
                        sign = side[ks]
                        if sign == 0.0:  # taken as outside when the stage began
                            sign = winding_sign(p, i, faces, x, patches, s0)
                            side[ks] = sign
                if wp.static(PUSH):
                    if push:
                        f0, u0, v0, p0 = at_origin(i, p, f, u, v, pts, pts_geom, pose0, faces, x0)
                        nw = wp.quat_rotate(wp.transform_get_rotation(pose0[pts_geom[i]]), pts_normal[i])
                        push_feature(p0, f0, u0, v0, sign, geom_obj[pts_geom[i]], faces, offset, max_step, x0, sums,
                                     touched_count, nw)
            k += step

    # the kernels' own names (profiles, tests), not the factory's
    kernel.__name__ = kernel.__qualname__ = ("stage_features" if STAGE else "feature_contact") + (
        "" if BVH else "_" + search)
    return wp.kernel(kernel)


def feature_inputs(faces, x, cand, cand_count, pts, pts_geom, pts_normal, pose, margin: float, *, skin=0, tris=None,
                   tri_count=None, stride: int = 0, geom_obj=None, keep: float = 0.0, near: float = 0.0,
                   eps: float = 0.0, offset: float = 0.0, max_step: float = 0.0, pose0=None, x0=None,
                   winding=(0, None), side=None, out=None, out_count=None,
                   push=(None, None)) -> list:
    """The arguments of a :func:`feature_kernel` launch in its order; ``winding``: (on, patches), the
    local winding number's switch and its patches (winding.Patches); ``push``: (sums, touched_count), the accumulators
    (query.PushSums) and the touched list's counter. What the variant does not read may stay None."""
    (on, patches), (sums, touched_count) = winding, push
    return [skin, faces, x, tris, tri_count, cand, cand_count, stride, pts, pts_geom, pts_normal, pose, geom_obj,
            margin, keep,
            near, eps, offset, max_step, pose0, x0, on, Patches() if patches is None else patches, side, out, out_count,
            PushSums() if sums is None else sums, touched_count]


stage_features = feature_kernel("bvh", True)
"""Of the frame's listed features, append those inside the skin or less than ``keep`` (m) outside it
(the stage's list). With ``winding`` (the CPU's local winding number, module docstring) a kept point
the pseudo normal takes as inside gets its side checked once per stage: ``side[slot[i]]`` -1 inside,
+1 outside, 0 not checked (the pseudo normal took it as outside)."""
feature_contact = feature_kernel("bvh", False)
"""For each listed feature point inside the skin (or closer than offset / 2 outside it): the
correction of the module docstring on its closest skin triangle, into ``sums``. With
``winding`` a point the pseudo normal takes as inside takes its side from the local winding number
(module docstring; ``x`` the skin as the queries see it): the stage's check (``side``,
:func:`stage_features`) where it made one, else one now (kept for the stage)."""
stage_features_tiled = feature_kernel("tiled", True)
""":func:`stage_features` with a block per listed feature: the closest point by :func:`closest_tiled`
(the feature's patch, or the skin triangles ``tris``: the frame's broadphase list). The stage's first
pass sees the skin its list is made on, so the same closest point also gives that pass's push
(:func:`feature_contact_tiled`'s, into ``sums``) in this launch: a point it pushes
(inside, or closer than offset / 2 outside) is always kept (keep >= offset / 2)."""
feature_contact_tiled = feature_kernel("tiled", False)
""":func:`feature_contact` with a block per listed feature: the closest point by :func:`closest_tiled`,
then lane 0 applies the same correction (:func:`push_feature`)."""
stage_features_scan = feature_kernel("scan", True)
""":func:`stage_features_tiled` with a thread per listed feature (:func:`closest_scan`), with the
stage's first feature push likewise."""
feature_contact_scan = feature_kernel("scan", False)
""":func:`feature_contact_tiled` with a thread per listed feature (:func:`closest_scan`)."""
