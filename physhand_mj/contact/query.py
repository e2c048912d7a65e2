"""Decision points per skin triangle and the Eq. 9 projection (paper section 3.3, Algorithm 2).

For every *active* skin triangle (broadphase.py) the kernel finds the decision point x*, the point
of the triangle with the lowest signed distance to the objects, by one of three strategies, and if
phi(x*) < 0 moves the triangle's three vertices by Eq. 9:

    x_i <- x_i - grad phi(x*) / |grad phi(x*)| phi(x*)

Triangles share vertices, so the corrections of a vertex are averaged over the penetrating
triangles that touch it, weighted by their depth -phi(x*) (``apply_contact``: the deepest triangle
dominates, where a plain average would halve a lone deep correction every pass);
``Config.contact_passes`` repeats query + projection to remove what averaging leaves.

Batched worlds (physhand_mj/batch.py): a triangle's queries loop over its own world's k geoms only
(:func:`world_phi` from base w k, the broadphase mask's bits relative to it), so a world's query
cost does not grow with the number of worlds W.

Triangles that cannot penetrate are left early, exactly (SDFs are 1-Lipschitz): for vertex and opt,
when phi(centroid) exceeds the circumradius; for multires, when after the first round (a lattice
of order L over the whole triangle, every point within longest edge / (L sqrt 3) of a sample) the
lowest sample exceeds that distance.

Strategies (``Strategy``):
- VERTEX: min over the 3 vertices and 3 edge midpoints (Fuhrmann et al. 2003): 6 queries.
- OPT: Frank-Wolfe on the barycentric simplex from the centroid (Macklin et al. 2020 solve the same
  local problem); step 2 / (k + 2), ``opt_queries`` gradient queries, best iterate kept.
- MULTIRES: Algorithm 2: sample the triangle on a barycentric lattice (vertices, edges, interior;
  ``multires_samples`` points per round), keep the 3 lowest as the next triangle, repeat
  ``multires_rounds`` times; the lowest sample seen is x*.
"""

import functools

import warp as wp

from physhand_mj.contact.bones import BoneHold, held_move
from physhand_mj.contact.exchange import Exchange, record, touch_load
from physhand_mj.contact.broadphase import TriList, triangle_bound, world_geoms
from physhand_mj.contact.sdf import (BOX, CAPSULE, CYLINDER, ELLIPSOID, FAR, MESH, SPHERE, GeomSet, geom_sdf,
                                     geom_sdf_analytic, geom_sdf_grad, geom_sdf_grad_analytic)
from physhand_mj.contact.sdf_mesh import mesh_near_dist, mesh_near_faces, mesh_near_first, mesh_near_ids, sdf_mesh_near
from physhand_mj.types import Strategy

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

VERTEX = wp.constant(int(Strategy.VERTEX))
OPT = wp.constant(int(Strategy.OPT))
MULTIRES = wp.constant(int(Strategy.MULTIRES))


@wp.func
def lattice_order(samples: int):
    """Largest order L with (L + 1)(L + 2) / 2 <= samples (at least 1)."""
    order = int(1)
    while (order + 2) * (order + 3) / 2 <= samples:
        order += 1
    return order


@wp.func
def keep_three_lowest(d: float, p: wp.vec3, d0: float, p0: wp.vec3, d1: float, p1: wp.vec3, d2: float, p2: wp.vec3):
    """Insert sample (d, p) into the ascending three lowest (d0 <= d1 <= d2) of Algorithm 2."""
    if d < d0:
        return d, p, d0, p0, d1, p1
    if d < d1:
        return d0, p0, d, p, d1, p1
    if d < d2:
        return d0, p0, d1, p1, d, p
    return d0, p0, d1, p1, d2, p2


@wp.func
def depth_weight(depth: float):
    """Weight of a triangle's correction in its vertices' mean: (depth / 0.1 mm)^4, at least 1e-30
    (the deepest triangle of a vertex dominates; the floor keeps the weight positive in float32)."""
    s = depth * 1.0e4
    return wp.max(s * s * s * s, 1.0e-30)


