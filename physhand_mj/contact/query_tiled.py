"""The CUDA multires kernel: a block per active skin triangle, a lane per lattice sample.

:func:`decide_and_project_tiled` is query.decide_and_project's MULTIRES for CUDA (Config.execution.tiled_contact):
each of the block's TILE_LANES lanes queries one sample of Algorithm 2's lattice, block reductions
pick the three lowest, lane 0 projects (Eq. 9, query.project). The serial chain per triangle shrinks
from samples x rounds queries to rounds x (1 query + 3 reductions); the samples, rounds, early-out,
bound and projection are the per-thread kernel's.
"""

import functools

import warp as wp

from physhand_mj.contact.broadphase import world_geoms
from physhand_mj.contact.query import geom_data, lattice_order, only_geom, phi_funcs
from physhand_mj.contact.sdf import FAR

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

TILE_LANES = 32  # lanes per triangle in the CUDA multires kernel (>= the lattice's sample count)


@wp.func
def lattice_uv(idx: int, order: int):
    """Barycentric (u, v) of sample ``idx`` of the order-``order`` lattice, in the order of the
    per-thread loops (i over u, then j over v)."""
    rem = int(idx)
    i = int(0)
    while rem >= order + 1 - i:
        rem -= order + 1 - i
        i += 1
    inv = 1.0 / float(order)
    return float(i) * inv, float(rem) * inv


