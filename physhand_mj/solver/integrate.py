"""Per-substep integration kernels (Algorithm 1, lines 3, 12, 14-15) and the kinematic skeleton."""

import warp as wp

from physhand_mj.solver.gather import gathered, gathered_lanes
from physhand_mj.solver.tet import six_volume

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.func
def count_guard(guard: wp.array(dtype=int), k: int, world: int):
    """guard[k] += 1, and with batched worlds (guard longer than 4) world ``world``'s own slot."""
    wp.atomic_add(guard, k, 1)
    if guard.shape[0] > 4:
        wp.atomic_add(guard, 4 + 4 * world + k, 1)


@wp.kernel
def begin_frame(
    body_pose: wp.array2d(dtype=wp.transform),
    body_sub: wp.array2d(dtype=wp.transform),
    guard: wp.array(dtype=int),
):
    """Zero the frame's guard counters, and interpolate the bone poses at the end of every substep
    k, fraction s = (k + 1) / substeps, between the frame's start (body_pose[0]) and end
    (body_pose[1]) poses: lerp of positions, slerp of rotations. Launched over (substeps, max(B, 1))."""
    k, b = wp.tid()
    nb = wp.max(body_sub.shape[1], 1)
    n = body_sub.shape[0] * nb  # threads of the launch, each zeroing every n-th counter
    j = k * nb + b
    while j < guard.shape[0]:  # [0, 4): the frame's; batched worlds: then 4 per world
        guard[j] = 0
        j += n
    if b >= body_pose.shape[1]:
        return
    s = float(k + 1) / float(body_sub.shape[0])
    t0 = body_pose[0, b]
    t1 = body_pose[1, b]
    p = wp.lerp(wp.transform_get_translation(t0), wp.transform_get_translation(t1), s)
    q = wp.quat_slerp(wp.transform_get_rotation(t0), wp.transform_get_rotation(t1), s)
    body_sub[k, b] = wp.transform(p, q)


@wp.func
def finish_substep(i: int, world: int, xi: wp.vec3, vi: wp.vec3, w: float, h: float, x_prev: wp.array(dtype=wp.vec3),
                   guard: wp.array(dtype=int)):
    """Vertex ``i``'s end of a substep (Algorithm 1, lines 14-15): v = (x - x^i) / h, or back to
    x^i at rest where x is not finite (counted in guard[0]). Returns (x, v)."""
    if not (wp.isfinite(xi[0]) and wp.isfinite(xi[1]) and wp.isfinite(xi[2])):
        count_guard(guard, 0, world)
        return x_prev[i], wp.vec3(0.0)
    if w > 0.0:
        return xi, (xi - x_prev[i]) * (1.0 / h)
    return xi, vi


@wp.func
def start_substep(i: int, world: int, xi: wp.vec3, vi: wp.vec3, w: float, start: int, h: float, damp: float,
                  gravity: wp.vec3, vertex_body: wp.array(dtype=int), body_local: wp.array(dtype=wp.vec3),
                  body_sub: wp.array2d(dtype=wp.transform), x_prev: wp.array(dtype=wp.vec3),
                  x_safe: wp.array(dtype=wp.vec3), guard: wp.array(dtype=int)):
    """Vertex ``i``'s start of substep ``start`` (line 3): x^i <- x, then its bone's pose for a
    skeleton vertex, else the prediction x + h (v + h g) damped; a non-finite x set from outside
    restarts from x_safe (counted in guard[0]). Returns (x, v)."""
    if not (wp.isfinite(xi[0]) and wp.isfinite(xi[1]) and wp.isfinite(xi[2])):
        xi = x_safe[i]
        vi = wp.vec3(0.0)
        count_guard(guard, 0, world)
    x_prev[i] = xi
    b = vertex_body[i]
    if b >= 0:
        xi = wp.transform_point(body_sub[start, b], body_local[i])
    elif w > 0.0:
        vi = (vi + gravity * h) * damp
        xi = xi + vi * h
    return xi, vi