@wp.struct
class PushSums:
    """A push's per-vertex accumulators as one kernel argument (data.PassBuffers' ``delta``, ``hits``,
    ``touched`` and ``vertex_obj``, its ``sums``: made once with them; a launch captures the arrays
    it holds, so a CUDA graph stays valid). The touched list's length is a counter slot per push,
    passed beside it (the struct is not rebuilt per launch).

    delta (V,) vec3 (m: summed weighted corrections), hits (V,) float (their weights summed),
    touched (V,) int (the vertices the push corrects, a list), vertex_obj (V,) int (the object that
    last pushed the vertex, -1: none)."""

    delta: wp.array(dtype=wp.vec3)
    hits: wp.array(dtype=float)
    touched: wp.array(dtype=int)
    vertex_obj: wp.array(dtype=int)


def push_sums(delta, hits, touched, vertex_obj) -> PushSums:
    """A :class:`PushSums` of the given arrays (held, not copied)."""
    s = PushSums()
    s.delta, s.hits, s.touched, s.vertex_obj = delta, hits, touched, vertex_obj
    return s


@wp.func
def touch(sums: PushSums, i: int, w: float, touched_count: wp.array(dtype=int)):
    """hits[i] += w (> 0); the first hit of vertex i in a pass appends i to ``touched``."""
    if wp.atomic_add(sums.hits, i, w) == 0.0:
        sums.touched[wp.atomic_add(touched_count, 0, 1)] = i


@wp.func
def accumulate(i0: int, i1: int, i2: int, c0: wp.vec3, c1: wp.vec3, c2: wp.vec3, w0: float, w1: float, w2: float,
               obj: int, sums: PushSums, touched_count: wp.array(dtype=int)):
    """Add a triangle's vertex corrections c_j with weights w_j (> 0) into the pass's weighted
    means (``apply_contact`` divides by the summed weights) and record the touched object."""
    wp.atomic_add(sums.delta, i0, c0 * w0)
    wp.atomic_add(sums.delta, i1, c1 * w1)
    wp.atomic_add(sums.delta, i2, c2 * w2)
    touch(sums, i0, w0, touched_count)
    touch(sums, i1, w1, touched_count)
    touch(sums, i2, w2, touched_count)
    sums.vertex_obj[i0] = obj
    sums.vertex_obj[i1] = obj
    sums.vertex_obj[i2] = obj


@wp.func
def only_geom(near: int, base: int, n_geoms: int):
    """The (global) index of the one geom near a triangle (its world-relative broadphase mask has a
    single bit; geoms [base, base + n_geoms) are its world's), else -1; that geom's data is then
    kept in registers and queried without the geom loop (Warp's CPU code copies array arguments on
    every call of world_phi)."""
    single = int(-1)
    if near > 0 and (near & (near - 1)) == 0 and (near != (1 << 30) or n_geoms <= 31):
        for bit in range(31):
            if near == (1 << bit):
                single = base + bit
    return single


@wp.func
def geom_data(g: int, geoms: GeomSet):
    """(type, inverse pose, size, mesh id) of geom ``g``; a NONE geom (phi = FAR) for g < 0."""
    if g < 0:
        return int(0), wp.transform_identity(), wp.vec3(0.0), wp.vec2ul(wp.uint64(0), wp.uint64(0))
    return geoms.gtype[g], geoms.inv_pose[g], geoms.size[g], geoms.mesh[g]


SIDE_COS = wp.constant(0.6)  # cos of the angle beyond which Eq. 9 would push the skin out through the object
SIDE_DEPTH = wp.constant(5.0e-4)  # m: shallower decision points take Eq. 9 (a box's edges tilt the gradient)
SIDE_FRAC = wp.constant(0.1)  # ... or shallower than this fraction of a thinner geom's half-thickness (side_floor)
MARCH_STEPS = wp.constant(32)  # sphere-tracing steps of the side-aware exit (each >= MARCH_MIN)
MARCH_MIN = wp.constant(2.0e-5)  # m


@wp.func
def side_floor(gtype: int, size: wp.vec3):
    """Depth (m) past which a decision point in geom ``gtype`` of ``size`` may take the side-aware
    exit: SIDE_DEPTH, or SIDE_FRAC of the geom's half-thickness where that is less (box: least half
    extent; sphere, capsule: radius; cylinder: radius or half height; ellipsoid: least radius; mesh:
    the half-thickness of its thin parts, ``size[2]``, from objects.mesh_half_thickness; plane and
    cone: SIDE_DEPTH). No point of an object is deeper than its half-thickness, so with a
    fixed 0.5 mm floor a 1 mm wall never took the exit and Eq. 9 carried skin that had passed its
    mid-plane out through the far side (docs/contact.md). Boxes at least 10 mm thick keep 0.5 mm."""
    half = float(FAR)
    if gtype == BOX or gtype == ELLIPSOID:
        half = wp.min(size[0], wp.min(size[1], size[2]))
    elif gtype == SPHERE or gtype == CAPSULE:
        half = size[0]
    elif gtype == CYLINDER:
        half = wp.min(size[0], size[1])
    elif gtype == MESH and size[2] > 0.0:
        half = size[2]  # objects.mesh_half_thickness, measured when the mesh was added
    return wp.min(SIDE_DEPTH, SIDE_FRAC * half)


