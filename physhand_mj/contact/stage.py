"""A contact stage in one launch (``Config.fused_stage``): the whole stage between grid barriers.

The recorded stage (contact.py) is a chain of launches: the stage's triangle lists, its feature list
with the first feature push, then per pass the feature push, its apply, the decision points (Eq. 9),
their apply and the next pass's list, each later pass behind a conditional graph node on CUDA. Here
the same phases run in one launch, separated by barriers instead of launches, and the passes are a
loop that stops after a pass that moved nothing (the same rule as activity.py's level 2). On CUDA
the launch is a block of ``STAGE_LANES`` threads per SM, all resident at once, and the barrier is
:func:`grid_sync` (a block barrier, then an arrival counter and a generation word in global memory
with fences on both sides); on the CPU a block is one thread and the barrier a no-op. Every phase
calls the per-item functions of the recorded kernels, so the decisions are theirs:

    stage lists         broadphase.stage_list_entry (a thread per frame-list triangle)
    feature list + push a warp per listed feature point: features.closest_warp, push_feature
    apply               query.apply_vertex (a thread per touched vertex)
    decision points     query.decide_triangle (a thread per listed triangle: the per-thread lattice)
    next list           broadphase.keep_if_moved

Counters go to the same slots of ``Contact.counters`` as the recorded stage's, so what ran is
reported alike. On the CPU the skin and every counter equal the recorded stage's bit for bit where
that stage runs CUDA's feature kernels (forced on the CPU in tests/test_stage.py); the CPU's default
feature path walks the skin's BVH with the pseudo-normal sign and differs. One world only.

Measured on an H100 (2026-11-25, docs/activity.md): correct (the hard cases' 600 held frames clean by
both measures), not faster. One block for the whole stage (the first design) took 12.8 ms a demo
frame against ~4 (eight warps on one SM wait on memory); a block per SM 4.15-4.18 against 4.03-4.36
ms held and 3x slower on the hard cases (the decision points' per-thread lattice and BVH walks are
the critical path there, where the recorded kernel gives each triangle a warp). Off by default.
"""

import warp as wp

from physhand_mj.contact.broadphase import keep_if_moved, stage_list_entry
from physhand_mj.contact.closest import FOUR_PI, NO_FACE, finish_closest, scan_closest
from physhand_mj.contact.features import at_origin, push_feature
from physhand_mj.contact.inside import object_point
from physhand_mj.contact.query import MULTIRES, apply_vertex, decide_triangle

# no adjoints: nothing here is differentiated, and the inlined stage's adjoint would multiply its
# (CUDA) compile time
wp.set_module_options({"enable_backward": False})

# triangles and geoms per world as one world passes them (broadphase.world_geoms: all geoms in use)
ONE_WORLD = 1 << 30

# threads of the block that runs a stage on CUDA (one on the CPU). At most 256: the mesh distance
# queries (decide_triangle on a mesh geom) walk Warp's BVH with a traversal stack in shared memory,
# 132 bytes a thread, and a block may hold 48 KB of static shared memory (sm_90: 512 threads needed
# 66 KB and ptxas refused the kernel; tests/test_cuda_build.py builds it without a GPU)
STAGE_LANES = 256
WARP = 32  # lanes per feature point on CUDA (a warp: shuffle reductions, no barrier)


# spins of a block's thread 0 at a grid barrier before it gives up and flags the launch (a block
# that never arrives: the grid was not resident at once); ~1 s at the 64 ns sleep per spin
BARRIER_SPINS = 1 << 24


@wp.func_native("""
#if defined(__CUDA_ARCH__)
__syncthreads();
if (gridDim.x > 1) {
    if (threadIdx.x == 0) {
        volatile int* gen = (volatile int*)(bar.data + 1);
        int g = *gen;
        __threadfence();
        if (atomicAdd(bar.data, 1) == (int)gridDim.x - 1) {
            atomicExch(bar.data, 0);
            __threadfence();
            atomicAdd(bar.data + 1, 1);
        } else {
            int spins = 0;
            while (*gen == g) {
                __nanosleep(64);
                if (++spins > spins_max) { atomicExch(bar.data + 2, 1); break; }
            }
        }
        __threadfence();
    }
    __syncthreads();
}
#endif
""")
def grid_sync(bar: wp.array(dtype=int), spins_max: int): ...


