"""CUDA's local-winding patches of one hand's listed feature points: a block of PATCH_LANES threads
per feature scans every skin triangle of its world (winding.feature_patches' job without the skin's
BVH). Its own module: Warp compiles a module per block size, and winding.py's other kernels do not
fit a block of 512 threads' shared memory."""

import warp as wp

from physhand_mj.contact.closest import solid_angle
from physhand_mj.contact.inside import object_point
from physhand_mj.contact.winding import Patches, patch_radius, within

wp.set_module_options({"enable_backward": False})  # forward only


PATCH_LANES = 512  # threads per listed feature in feature_patches_tiled (CUDA; the lanes stride the world's skin:
# each feature's block scans every skin triangle, ~10,000 for the embedded hand, a latency-bound loop; 128 lanes took
# ~110 us a frame on the held grasp, the frame's longest launch; docs/activity.md)


@wp.kernel
def feature_patches_tiled(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    feat: wp.array(dtype=int),
    feat_count: wp.array(dtype=int),
    stride: int,
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    radius: float,
    feat_dist: wp.array(dtype=float),
    slack: wp.array(dtype=float),
    tris_per_world: int,
    geoms_per_world: int,
    pool_count: wp.array(dtype=int),
    patches: Patches,
    patch_fill: wp.array(dtype=int),
):
    """:func:`feature_patches` with a block per listed feature (CUDA; launch (stride, PATCH_LANES),
    block b taking entries b, b + stride, ...): the lanes scan every skin triangle of the feature's world, so Omega_far is the far triangles'
    own solid-angle sum (no winding-number BVH, no integer w_0), and append the patch's triangles
    (in no fixed order; ``patch_fill`` zeroed per frame). On the CPU (block_dim 1) one thread scans
    them all."""
    blk, lane = wp.tid()
    lanes = wp.block_dim()
    k = blk
    n_feat = feat_count[0]
    while k < n_feat:  # (uniform over the block: k is the block's feature; every lane reaches the block reductions)
        i = feat[k]
        p = object_point(i, pts, pts_geom, pose)
        world = pts_geom[i] // geoms_per_world
        first = world * tris_per_world
        r = patch_radius(radius, feat_dist[k], slack[world])
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
            if within(p, t, faces, x, r):
                near += w
                cnt += 1
        n = wp.tile_sum(wp.tile(cnt))[0]
        far = wp.tile_sum(wp.tile(total))[0] - wp.tile_sum(wp.tile(near))[0]
        mine = int(-1)
        if lane == 0:
            mine = wp.atomic_add(pool_count, 0, n)
        start = wp.tile_max(wp.tile(mine))[0]
        if start < 0 or start > patches.pool.shape[0] - n:  # (no start + n: it wraps past 2^31; so does the counter)
            if lane == 0:
                patches.slot[i] = k
                patches.length[k] = -1
        else:
            j = first + lane
            while j < first + tris_per_world:
                t = j
                j += lanes
                if within(p, t, faces, x, r):
                    patches.pool[start + wp.atomic_add(patch_fill, k, 1)] = t
            if lane == 0:
                patches.slot[i] = k
                patches.start[k] = start
                patches.length[k] = n
                patches.far_angle[k] = far
        k += stride