@functools.cache  # (the same funcs for every kernel of a flag)
def phi_funcs(with_mesh: bool):
    """(:func:`world_phi`, :func:`world_phi_grad`, :func:`phi_at`, :func:`project`) over the geom
    SDFs with the MESH branch (``with_mesh``) or without it (sdf.geom_sdf_funcs: for the kernels of
    scenes with analytic geoms only, query_tiled.py)."""
    sdf, sdf_grad = (geom_sdf, geom_sdf_grad) if with_mesh else (geom_sdf_analytic, geom_sdf_grad_analytic)

    @wp.func
    def world_phi(p: wp.vec3, geoms: GeomSet, base: int, count: int, mask: int):
        """min over the geoms [base, base + count) (one world's: batched worlds) of phi at world point
        p (m). Only geoms whose bit is set in ``mask`` count: bit j is geom base + j (the broadphase's
        world-relative list for this triangle; -1 = all); geoms base + 31 on share bit 30 and are always
        tried. Geoms whose bounding sphere is farther than the best value so far are skipped
        (phi >= |q| - R for p at q in the geom frame)."""
        best = float(FAR)
        for j in range(count):
            if (j < 31 and ((mask >> j) & 1) == 0):
                continue
            g = base + j
            q = wp.transform_point(geoms.inv_pose[g], p)
            if wp.length(q) - geoms.radius[g] < best:
                best = wp.min(best, sdf(geoms.gtype[g], q, geoms.size[g], geoms.mesh[g]))
        return best

    @wp.func
    def world_phi_grad(p: wp.vec3, geoms: GeomSet, base: int, count: int, mask: int):
        """(phi, unit world gradient, geom index) of the closest geom of [base, base + count) at world
        point p (``mask`` as in :func:`world_phi`; the index is global)."""
        best = float(FAR)
        grad = wp.vec3(0.0, 0.0, 1.0)
        arg = int(base)
        for j in range(count):
            if (j < 31 and ((mask >> j) & 1) == 0):
                continue
            g = base + j
            ti = geoms.inv_pose[g]
            q = wp.transform_point(ti, p)
            if wp.length(q) - geoms.radius[g] < best:
                d, n = sdf_grad(geoms.gtype[g], q, geoms.size[g], geoms.mesh[g])
                if d < best:
                    best = d
                    grad = wp.quat_rotate_inv(wp.transform_get_rotation(ti), n)
                    arg = g
        return best, grad, arg

    @wp.func
    def phi_at(p: wp.vec3, single: int, s_type: int, s_inv: wp.transform, s_size: wp.vec3, s_mesh: wp.vec2ul,
               geoms: GeomSet, base: int, n_geoms: int, near: int):
        """phi (m) at world point p: the one geom near the triangle (``single``, its data from
        :func:`geom_data`) or, with ``single`` < 0, the lowest over its world's geoms in ``near``."""
        if single < 0:
            return world_phi(p, geoms, base, n_geoms, near)
        return sdf(s_type, wp.transform_point(s_inv, p), s_size, s_mesh)

    @wp.func
    def project(best_p: wp.vec3, offset: float, i0: int, i1: int, i2: int, nt: wp.vec3, side_aware: int,
                near: int, base: int, n_geoms: int, geoms: GeomSet, sums: PushSums,
                touched_count: wp.array(dtype=int)):
        """Eq. 9 for a triangle (vertices i0, i1, i2, outward unit normal nt) whose decision point is
        best_p: the correction that puts x* ``offset`` outside the surface along the gradient there,
        added to its vertices' accumulators with the depth weight; the touched object recorded per vertex.

        Side-aware: where the gradient points out of the hand (dot(grad, nt) > SIDE_COS) at a decision
        point deeper than :func:`side_floor` (0.5 mm, less in thin geoms: shallow contact at a box's edge
        tilts the gradient) the object's nearest surface lies beyond the skin, on the far side of an
        object the skin has passed more than half way into (a thin wall, a capsule past its axis, a deep
        start); Eq. 9 would put the skin on the object's far side and the object inside the hand. The
        triangle then leaves the object the way it came, into the hand along -nt (``side_aware``: the
        skin is closed, so it has an inside): by sphere tracing from x* (inside an SDF a step of |phi|
        never passes the surface), at most MARCH_STEPS steps; no exit found, no correction."""
        d, g, arg = world_phi_grad(best_p, geoms, base, n_geoms, near)
        corr = g * (offset - d)
        if side_aware != 0 and wp.dot(g, nt) > SIDE_COS and -d > side_floor(geoms.gtype[arg], geoms.size[arg]):
            t = float(0.0)
            exited = int(0)
            for k in range(MARCH_STEPS):
                dd = world_phi(best_p - nt * t, geoms, base, n_geoms, near)
                if dd >= offset:
                    exited = 1
                    break
                t += wp.max(offset - dd, MARCH_MIN)
                if t > 2.0 * (offset - d) + 5.0e-4:
                    break
            if exited == 0:
                return
            corr = -nt * t
        w = depth_weight(-d)
        accumulate(i0, i1, i2, corr, corr, corr, w, w, w, geoms.obj[arg], sums, touched_count)

    return world_phi, world_phi_grad, phi_at, project