# grid_sync: a barrier over every thread of the launch: the block's threads, then (more than one
# block) the blocks through ``bar`` = [arrived, generation, stuck], with fences on both sides (what a
# block wrote before is seen by every block after). The blocks must all be resident at once (one per
# SM: record_stage); a block whose thread 0 waits more than ``spins_max`` spins sets ``bar[2]`` and
# goes on (Contact.raise_if_stuck raises after the frame). No-op on the CPU (one thread).


@wp.func_native("""
float r = v;
#if defined(__CUDA_ARCH__)
for (int o = 16; o > 0; o >>= 1) { float s = __shfl_xor_sync(0xffffffffu, r, o); r = s < r ? s : r; }
#endif
return r;
""")
def warp_min(v: float) -> float: ...


@wp.func_native("""
int r = v;
#if defined(__CUDA_ARCH__)
for (int o = 16; o > 0; o >>= 1) { int s = __shfl_xor_sync(0xffffffffu, r, o); r = s < r ? s : r; }
#endif
return r;
""")
def warp_min_int(v: int) -> int: ...


@wp.func_native("""
float r = v;
#if defined(__CUDA_ARCH__)
for (int o = 16; o > 0; o >>= 1) r += __shfl_xor_sync(0xffffffffu, r, o);
#endif
return r;
""")
def warp_sum(v: float) -> float: ...


@wp.func
def closest_signed_warp(p: wp.vec3, lane: int, lanes: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                        tris: wp.array(dtype=int), start: int, n: int, far: float, eps: float, angles: int):
    """closest.closest_signed_tiled with the ``lanes`` lanes of one warp (32 on CUDA, 1 on the CPU)
    instead of a block: the same scan, reductions by shuffles; every lane gets the answer."""
    best, face, acc, omega = scan_closest(p, lane, lanes, faces, x, tris, start, n, far, eps, angles)
    d = warp_min(best)
    near_face = int(NO_FACE)
    near_acc = wp.vec3(0.0)
    if best == d:
        near_face = face
    if best < d + eps:
        near_acc = acc
    f = warp_min_int(near_face)
    normal_sum = wp.vec3(warp_sum(near_acc[0]), warp_sum(near_acc[1]), warp_sum(near_acc[2]))
    total = float(0.0)
    if angles != 0:
        total = warp_sum(omega)
    found, f, u, v, sign = finish_closest(p, d, f, normal_sum, faces, x, far)
    return found, f, u, v, sign, total


@wp.func
def closest_warp(p: wp.vec3, i: int, lane: int, lanes: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                 tris: wp.array(dtype=int), tri_count: int, far: float, eps: float, winding: int,
                 slot: wp.array(dtype=int), pool: wp.array(dtype=int), patch_start: wp.array(dtype=int),
                 patch_len: wp.array(dtype=int), far_angle: wp.array(dtype=float)):
    """winding.closest_tiled by one warp: over feature point ``i``'s patch with the local winding
    number's sign, else (or where its patch did not fit the pool) over the frame's list ``tris``."""
    if winding != 0:
        k = slot[i]
        n = patch_len[k]
        if n >= 0:
            found, f, u, v, sign, omega = closest_signed_warp(p, lane, lanes, faces, x, pool, patch_start[k], n, far,
                                                              eps, 1)
            sign = float(1.0)
            if omega + far_angle[k] > 0.5 * FOUR_PI:
                sign = -1.0
            return found, f, u, v, sign
    found, f, u, v, sign, omega = closest_signed_warp(p, lane, lanes, faces, x, tris, 0, tri_count, far, eps, 0)
    return found, f, u, v, sign


