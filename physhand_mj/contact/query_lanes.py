"""Multires decision points with a lane per lattice sample (Config.sample_lanes; off by default).

The per-thread kernel (query.decide_and_project) gives each thread a triangle: on the HOI bowl batch
Nsight Compute found its heavy passes running at 7.6-7.9 of 32 lanes a warp instruction, each lane
walking its own triangle's near faces, BVH paths and Voronoi regions (docs/scale.md). Here one pass
is split so that neighbouring lanes ask samples of the same triangle over the same near faces:

1. :func:`lanes_begin`, a thread per listed triangle: the per-triangle set-up of
   query.decide_triangle (its geom, its mesh's near faces found once), into per-entry scratch;
   entries past the scratch's capacity run the whole per-thread decide instead (:func:`lanes_overflow`,
   launched after the rounds, so Eq. 9's sums run in the list's order as the per-thread kernel's);
2. per round, :func:`lanes_samples`, a thread per (triangle, sample) on CUDA (a thread per
   triangle looping its samples on the CPU): each sample's phi, as query.decide_triangle asks it;
3. per round, :func:`lanes_reduce`, a thread per triangle: the three lowest in the lattice's order
   (the same points, recomputed by the same operations), the certification after the first round,
   the next round's triangle; after the last round the decision point, the bound and Eq. 9
   (query.project) as query.decide_triangle ends.

The same operations in the same order on the same values: the CPU's skins are bit for bit the
per-thread kernel's (tests/test_sample_lanes.py). The loops stride over the list (its length is on
the device), so a launch of G threads costs nothing past the list.

Measured on an H100 (2026-11-27, docs/scale.md): no faster. The bowl batch at W = 1,024 ran at
6,259-6,293 hand-frames/s against 6,269-6,360 per thread; its samples took 49.4 ms a frame, the
set-up 12.2 and the reductions 6.7, against 67.0 for the per-thread kernel. Grouping a triangle's
samples did not take out the cost the per-thread kernel's divergence suggested; what a sample costs
(its pruned walk over the near faces, their vertices fetched through the mesh's indices, the
pseudo-normal sign) is the next thing to look at, and this layout is where per-triangle data for
the samples (the near faces' vertices) could be prepared once. One hand: 11.0-11.2 ms a frame
against 5.5 for the tiled kernel (six launches a pass of a GPU-wide grid).
"""

import warp as wp

from physhand_mj.contact.broadphase import triangle_bound, world_geoms
from physhand_mj.contact.query import (MULTIRES, decide_triangle, geom_data, keep_three_lowest, only_geom, phi_at,
                                       project)
from physhand_mj.contact.sdf import FAR, MESH
from physhand_mj.contact.sdf_mesh import mesh_near_dist, mesh_near_faces, mesh_near_first, mesh_near_ids, sdf_mesh_near

wp.set_module_options({"enable_backward": False})


def lattice_lanes(samples: int) -> tuple[int, int]:
    """(order, lanes) of Algorithm 2's round of ``samples`` queries: the lattice of query.lattice_order
    and its (order + 1)(order + 2) / 2 points, plus the centroid when that leaves a query over."""
    order = 1
    while (order + 2) * (order + 3) // 2 <= samples:
        order += 1
    n = (order + 1) * (order + 2) // 2
    return order, n + (1 if n < samples else 0)


@wp.func
def lattice_point(ta: wp.vec3, tb: wp.vec3, tc: wp.vec3, s: int, order: int, inv: float):
    """Sample ``s`` of a round over (ta, tb, tc) in query.decide_triangle's order (i outer, j inner;
    past the lattice: the centroid), by the same operations."""
    rest = s
    for i in range(order + 1):
        row = order + 1 - i
        if rest < row:
            u = float(i) * inv
            v = float(rest) * inv
            return ta * (1.0 - u - v) + tb * u + tc * v
        rest -= row
    return (ta + tb + tc) * (1.0 / 3.0)