@wp.func
def fast_vertex(i: int, vi: wp.vec3, h: float, speed_limit: float, vertex_carrier: wp.array(dtype=int),
                body_sub: wp.array2d(dtype=wp.transform), x_prev: wp.array(dtype=wp.vec3)):
    """Whether soft vertex ``i`` ends the frame (velocity ``vi``) faster than ``speed_limit`` (m/s)
    relative to its carrier bone: the rigid velocity the bone gives it over the last substep."""
    vr = vi
    b = vertex_carrier[i]
    ns = body_sub.shape[0]
    if b >= 0 and ns >= 2:
        p = x_prev[i]
        ride = wp.transform_point(body_sub[ns - 1, b], wp.transform_point(wp.transform_inverse(body_sub[ns - 2, b]), p))
        vr = vi - (ride - p) * (1.0 / h)
    return wp.length(vr) > speed_limit


@wp.kernel
def advance(
    # Model:
    inv_mass: wp.array(dtype=float),
    vertex_body: wp.array(dtype=int),
    body_local: wp.array(dtype=wp.vec3),
    vertex_count: wp.array2d(dtype=float),
    # Solver in:
    gravity: wp.vec3,
    h: float,
    damp: float,
    finish: int,
    group: int,
    relaxation: float,
    start: int,
    body_sub: wp.array2d(dtype=wp.transform),
    speed_limit: float,
    vertex_carrier: wp.array(dtype=int),
    vertex_world: wp.array(dtype=int),
    # State in/out:
    x_safe: wp.array(dtype=wp.vec3),
    # State in/out:
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3),
    guard: wp.array(dtype=int),
    # Model (the pending group's gather lists, solver/gather.py; empty on the atomic path):
    gather_off: wp.array(dtype=int),
    gather_slot: wp.array(dtype=int),
    slots: wp.array(dtype=wp.vec3),
    # Per-region sleeping (physhand_mj/solver/regions.py; empty when off):
    vertex_region: wp.array(dtype=int),
    region_fast: wp.array(dtype=int),
):
    """The per-vertex work between two substeps, in one launch (start < 0 after the last substep
    also commits the frame's finite positions to x_safe).

    finish != 0 ends the current substep: apply the last Jacobi group's pending correction
    (group >= 0), then v^{i+1} = (x^{i+1} - x^i) / h (Algorithm 1, lines 14-15). A non-finite
    position is reset to x^i with zero velocity and counted in guard[0], so NaN never spreads.

    start >= 0 begins substep ``start``: save x^i, then x <- x^i + h v^i + h^2 M^-1 f_ext with
    f_ext = m g and v scaled by damp = exp(-damping h) (line 3). A kinematic (skeleton) vertex goes to
    its bone's pose at the end of that substep (begin_frame) applied to its body-frame
    position: bones are an input, constraints never move them (w = 0). A non-finite position met here
    (set from outside the solver) is reset to the end of the last frame (x_safe) and counted.
    After the last substep, soft vertices moving faster than ``speed_limit`` (m/s; > 0) relative to
    their carrier bone (the rigid velocity it gives them over the last substep) are counted in
    guard[3] (the sleep test, activity.py: only moving vertices touch the counter) and, with
    per-region sleeping, in their region's ``region_fast``.
    """
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    w = inv_mass[i]
    if finish != 0:
        if group >= 0:
            n = vertex_count[group, i]
            if n > 0.0:
                xi = xi + gathered(delta, gather_off, gather_slot, slots, i) * (relaxation / n)
            if gather_off.shape[0] == 0:  # (the gather leaves delta alone: zero)
                delta[i] = wp.vec3(0.0)
        xi, vi = finish_substep(i, vertex_world[i], xi, vi, w, h, x_prev, guard)
    if start >= 0:
        xi, vi = start_substep(i, vertex_world[i], xi, vi, w, start, h, damp, gravity, vertex_body, body_local,
                               body_sub, x_prev, x_safe, guard)
    else:
        x_safe[i] = xi
        if speed_limit > 0.0 and w > 0.0:
            if fast_vertex(i, vi, h, speed_limit, vertex_carrier, body_sub, x_prev):
                count_guard(guard, 3, vertex_world[i])
                if region_fast.shape[0] > 0:
                    r = vertex_region[i]
                    if r >= 0:
                        wp.atomic_add(region_fast, r, 1)
    x[i] = xi
    v[i] = vi