@wp.func
def feature_phase(lane: int, lanes: int, items: wp.array(dtype=int), n_items: int, keep_list: int, keep: float,
                  kept: wp.array(dtype=int), kept_count: wp.array(dtype=int),
                  faces: wp.array2d(dtype=int), cand: wp.array(dtype=int), n_cand: int, pts: wp.array(dtype=wp.vec3),
                  pts_geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform), geom_obj: wp.array(dtype=int),
                  margin: float, offset: float, max_step: float, eps: float, x: wp.array(dtype=wp.vec3),
                  winding: int, slot: wp.array(dtype=int), pool: wp.array(dtype=int),
                  patch_start: wp.array(dtype=int), patch_len: wp.array(dtype=int), far_angle: wp.array(dtype=float),
                  delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=float), touched: wp.array(dtype=int),
                  touched_count: wp.array(dtype=int), vertex_obj: wp.array(dtype=int)):
    """The feature push of features.feature_contact_tiled over ``items[:n_items]``, a warp per
    feature; with ``keep_list`` also stage_features_tiled's list (into ``kept``)."""
    wl = wp.min(WARP, lanes)
    sub = lane % wl
    k = lane // wl
    while k < n_items:
        i = items[k]
        k += lanes // wl
        p = object_point(i, pts, pts_geom, pose)
        found, f, u, v, sign = closest_warp(p, i, sub, wl, faces, x, cand, n_cand, margin, eps, winding, slot, pool,
                                            patch_start, patch_len, far_angle)
        if sub == 0 and found:
            push = True
            if keep_list != 0:
                c = x[faces[f, 0]] * u + x[faces[f, 1]] * v + x[faces[f, 2]] * (1.0 - u - v)
                push = sign * wp.length(p - c) < keep
                if push:
                    kept[wp.atomic_add(kept_count, 0, 1)] = i
            if push:
                f0, u0, v0, p0 = at_origin(i, p, f, u, v, pts, pts_geom, pose, faces, x)
                push_feature(p0, f0, u0, v0, sign, geom_obj[pts_geom[i]], faces, offset, max_step, x, delta, hits,
                             touched, touched_count, vertex_obj)


@wp.func
def apply_phase(lane: int, lanes: int, touched: wp.array(dtype=int), n: int, stamp: int,
                delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=float), x: wp.array(dtype=wp.vec3),
                push: wp.array(dtype=float), moved: wp.array(dtype=int), disp: wp.array(dtype=float)):
    k = lane
    while k < n:
        apply_vertex(touched[k], stamp, delta, hits, x, push, moved, disp)
        k += lanes