world_phi, world_phi_grad, phi_at, project = phi_funcs(True)


@wp.func
def scene_phi(p: wp.vec3, geoms: GeomSet, count: int, mask: int):
    """:func:`world_phi` over geoms [0, count) (one world)."""
    return world_phi(p, geoms, 0, count, mask)


@wp.func
def scene_phi_grad(p: wp.vec3, geoms: GeomSet, count: int, mask: int):
    """:func:`world_phi_grad` over geoms [0, count)."""
    return world_phi_grad(p, geoms, 0, count, mask)


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


def decide_source(tiled: bool, multires: bool, with_mesh: bool = True):
    """The Python function of the decision-point kernel, for ``wp.kernel`` (its callers give each
    variant its module and options): :func:`decide_and_project` (``tiled`` False, ``multires``
    False), :func:`multires_kernel`'s copy (the strategy a constant MULTIRES: the other strategies'
    inlined queries and their local arrays drop out) and query_tiled's CUDA kernel (``tiled``: a
    block of query_tiled.TILE_LANES lanes per triangle, a lane per lattice sample, block reductions
    pick the three lowest, lane 0 projects; MULTIRES only, without Algorithm 2's one-mesh shortcut).
    ``with_mesh``: the geom SDFs with the MESH branch (:func:`phi_funcs`). Every variant takes the
    same arguments: ``stride`` is read by the tiled one only, ``strategy`` and ``opt_queries`` by
    the per-thread generic one."""
    _, grad_fn, phi_fn, project_fn = phi_funcs(with_mesh)
    TILED = bool(tiled)
    ANY = not tiled and not multires  # the strategy an argument

    def decide_and_project(
        # Model:
        faces: wp.array2d(dtype=int),
        # Objects:
        geoms: GeomSet,
        tris_per_world: int,
        geoms_per_world: int,
        # Contact in:
        active: TriList,
        active_count: wp.array(dtype=int),
        stride: int,
        strategy: int,
        samples: int,
        rounds: int,
        opt_queries: int,
        offset: float,
        side_aware: int,
        # State in:
        x: wp.array(dtype=wp.vec3),
        # Contact out:
        decision: wp.array(dtype=wp.vec4),
        bound: wp.array(dtype=float),
        bound_mask: wp.array(dtype=int),
        eval_x: wp.array2d(dtype=wp.vec3),
        sums: PushSums,
        touched_count: wp.array(dtype=int),
    ):
        if wp.static(TILED):
            blk, lane = wp.tid()
            k = blk
            n = active_count[0]
            step = stride
        else:  # (a thread per entry: Warp's grid-stride loop walks the list)
            k = wp.tid()
            lane = int(0)
            n = wp.min(k + 1, active_count[0])
            step = int(1)
        while k < n:  # (tiled: uniform over the block, k is the block's triangle; every lane reaches the block reductions)
            t = active.tri[k]
            near = active.mask[k]
            i0 = faces[t, 0]
            i1 = faces[t, 1]
            i2 = faces[t, 2]
            a = x[i0]
            b = x[i1]
            c = x[i2]
            if lane == 0:
                eval_x[t, 0] = a
                eval_x[t, 1] = b
                eval_x[t, 2] = c
                bound_mask[t] = near
            base, end = world_geoms(t, tris_per_world, geoms_per_world, geoms.count[0])  # the triangle's world's geoms
            n_geoms = end - base
            single = only_geom(near, base, n_geoms)  # one geom near this triangle (the common case)
            s_type, s_inv, s_size, s_mesh = geom_data(single, geoms)
            best = float(FAR)
            best_p = a
            certified = float(-FAR)
            multires_now = True
            if wp.static(ANY):
                multires_now = strategy == MULTIRES
                if strategy != MULTIRES:
                    mc, rc = triangle_bound(a, b, c)
                    dc = phi_fn(mc, single, s_type, s_inv, s_size, s_mesh, geoms, base, n_geoms, near)
                    if dc > rc:  # no point of the triangle is inside an object
                        decision[t] = wp.vec4(mc[0], mc[1], mc[2], dc)
                        bound[t] = dc - rc
                        return
                if strategy == VERTEX:
                    for q in range(6):
                        p = a
                        if q == 1:
                            p = b
                        elif q == 2:
                            p = c
                        elif q == 3:
                            p = (a + b) * 0.5
                        elif q == 4:
                            p = (b + c) * 0.5
                        elif q == 5:
                            p = (c + a) * 0.5
                        d = phi_fn(p, single, s_type, s_inv, s_size, s_mesh, geoms, base, n_geoms, near)
                        if d < best:
                            best = d
                            best_p = p
                elif strategy == OPT:
                    w0 = float(1.0 / 3.0)
                    w1 = float(1.0 / 3.0)
                    w2 = float(1.0 / 3.0)
                    for q in range(opt_queries):
                        p = a * w0 + b * w1 + c * w2
                        d, g, arg = grad_fn(p, geoms, base, n_geoms, near)
                        if d < best:
                            best = d
                            best_p = p
                        # Frank-Wolfe: the simplex vertex minimising the linearised phi, step 2 / (q + 2)
                        ga = wp.dot(g, a)
                        gb = wp.dot(g, b)
                        gc = wp.dot(g, c)
                        gamma = 2.0 / (float(q) + 2.0)
                        w0 = w0 * (1.0 - gamma)
                        w1 = w1 * (1.0 - gamma)
                        w2 = w2 * (1.0 - gamma)
                        if ga <= gb and ga <= gc:
                            w0 += gamma
                        elif gb <= gc:
                            w1 += gamma
                        else:
                            w2 += gamma
            if wp.static(TILED):  # (MULTIRES only)
                order = lattice_order(samples)
                n_lat = (order + 1) * (order + 2) / 2
                ta = a
                tb = b
                tc = c
                for r in range(rounds):
                    d = float(FAR)
                    if lane < n_lat:
                        u, v = lattice_uv(lane, order)
                        d = phi_fn(ta * (1.0 - u - v) + tb * u + tc * v, single, s_type, s_inv, s_size, s_mesh,
                                   geoms, base, n_geoms, near)
                    elif lane == n_lat and n_lat < samples:  # a leftover query on the centroid
                        d = phi_fn((ta + tb + tc) * (1.0 / 3.0), single, s_type, s_inv, s_size, s_mesh,
                                   geoms, base, n_geoms, near)
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
            else:
                if multires_now:
                    order = lattice_order(samples)
                    inv = 1.0 / float(order)
                    ta = a
                    tb = b
                    tc = c
                    # one mesh near (pseudo-normal sign, few faces near a skin triangle: Objects.add marks it; exact
                    # ids): its faces near the triangle, found once, answer every sample of both rounds
                    # (sdf_mesh.mesh_near_faces; n_near = -1: the BVH per sample)
                    near_ids = mesh_near_ids()
                    near_d = mesh_near_dist()
                    lm = wp.vec3(0.0)
                    n_near = int(-1)
                    near_first = int(0)
                    if s_type == MESH and s_size[1] > 1.5 and s_mesh[1] == wp.uint64(0):  # sdf_mesh.MESH_SIGN_PSEUDO_NEAR
                        la = wp.transform_point(s_inv, a)
                        lb = wp.transform_point(s_inv, b)
                        lc = wp.transform_point(s_inv, c)
                        lm, lr = triangle_bound(la, lb, lc)
                        near_ids, near_d, n_near = mesh_near_faces(s_mesh[0], lm, lr, s_size[0])
                        near_first = mesh_near_first(near_d, n_near)
                    for r in range(rounds):
                        # the three lowest samples of this round, ascending
                        d0 = float(FAR)
                        d1 = float(FAR)
                        d2 = float(FAR)
                        p0 = ta
                        p1 = tb
                        p2 = tc
                        count = int(0)
                        for i in range(order + 1):
                            for j in range(order + 1 - i):
                                u = float(i) * inv
                                v = float(j) * inv
                                p = ta * (1.0 - u - v) + tb * u + tc * v
                                d = float(FAR)
                                if n_near >= 0:
                                    d = sdf_mesh_near(wp.transform_point(s_inv, p), s_size, s_mesh[0], near_ids, near_d,
                                                      n_near, near_first, lm)
                                else:
                                    d = phi_fn(p, single, s_type, s_inv, s_size, s_mesh, geoms, base, n_geoms, near)
                                count += 1
                                d0, p0, d1, p1, d2, p2 = keep_three_lowest(d, p, d0, p0, d1, p1, d2, p2)
                        if count < samples:  # spend a leftover query on the centroid
                            p = (ta + tb + tc) * (1.0 / 3.0)
                            d = float(FAR)
                            if n_near >= 0:
                                d = sdf_mesh_near(wp.transform_point(s_inv, p), s_size, s_mesh[0], near_ids, near_d,
                                                  n_near, near_first, lm)
                            else:
                                d = phi_fn(p, single, s_type, s_inv, s_size, s_mesh, geoms, base,
                                           n_geoms, near)
                            d0, p0, d1, p1, d2, p2 = keep_three_lowest(d, p, d0, p0, d1, p1, d2, p2)
                        if d0 < best:
                            best = d0
                            best_p = p0
                        if r == 0:
                            longest = wp.max(wp.length(b - a), wp.max(wp.length(c - b), wp.length(a - c)))
                            h = longest * inv * 0.5773503  # every point is within longest / (L sqrt 3) of a sample
                            if d0 > h:
                                certified = d0 - h
                                break
                        ta = p0
                        tb = p1
                        tc = p2
            if lane == 0:
                decision[t] = wp.vec4(best_p[0], best_p[1], best_p[2], best)
                bound[t] = best
                if certified > -FAR:  # (MULTIRES's certified bound of a triangle left early)
                    bound[t] = certified
                if best < 0.5 * offset:
                    nt = wp.normalize(wp.cross(b - a, c - a))
                    project_fn(best_p, offset, i0, i1, i2, nt, side_aware, near, base, n_geoms, geoms, sums,
                               touched_count)
            k += step

    decide_and_project.__qualname__ = "decide_and_project"  # (the kernel's key: profiles, tests)
    return decide_and_project