@functools.cache  # (one kernel a flag: a second one in the same module would change its hash)
def tiled_kernel(with_mesh: bool):
    """:func:`decide_and_project_tiled` over the geom SDFs with the MESH branch (``with_mesh``) or
    without it (:func:`tiled_kernel_for`)."""
    _, _, phi_at, project = phi_funcs(with_mesh)

    def decide_and_project_tiled(
        # Model:
        faces: wp.array2d(dtype=int),
        # Objects:
        gtype: wp.array(dtype=int),
        size: wp.array(dtype=wp.vec3),
        inv_pose: wp.array(dtype=wp.transform),
        radius: wp.array(dtype=float),
        mesh: wp.array(dtype=wp.vec2ul),
        geom_count: wp.array(dtype=int),
        geom_obj: wp.array(dtype=int),
        tris_per_world: int,
        geoms_per_world: int,
        # Contact in:
        active: wp.array(dtype=int),
        active_mask: wp.array(dtype=int),
        active_count: wp.array(dtype=int),
        stride: int,
        samples: int,
        rounds: int,
        offset: float,
        side_aware: int,
        # State in:
        x: wp.array(dtype=wp.vec3),
        # Contact out:
        delta: wp.array(dtype=wp.vec3),
        hits: wp.array(dtype=float),
        decision: wp.array(dtype=wp.vec4),
        vertex_obj: wp.array(dtype=int),
        bound: wp.array(dtype=float),
        bound_mask: wp.array(dtype=int),
        eval_x: wp.array2d(dtype=wp.vec3),
        touched: wp.array(dtype=int),
        touched_count: wp.array(dtype=int),
    ):
        """:func:`decide_and_project` for MULTIRES on CUDA with a block of TILE_LANES threads per active
        triangle: each lane queries one lattice sample, block reductions pick the three lowest, lane 0
        projects. Same samples, rounds, early-out, bound and Eq. 9 as the per-thread kernel; the serial
        chain per triangle shrinks from samples x rounds queries to rounds x (1 query + 3 reductions).
        Launched with ``stride`` blocks (launch.tiled_blocks): block b takes entries b, b + stride, ...
        of the list and a block past its end reads the count and leaves (Warp's own grid-stride loop
        over every slot cost the held grasp's launch ~9 idle rounds a block, docs/activity.md)."""
        blk, lane = wp.tid()
        k = blk
        n = active_count[0]
        while k < n:  # (uniform over the block: k is the block's triangle; every lane reaches the block reductions)
            t = active[k]
            near = active_mask[k]
            i0 = faces[t, 0]
            i1 = faces[t, 1]
            i2 = faces[t, 2]
            a = x[i0]
            b = x[i1]
            c = x[i2]
            base, end = world_geoms(t, tris_per_world, geoms_per_world, geom_count[0])  # the triangle's world's geoms
            n_geoms = end - base
            single = only_geom(near, base, n_geoms)
            s_type, s_inv, s_size, s_mesh = geom_data(single, gtype, size, inv_pose, mesh)
            order = lattice_order(samples)
            n_lat = (order + 1) * (order + 2) / 2
            best = float(FAR)
            best_p = a
            certified = float(-FAR)
            ta = a
            tb = b
            tc = c
            for r in range(rounds):
                d = float(FAR)
                if lane < n_lat:
                    u, v = lattice_uv(lane, order)
                    d = phi_at(ta * (1.0 - u - v) + tb * u + tc * v, single, s_type, s_inv, s_size, s_mesh,
                                 gtype, size, inv_pose, radius, mesh, base, n_geoms, near)
                elif lane == n_lat and n_lat < samples:  # a leftover query on the centroid
                    d = phi_at((ta + tb + tc) * (1.0 / 3.0), single, s_type, s_inv, s_size, s_mesh,
                                 gtype, size, inv_pose, radius, mesh, base, n_geoms, near)
                # the three lowest samples (indices j0, j1, j2), ascending
                j0 = wp.tile_argmin(wp.tile(d))[0]
                d0 = wp.tile_min(wp.tile(d))[0]
                e = d
                if lane == j0:
                    e = float(FAR)
                j1 = wp.tile_argmin(wp.tile(e))[0]
                if lane == j1:
                    e = float(FAR)
                j2 = wp.tile_argmin(wp.tile(e))[0]
                q0 = (ta + tb + tc) * (1.0 / 3.0)
                q1 = q0
                q2 = q0
                if j0 < n_lat:
                    u, v = lattice_uv(j0, order)
                    q0 = ta * (1.0 - u - v) + tb * u + tc * v
                if j1 < n_lat:
                    u, v = lattice_uv(j1, order)
                    q1 = ta * (1.0 - u - v) + tb * u + tc * v
                if j2 < n_lat:
                    u, v = lattice_uv(j2, order)
                    q2 = ta * (1.0 - u - v) + tb * u + tc * v
                if d0 < best:
                    best = d0
                    best_p = q0
                if r == 0:
                    longest = wp.max(wp.length(b - a), wp.max(wp.length(c - b), wp.length(a - c)))
                    h = longest / float(order) * 0.5773503  # every point is within longest / (L sqrt 3) of a sample
                    if d0 > h:
                        certified = d0 - h
                        break
                ta = q0
                tb = q1
                tc = q2
            if lane == 0:
                eval_x[t, 0] = a
                eval_x[t, 1] = b
                eval_x[t, 2] = c
                bound_mask[t] = near
                decision[t] = wp.vec4(best_p[0], best_p[1], best_p[2], best)
                bound[t] = best
                if certified > -FAR:
                    bound[t] = certified
                if best < 0.5 * offset:
                    nt = wp.normalize(wp.cross(b - a, c - a))
                    project(best_p, offset, i0, i1, i2, nt, side_aware, near, base, n_geoms, gtype, size, inv_pose, radius, mesh, geom_obj, delta, hits,
                            touched, touched_count, vertex_obj)
            k += stride

    # the kernels' own names (Nsight Compute, cpu_op_split.py), not the factory's
    decide_and_project_tiled.__qualname__ = "decide_and_project_tiled" + ("" if with_mesh else "_analytic")
    if with_mesh:
        return wp.kernel(decide_and_project_tiled)
    k = wp.kernel(decide_and_project_tiled, module=f"{__name__}_analytic", enable_backward=False)
    k.module.options["block_dim"] = TILE_LANES
    return k


decide_and_project_tiled = tiled_kernel(True)
decide_and_project_tiled_analytic = tiled_kernel(False)  # (its own module: compiled only where a scene uses it)


def tiled_kernel_for(has_mesh: bool):
    """The CUDA multires kernel for a scene with a mesh geom or without: without, the kernel
    compiled without the MESH branch (sdf.geom_sdf_funcs), 114 registers a thread and no spills on
    sm_90 against 255 and a 640 B spill frame (`python benchmarks/aot_cache.py --resources decide`).
    The same answers for every analytic geom; a mesh geom would read FAR in it, so the solver records
    its frames again when a geom is added after they were recorded (Solver._recorded_geoms)."""
    return decide_and_project_tiled if has_mesh else decide_and_project_tiled_analytic