@wp.kernel
def contact_stage(
    # Model and objects:
    faces: wp.array2d(dtype=int),
    gtype: wp.array(dtype=int),
    size: wp.array(dtype=wp.vec3),
    inv_pose: wp.array(dtype=wp.transform),
    pose: wp.array(dtype=wp.transform),
    radius: wp.array(dtype=float),
    mesh: wp.array(dtype=wp.vec2ul),
    mesh_exact: wp.array(dtype=wp.vec2ul),
    geom_count: wp.array(dtype=int),
    geom_obj: wp.array(dtype=int),
    # the frame's lists
    cand: wp.array(dtype=int),
    cand_mask: wp.array(dtype=int),
    feat: wp.array(dtype=int),
    feat_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    # settings
    slots: wp.array(dtype=int),
    stage: int,
    passes: int,
    margin: float,
    frame_margin: float,
    samples: int,
    rounds: int,
    offset: float,
    side_aware: int,
    feature_offset: float,
    feature_last_offset: float,
    eps: float,
    winding: int,
    feat_slot: wp.array(dtype=int),
    pool: wp.array(dtype=int),
    patch_start: wp.array(dtype=int),
    patch_len: wp.array(dtype=int),
    far_angle: wp.array(dtype=float),
    total: int,
    # state and contact buffers (read and written)
    x: wp.array(dtype=wp.vec3),
    counters: wp.array(dtype=int),
    active: wp.array(dtype=int),
    active_mask: wp.array(dtype=int),
    pass_list: wp.array(dtype=int),
    pass_mask: wp.array(dtype=int),
    feat_stage: wp.array(dtype=int),
    feat_stage_counts: wp.array(dtype=int),
    bound: wp.array(dtype=float),
    bound_mask: wp.array(dtype=int),
    eval_x: wp.array2d(dtype=wp.vec3),
    decision: wp.array(dtype=wp.vec4),
    delta: wp.array(dtype=wp.vec3),
    hits: wp.array(dtype=float),
    touched: wp.array(dtype=int),
    vertex_obj: wp.array(dtype=int),
    push: wp.array(dtype=float),
    moved: wp.array(dtype=int),
    disp: wp.array(dtype=float),
    bar: wp.array(dtype=int),
):
    """One contact stage (module docstring); launch one block: dim = block_dim = STAGE_LANES on
    CUDA, 1 on the CPU. ``slots``: the stage's counter slots [active list, first pass list, then per
    pass: Eq. 9's touched, the features' touched (-1: no features), the next pass's list (-1: last),
    the last push's touched (-1: none)]."""
    lane = wp.tid()
    lanes = total
    # the stage's active triangles (within contact_margin) of the frame's list, and its first pass's list
    s_act = slots[0]
    s_lst = slots[1]
    n_cand = counters[0]
    k = lane
    while k < n_cand:
        stage_list_entry(cand[k], cand_mask[k], faces, x, gtype, size, inv_pose, radius, mesh, geom_count,
                         ONE_WORLD, ONE_WORLD, margin, bound, bound_mask, eval_x, active, active_mask,
                         counters[s_act: s_act + 1], pass_list, pass_mask, counters[s_lst: s_lst + 1])
        k += lanes
    n_feat = feat_count[0]
    grid_sync(bar, BARRIER_SPINS)
    n_act = counters[s_act]
    # the stage's features (inside the skin or within contact_margin of it) and the first pass's push
    s_feat0 = slots[3]
    if s_feat0 >= 0:
        feature_phase(lane, lanes, feat, n_feat, 1, margin, feat_stage, feat_stage_counts[stage: stage + 1], faces,
                      cand, n_cand, pts, pts_geom, pose, geom_obj, frame_margin, feature_offset, margin, eps, x,
                      winding, feat_slot, pool, patch_start, patch_len, far_angle, delta, hits, touched,
                      counters[s_feat0: s_feat0 + 1], vertex_obj)
    grid_sync(bar, BARRIER_SPINS)
    n_stage = feat_stage_counts[stage]
    lst = s_lst
    for p in range(passes):
        b = 2 + 4 * p
        s_eq9 = slots[b]
        s_feat = slots[b + 1]
        s_next = slots[b + 2]
        s_last = slots[b + 3]
        stamp = s_eq9
        if s_feat >= 0:
            if p > 0:  # (the first pass's push came with the stage's list)
                feature_phase(lane, lanes, feat_stage, n_stage, 0, margin, feat_stage, feat_stage_counts, faces, cand,
                              n_cand, pts, pts_geom, pose, geom_obj, frame_margin, feature_offset, margin, eps, x,
                              winding, feat_slot, pool, patch_start, patch_len, far_angle, delta, hits, touched,
                              counters[s_feat: s_feat + 1], vertex_obj)
                grid_sync(bar, BARRIER_SPINS)
            apply_phase(lane, lanes, touched, counters[s_feat], stamp, delta, hits, x, push, moved, disp)
            grid_sync(bar, BARRIER_SPINS)
        # the decision points of the pass's list and Eq. 9 (a thread per triangle)
        n_lst = counters[lst]
        k = lane
        while k < n_lst:
            decide_triangle(pass_list[k], pass_mask[k], faces, gtype, size, inv_pose, radius, mesh_exact, geom_count,
                            geom_obj, ONE_WORLD, ONE_WORLD, MULTIRES, samples, rounds, 0, offset, side_aware, x, delta,
                            hits,
                            decision, vertex_obj, bound, bound_mask, eval_x, touched, counters[s_eq9: s_eq9 + 1])
            k += lanes
        grid_sync(bar, BARRIER_SPINS)
        apply_phase(lane, lanes, touched, counters[s_eq9], stamp, delta, hits, x, push, moved, disp)
        grid_sync(bar, BARRIER_SPINS)
        if s_last >= 0:  # the last feature push (Config.feature_last)
            feature_phase(lane, lanes, feat_stage, n_stage, 0, margin, feat_stage, feat_stage_counts, faces, cand,
                          n_cand, pts, pts_geom, pose, geom_obj, frame_margin, feature_last_offset, margin, eps, x,
                          winding, feat_slot, pool, patch_start, patch_len, far_angle, delta, hits, touched,
                          counters[s_last: s_last + 1], vertex_obj)
            grid_sync(bar, BARRIER_SPINS)
            apply_phase(lane, lanes, touched, counters[s_last], stamp, delta, hits, x, push, moved, disp)
            grid_sync(bar, BARRIER_SPINS)
        if s_next < 0:
            break
        moved_any = counters[s_eq9]
        if s_feat >= 0:
            moved_any += counters[s_feat]
        if moved_any == 0:  # the next pass would repeat this one on the same skin (activity.py level 2)
            break
        k = lane
        while k < n_act:
            keep_if_moved(active[k], active_mask[k], faces, moved, disp, stamp, bound, pass_list, pass_mask,
                          counters[s_next: s_next + 1])
            k += lanes
        grid_sync(bar, BARRIER_SPINS)
        lst = s_next