@wp.kernel
def lanes_begin(
    faces: wp.array2d(dtype=int), gtype: wp.array(dtype=int), size: wp.array(dtype=wp.vec3),
    inv_pose: wp.array(dtype=wp.transform), mesh: wp.array(dtype=wp.vec2ul), geom_count: wp.array(dtype=int),
    tris_per_world: int, geoms_per_world: int, active: wp.array(dtype=int), active_mask: wp.array(dtype=int),
    active_count: wp.array(dtype=int), cap: int, stride: int, x: wp.array(dtype=wp.vec3),
    # out
    bound_mask: wp.array(dtype=int), eval_x: wp.array2d(dtype=wp.vec3), tri: wp.array2d(dtype=wp.vec3),
    best: wp.array(dtype=wp.vec4), certified: wp.array(dtype=float), going: wp.array(dtype=int),
    near_ids: wp.array(dtype=mesh_near_ids), near_d: wp.array(dtype=mesh_near_dist), near_n: wp.array(dtype=int),
    near_m: wp.array(dtype=wp.vec3),
):
    """Entries k < min(count, cap): query.decide_triangle's set-up of triangle active[k] (its
    vertices into eval_x, its mask into bound_mask) and its mesh's near faces (n = -1: none; each
    sample then asks phi_at), the first round's triangle and the running lowest sample (FAR)."""
    k = wp.tid()
    n = wp.min(active_count[0], cap)
    while k < n:
        t = active[k]
        near = active_mask[k]
        a = x[faces[t, 0]]
        b = x[faces[t, 1]]
        c = x[faces[t, 2]]
        eval_x[t, 0] = a
        eval_x[t, 1] = b
        eval_x[t, 2] = c
        bound_mask[t] = near
        tri[k, 0] = a
        tri[k, 1] = b
        tri[k, 2] = c
        best[k] = wp.vec4(a[0], a[1], a[2], FAR)
        certified[k] = -FAR
        going[k] = 1
        base, end = world_geoms(t, tris_per_world, geoms_per_world, geom_count[0])
        single = only_geom(near, base, end - base)
        s_type, s_inv, s_size, s_mesh = geom_data(single, gtype, size, inv_pose, mesh)
        ids = mesh_near_ids()
        dist = mesh_near_dist()
        lm = wp.vec3(0.0)
        n_near = int(-1)
        if s_type == MESH and s_size[1] > 1.5 and s_mesh[1] == wp.uint64(0):  # as query.decide_triangle
            la = wp.transform_point(s_inv, a)
            lb = wp.transform_point(s_inv, b)
            lc = wp.transform_point(s_inv, c)
            m, lr = triangle_bound(la, lb, lc)
            lm = m
            ids, dist, n_near = mesh_near_faces(s_mesh[0], lm, lr, s_size[0])
        near_ids[k] = ids
        near_d[k] = dist
        near_n[k] = n_near
        near_m[k] = lm
        k += stride


@wp.kernel
def lanes_samples(
    gtype: wp.array(dtype=int), size: wp.array(dtype=wp.vec3), inv_pose: wp.array(dtype=wp.transform),
    radius: wp.array(dtype=float), mesh: wp.array(dtype=wp.vec2ul), geom_count: wp.array(dtype=int),
    tris_per_world: int, geoms_per_world: int, active: wp.array(dtype=int), active_mask: wp.array(dtype=int),
    active_count: wp.array(dtype=int), cap: int, stride: int, lanes: int, order: int, spread: int,
    tri: wp.array2d(dtype=wp.vec3), going: wp.array(dtype=int), near_ids: wp.array(dtype=mesh_near_ids),
    near_d: wp.array(dtype=mesh_near_dist), near_n: wp.array(dtype=int), near_m: wp.array(dtype=wp.vec3),
    # out
    sample_d: wp.array2d(dtype=float),
):
    """phi at each sample of the round's triangle of every entry still going: a thread per (entry,
    sample) (``spread`` 1) or per entry looping its samples (0)."""
    i = wp.tid()
    per = wp.where(spread != 0, lanes, 1)
    n = wp.min(active_count[0], cap) * per
    inv = 1.0 / float(order)
    while i < n:
        k = i // per
        s0 = i - k * per
        if going[k] != 0:
            t = active[k]
            near = active_mask[k]
            base, end = world_geoms(t, tris_per_world, geoms_per_world, geom_count[0])
            n_geoms = end - base
            single = only_geom(near, base, n_geoms)
            s_type, s_inv, s_size, s_mesh = geom_data(single, gtype, size, inv_pose, mesh)
            ta = tri[k, 0]
            tb = tri[k, 1]
            tc = tri[k, 2]
            n_near = near_n[k]
            first = int(0)
            if n_near > 1:
                first = mesh_near_first(near_d[k], n_near)
            s1 = wp.where(spread != 0, s0 + 1, lanes)
            for s in range(s0, s1):
                p = lattice_point(ta, tb, tc, s, order, inv)
                d = float(FAR)
                if n_near >= 0:
                    d = sdf_mesh_near(wp.transform_point(s_inv, p), s_size, s_mesh[0], near_ids[k], near_d[k], n_near,
                                      first, near_m[k])
                else:
                    d = phi_at(p, single, s_type, s_inv, s_size, s_mesh, gtype, size, inv_pose, radius, mesh, base,
                               n_geoms, near)
                sample_d[k, s] = d
        i += stride