decide_and_project = wp.kernel(decide_source(False, False))
""" One active triangle per thread: decision point x* by ``strategy``; if phi(x*) < offset / 2
(Config.tuning.contact_offset: the skin rests that far outside objects), Eq. 9 onto phi = offset:
corrections into ``sums`` (:class:`PushSums`: ``delta`` and ``hits`` of its three vertices, summed
and weighted by the depth, the vertices' first hits of the pass appended to ``touched``, counted in
``touched_count``, and the object touched into ``vertex_obj``). decision[t] = (x*, phi(x*)) for
diagnostics (for triangles left early: the lowest point seen); bound[t] = the triangle's lowest phi as the later passes' filters use it (certified
for triangles left early, the strategy's estimate phi(x*) otherwise), with the positions and the
geoms (bound_mask[t]) it holds for in eval_x[t]. Batched worlds: triangle t queries only its
world's geoms [w k, (w + 1) k), w = t // ``tris_per_world``, k = ``geoms_per_world``
(broadphase.world_geoms), and its mask's bits are relative to w k; one world passes its
triangle count and the geom capacity (w = 0, all geoms: as before batching). Arguments:
:func:`decide_inputs`."""

_MULTIRES_KERNELS: dict = {}


def multires_kernel(max_registers: int, block_dim: int = 256):
    """:func:`decide_and_project` specialised to MULTIRES (:func:`decide_source`) and capped at
    ``max_registers`` registers a thread on CUDA (Config.execution.multires_registers; ignored on the CPU),
    compiled for blocks of ``block_dim`` threads (Config.execution.multires_block_dim: Warp's mesh queries keep
    their BVH stacks in shared memory, 32 ints a thread of the block). The same code path, so the
    same answers. One kernel per (cap, block), made on first use."""
    key = (int(max_registers), int(block_dim))
    if key not in _MULTIRES_KERNELS:
        fn = decide_source(False, True)
        fn.__name__ = fn.__qualname__ = "decide_and_project_multires"
        # a module of its own per (cap, block): Warp's "unique" modules are shared by equal code
        k = wp.kernel(fn, module=f"{__name__}.multires_r{key[0]}_b{key[1]}", enable_backward=False,
                      cuda_max_registers=key[0])
        k.module.options["block_dim"] = key[1]
        _MULTIRES_KERNELS[key] = k
    return _MULTIRES_KERNELS[key]