@wp.kernel
def carry_asleep(
    vertex_carrier: wp.array(dtype=int),
    vertex_world: wp.array(dtype=int),
    body_pose: wp.array2d(dtype=wp.transform),
    frame_dt: float,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    x_prev: wp.array(dtype=wp.vec3),
    x_safe: wp.array(dtype=wp.vec3),
    guard: wp.array(dtype=int),
):
    """A sleeping hand's frame: every vertex rides rigidly with its carrier bone from the start to
    the end of the frame (x <- T_end T_start^-1 x) with that motion's velocity (so a hand carried at
    a steady speed wakes moving with it). A non-finite position (set from outside) restarts from
    the last finite one (x_safe) and is counted in guard[0], as in ``advance``."""
    i = wp.tid()
    x0 = x[i]
    if not (wp.isfinite(x0[0]) and wp.isfinite(x0[1]) and wp.isfinite(x0[2])):
        x0 = x_safe[i]
        count_guard(guard, 0, vertex_world[i])
    xi = x0
    b = vertex_carrier[i]
    if b >= 0:
        xi = wp.transform_point(body_pose[1, b], wp.transform_point(wp.transform_inverse(body_pose[0, b]), x0))
    x[i] = xi
    x_prev[i] = xi
    x_safe[i] = xi
    v[i] = (xi - x0) * (1.0 / frame_dt)


@wp.kernel
def apply_jacobi(
    # Model:
    vertex_count: wp.array2d(dtype=float),
    # Solver in:
    group: int,
    relaxation: float,
    # State in/out:
    x: wp.array(dtype=wp.vec3),
    delta: wp.array(dtype=wp.vec3),
    # Model (the group's gather lists, solver/gather.py; empty on the atomic path):
    gather_off: wp.array(dtype=int),
    gather_slot: wp.array(dtype=int),
    slots: wp.array(dtype=wp.vec3),
    lanes: int,
):
    """Jacobi step: x_i += omega / n_i * sum of the corrections of vertex i's n_i constraints of
    one group of families (groups run one after another: solver.model.JACOBI_GROUPS): ``delta[i]``
    plus, when the solver gathers, vertex i's slots, summed by ``lanes`` neighbouring threads
    (gather.GATHER_LANES; the launch is ``lanes`` x the vertices; 1 on the atomic path)."""
    t = wp.tid()
    i = t // lanes
    if gather_off.shape[0] == 0:  # the atomic path (one lane); the gather leaves delta alone: zero
        n = vertex_count[group, i]
        if n > 0.0:
            x[i] = x[i] + delta[i] * (relaxation / n)
        delta[i] = wp.vec3(0.0)
    else:
        d = gathered_lanes(gather_off, gather_slot, slots, i, t % lanes, lanes)
        n = vertex_count[group, i]
        if t % lanes == 0 and n > 0.0:
            x[i] = x[i] + d * (relaxation / n)


@wp.kernel
def count_inverted(
    tets: wp.array2d(dtype=int),
    vertex_world: wp.array(dtype=int),
    x: wp.array(dtype=wp.vec3),
    guard: wp.array(dtype=int),
):
    """guard[1] += number of tets whose signed volume is <= 0 (inverted or flat)."""
    j = wp.tid()
    if six_volume(x[tets[j, 0]], x[tets[j, 1]], x[tets[j, 2]], x[tets[j, 3]]) <= 0.0:
        count_guard(guard, 1, vertex_world[tets[j, 0]])


@wp.kernel
def tether_skin(
    skin_body: wp.array(dtype=int),
    vertex_world: wp.array(dtype=int),
    skin_local: wp.array(dtype=wp.vec3),
    body_sub: wp.array2d(dtype=wp.transform),
    sub: int,
    bound: float,
    x: wp.array(dtype=wp.vec3),
    guard: wp.array(dtype=int),
):
    """Keep skin vertex i within ``bound`` (m) of its rigidly carried position (its bone's pose at
    the end of substep ``sub`` applied to skin_local[i]); each vertex moved counts in guard[2]."""
    i = wp.tid()
    b = skin_body[i]
    if b < 0:
        return
    r = wp.transform_point(body_sub[sub, b], skin_local[i])
    d = x[i] - r
    n = wp.length(d)
    if n > bound:
        x[i] = r + d * (bound / n)
        count_guard(guard, 2, vertex_world[i])