@wp.kernel
def lanes_reduce(
    faces: wp.array2d(dtype=int), gtype: wp.array(dtype=int), size: wp.array(dtype=wp.vec3),
    inv_pose: wp.array(dtype=wp.transform), radius: wp.array(dtype=float), mesh: wp.array(dtype=wp.vec2ul),
    geom_count: wp.array(dtype=int), geom_obj: wp.array(dtype=int), tris_per_world: int, geoms_per_world: int,
    active: wp.array(dtype=int), active_mask: wp.array(dtype=int), active_count: wp.array(dtype=int), cap: int,
    stride: int, lanes: int, order: int, first: int, last: int, offset: float, side_aware: int,
    eval_x: wp.array2d(dtype=wp.vec3), sample_d: wp.array2d(dtype=float),
    # in and out
    tri: wp.array2d(dtype=wp.vec3), best: wp.array(dtype=wp.vec4), certified: wp.array(dtype=float),
    going: wp.array(dtype=int),
    # out (the last round)
    delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=float), decision: wp.array(dtype=wp.vec4),
    vertex_obj: wp.array(dtype=int), bound: wp.array(dtype=float), touched: wp.array(dtype=int),
    touched_count: wp.array(dtype=int),
):
    """A round's end for every entry still going (query.decide_triangle's: the three lowest samples
    in order, the lowest seen, after the ``first`` round the certification that leaves the triangle,
    else the next round's triangle); after the ``last`` round, every entry's decision point, bound
    and Eq. 9."""
    k = wp.tid()
    n = wp.min(active_count[0], cap)
    inv = 1.0 / float(order)
    while k < n:
        t = active[k]
        a = eval_x[t, 0]
        b = eval_x[t, 1]
        c = eval_x[t, 2]
        if going[k] != 0:
            ta = tri[k, 0]
            tb = tri[k, 1]
            tc = tri[k, 2]
            d0 = float(FAR)
            d1 = float(FAR)
            d2 = float(FAR)
            p0 = ta
            p1 = tb
            p2 = tc
            for s in range(lanes):
                p = lattice_point(ta, tb, tc, s, order, inv)
                d0, p0, d1, p1, d2, p2 = keep_three_lowest(sample_d[k, s], p, d0, p0, d1, p1, d2, p2)
            lo = best[k]
            if d0 < lo[3]:
                best[k] = wp.vec4(p0[0], p0[1], p0[2], d0)
            stop = int(0)
            if first != 0:
                longest = wp.max(wp.length(b - a), wp.max(wp.length(c - b), wp.length(a - c)))
                h = longest * inv * 0.5773503  # every point is within longest / (L sqrt 3) of a sample
                if d0 > h:
                    certified[k] = d0 - h
                    stop = 1
            if stop != 0:
                going[k] = 0
            else:
                tri[k, 0] = p0
                tri[k, 1] = p1
                tri[k, 2] = p2
        if last != 0:
            lo = best[k]
            best_p = wp.vec3(lo[0], lo[1], lo[2])
            decision[t] = lo
            bound[t] = lo[3]
            if certified[k] > -FAR:
                bound[t] = certified[k]
            if lo[3] < 0.5 * offset:
                near = active_mask[k]
                base, end = world_geoms(t, tris_per_world, geoms_per_world, geom_count[0])
                nt = wp.normalize(wp.cross(b - a, c - a))
                project(best_p, offset, faces[t, 0], faces[t, 1], faces[t, 2], nt, side_aware, near, base, end - base,
                        gtype, size, inv_pose, radius, mesh, geom_obj, delta, hits, touched, touched_count,
                        vertex_obj)
        k += stride


@wp.kernel
def lanes_overflow(
    faces: wp.array2d(dtype=int), gtype: wp.array(dtype=int), size: wp.array(dtype=wp.vec3),
    inv_pose: wp.array(dtype=wp.transform), radius: wp.array(dtype=float), mesh: wp.array(dtype=wp.vec2ul),
    geom_count: wp.array(dtype=int), geom_obj: wp.array(dtype=int), tris_per_world: int, geoms_per_world: int,
    active: wp.array(dtype=int), active_mask: wp.array(dtype=int), active_count: wp.array(dtype=int), cap: int,
    stride: int, samples: int, rounds: int, offset: float, side_aware: int, x: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=float), decision: wp.array(dtype=wp.vec4),
    vertex_obj: wp.array(dtype=int), bound: wp.array(dtype=float), bound_mask: wp.array(dtype=int),
    eval_x: wp.array2d(dtype=wp.vec3), touched: wp.array(dtype=int), touched_count: wp.array(dtype=int),
):
    """Entries k >= cap (past the scratch): the per-thread multires decide, whole."""
    k = wp.tid() + cap
    while k < active_count[0]:
        decide_triangle(active[k], active_mask[k], faces, gtype, size, inv_pose, radius, mesh, geom_count, geom_obj,
                        tris_per_world, geoms_per_world, MULTIRES, samples, rounds, 0, offset, side_aware, x, delta,
                        hits, decision, vertex_obj, bound, bound_mask, eval_x, touched, touched_count)
        k += stride