def decide_inputs(faces, objects, tris_per_world: int, geoms_per_world: int, lst, stride: int, strategy: int,
                  samples: int, rounds: int, opt_queries: int, offset: float, side_aware: int, x) -> list:
    """The inputs of a decision-point launch (:func:`decide_source`'s kernels) before its outputs:
    the skin ``faces``, the ``objects``' geoms (their exact mesh ids), the list ``lst`` (broadphase.TriList,
    count) and the strategy's settings."""
    o = objects
    return [faces, o.geoms_exact, tris_per_world, geoms_per_world, *lst, stride, strategy, samples, rounds,
            opt_queries, offset, side_aware, x]


@wp.func
def apply_vertex(i: int, stamp: int, sums: PushSums, hold: BoneHold, ex: Exchange, x: wp.array(dtype=wp.vec3),
                 push: wp.array(dtype=float), moved: wp.array(dtype=int), disp: wp.array(dtype=float)):
    """:func:`apply_contact` for touched vertex ``i``, where its bones allow it (bones.held_move); with
    two-way coupling (``ex`` not empty) its impulse summed and its normal load kept for its friction
    (exchange.record, exchange.touch_load; the friction itself: exchange.skin_friction)."""
    obj = sums.vertex_obj[i]
    dx = held_move(hold, i, x, x[i], sums.delta[i] * (1.0 / sums.hits[i]))
    sums.delta[i] = wp.vec3(0.0)
    sums.hits[i] = 0.0
    touch_load(ex, i, obj, dx)
    record(ex, i, obj, x[i], dx, wp.vec3(0.0))
    x[i] = x[i] + dx
    step = wp.length(dx)
    push[i] = push[i] + step
    if moved[i] == stamp:  # moved twice in this pass (the feature push, then Eq. 9): how far in all
        disp[i] = disp[i] + step
    else:
        disp[i] = step
    moved[i] = stamp