def record_stage(contact, launch, state) -> None:
    """Record one contact stage of ``contact`` (contact.Contact, ``fused``) as one launch of
    :func:`contact_stage`, its counters in the slots the recorded stage's launches use
    (Contact.record / _record_pass / _record_features take them in the same order)."""
    m, o, cfg = contact.model, contact.objects, contact.config
    feats = contact.feat is not None
    stage = len(contact._stage_slots)
    a = contact._slot
    contact._stage_slots.append((a, a + 2, a + 3 if feats else -1))
    contact.active_count = contact._counter()
    contact.pass_slots.append(contact._slot)
    contact._counter()
    slots = [a, a + 1]
    for p in range(cfg.contact_passes):
        eq9 = contact._slot
        contact._counter()
        feat = contact._slot if feats else -1
        if feats:
            contact._counter()
        last = -1
        if p + 1 == cfg.contact_passes and feats and cfg.feature_last:
            last = contact._slot
            contact._counter()
        nxt = -1
        if p + 1 < cfg.contact_passes:
            nxt = contact._slot
            contact.pass_slots.append(nxt)
            contact._counter()
        slots += [eq9, feat, nxt, last]
    pts = contact.points
    dummy = contact.cand
    # (no features listed this recording: the patch arrays may not exist; the stand-ins are never read)
    wind = contact._winding_args() if feats else [0, dummy, dummy, dummy, dummy, contact.feat_stage_float]
    total = contact.stage_blocks * contact.stage_lanes
    launch(contact_stage, total,
           [m.skin_faces, o.gtype, o.size, o.inv_pose, o.pose, o.radius, o.mesh, o.mesh_exact, o.count, o.obj,
            contact.cand, contact.cand_mask, contact.feat if feats else dummy, contact.feat_count, pts.pts, pts.geom,
            contact._slot_array(slots), stage, cfg.contact_passes, cfg.contact_margin, cfg.contact_frame_margin,
            cfg.multires_samples, cfg.multires_rounds, cfg.contact_offset, int(contact.closed_skin and cfg.side_aware),
            cfg.feature_offset, contact.last_push_offset, contact.feature_eps, *wind, total],
           [state.x, contact.counters, contact.active, contact.active_mask, contact.pass_list, contact.pass_mask,
            contact.feat_stage if feats else dummy, contact.feat_stage_counts, contact.bound, contact.bound_mask,
            contact.eval_x, contact.decision, contact.delta, contact.hits, contact.touched, contact.vertex_obj,
            contact.push, contact.moved, contact.disp, contact.stage_barrier],
           block_dim=contact.stage_lanes)