LANES_SHARE = 0.25  # the scratch holds this share of the skin triangles of every world (entries past it: lanes_overflow)
LANES_MIN_CAP = 65536  # ... or this many entries, or every triangle where fewer


class SampleLanes:
    """Scratch and recording of one contact pass's decision points with a lane per sample (the
    module docstring). ``cap`` entries of scratch (~290 bytes each at 21 samples: a quarter of the
    skin triangles of every world, at least LANES_MIN_CAP)."""

    def __init__(self, n_tris: int, samples: int, rounds: int, device):
        d = wp.get_device(device)
        self.device, self.cuda = d, d.is_cuda
        self.samples, self.rounds = int(samples), int(rounds)
        self.order, self.lanes = lattice_lanes(samples)
        self.cap = cap = max(1, min(n_tris, max(LANES_MIN_CAP, int(n_tris * LANES_SHARE))))
        # CUDA: a fixed grid of as many threads as the GPU holds, striding over the list; the CPU: a
        # thread per entry (the recorded launch is sized by the list's length when it runs)
        self.stride = d.sm_count * 2048 if self.cuda else 1 << 30
        self.tri = wp.zeros((cap, 3), dtype=wp.vec3, device=d)
        self.best = wp.zeros(cap, dtype=wp.vec4, device=d)
        self.certified = wp.zeros(cap, dtype=float, device=d)
        self.going = wp.zeros(cap, dtype=int, device=d)
        self.near_ids = wp.zeros(cap, dtype=mesh_near_ids, device=d)
        self.near_d = wp.zeros(cap, dtype=mesh_near_dist, device=d)
        self.near_n = wp.zeros(cap, dtype=int, device=d)
        self.near_m = wp.zeros(cap, dtype=wp.vec3, device=d)
        self.sample_d = wp.zeros((cap, self.lanes), dtype=float, device=d)

    def record(self, launch, faces, objects, tris_per_world: int, geoms_per_world: int, lst, offset: float,
               side_aware: int, x, outs: list) -> None:
        """The pass's launches (``launch`` as Contact records them) for list ``lst`` = (active, mask,
        count); ``outs`` = query.decide_and_project's outputs (delta, hits, decision, vertex_obj, bound,
        bound_mask, eval_x, touched, touched_count)."""
        o = objects
        delta, hits, decision, vertex_obj, bound, bound_mask, eval_x, touched, touched_count = outs
        count = lst[2]
        cap, stride = self.cap, self.stride
        per_entry = dict(count=None) if self.cuda else dict(count=count)
        dim = stride if self.cuda else cap
        geoms = [o.gtype, o.size, o.inv_pose]
        launch(lanes_begin, dim, [faces, *geoms, o.mesh_exact, o.count, tris_per_world, geoms_per_world, *lst, cap,
                                  stride, x],
               [bound_mask, eval_x, self.tri, self.best, self.certified, self.going, self.near_ids, self.near_d,
                self.near_n, self.near_m], **per_entry)
        for r in range(self.rounds):
            launch(lanes_samples, dim, [*geoms, o.radius, o.mesh_exact, o.count, tris_per_world, geoms_per_world, *lst,
                                        cap, stride, self.lanes, self.order, int(self.cuda), self.tri, self.going,
                                        self.near_ids, self.near_d, self.near_n, self.near_m],
                   [self.sample_d], **per_entry)
            launch(lanes_reduce, dim, [faces, *geoms, o.radius, o.mesh_exact, o.count, o.obj, tris_per_world,
                                       geoms_per_world, *lst, cap, stride, self.lanes, self.order, int(r == 0),
                                       int(r + 1 == self.rounds), offset, side_aware, eval_x, self.sample_d],
                   [self.tri, self.best, self.certified, self.going, delta, hits, decision, vertex_obj, bound, touched,
                    touched_count], **per_entry)
        # entries past the scratch last, so that Eq. 9's sums run in the list's order as the per-thread kernel's do
        launch(lanes_overflow, dim, [faces, *geoms, o.radius, o.mesh_exact, o.count, o.obj, tris_per_world,
                                     geoms_per_world, *lst, cap, stride, self.samples, self.rounds, offset, side_aware, x],
               [delta, hits, decision, vertex_obj, bound, bound_mask, eval_x, touched, touched_count], **per_entry)