@wp.kernel
def apply_contact(
    sums: PushSums,
    touched_count: wp.array(dtype=int),
    stamp: int,
    shift: wp.array(dtype=wp.vec3),
    hold: BoneHold,
    ex: Exchange,
    x: wp.array(dtype=wp.vec3),
    push: wp.array(dtype=float),
    moved: wp.array(dtype=int),
    disp: wp.array(dtype=float),
    pass_move: wp.array(dtype=float),
    shifted: wp.array(dtype=wp.vec3),
):
    """For each touched vertex i: x_i += (depth-weighted mean of its Eq. 9 corrections); push_i
    accumulates |correction| over the frame (the contact report's force estimate); moved_i = stamp
    (this pass's number) and disp_i = |correction| (summed if this pass already moved i), for the
    next pass's list; the accumulators are cleared. ``pass_move`` (Config.tuning.contact_pass_tol > 0; else
    empty): pass_move[stamp] = the pass's largest disp_i. Batched worlds queried apart (``shifted``
    not empty: the object side's copy of the skin, Contact.set_query_offsets): shifted_i = x_i +
    shift_i for a skin vertex, so the copy stays current between passes without a full copy."""
    k = wp.tid()
    if k >= touched_count[0]:
        return
    i = sums.touched[k]
    apply_vertex(i, stamp, sums, hold, ex, x, push, moved, disp)
    if i < shifted.shape[0]:
        shifted[i] = x[i] + shift[i]
    if pass_move.shape[0] > 0:
        wp.atomic_max(pass_move, stamp, disp[i])