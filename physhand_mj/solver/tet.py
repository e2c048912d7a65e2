"""Tetrahedron volume constraint, paper Eq. 3."""

import warp as wp

from physhand_mj.solver.gather import constraint_at, first_movable, idle, lanes_sum, scatter



@wp.func
def six_volume(x1: wp.vec3, x2: wp.vec3, x3: wp.vec3, x4: wp.vec3):
    """x21 x x31 . x41 = 6 x signed volume (positive for a positively oriented tet)."""
    return wp.dot(wp.cross(x2 - x1, x3 - x1), x4 - x1)


@wp.kernel
def solve_tets(
    # Model:
    inv_mass: wp.array(dtype=float),
    ids: wp.array2d(dtype=int),
    rest6v: wp.array(dtype=float),
    alpha: wp.array(dtype=float),
    # Solver in:
    inv_h2: float,
    start: int,
    reset: int,
    # State in/out:
    x: wp.array(dtype=wp.vec3),
    lam: wp.array(dtype=float),
    delta: wp.array(dtype=wp.vec3),
    slots: wp.array(dtype=wp.vec3),
    slot_base: int,
    # Per-region sleeping (physhand_mj/regions.py; empty when off): the constraints to solve,
    # order[0: order_count[0]] (the others have every vertex asleep or on a bone)
    order: wp.array(dtype=int),
    order_count: wp.array(dtype=int),
):
    """C(x1..x4) = x21 x x31 . x41 - 6V (Eq. 3). Gradients: g2 = x31 x x41, g3 = x41 x x21,
    g4 = x21 x x31, g1 = -(g2 + g3 + g4); A = sum_i w_i |g_i|^2 + alpha~ (see solver/__init__.py).
    Kinematic vertices have w = 0, so their update adds zero.
    An inverted tet has C < -6V, so the projection pushes it back through zero volume."""
    t = wp.tid()
    j = constraint_at(t, start, order, order_count)
    if j < 0:
        return
    s = slot_base + j  # corner l's slot: s + l C (solver/gather.py; unused by the atomic path)
    nc = ids.shape[0]
    ok, lam_new, i1, i2, i3, i4, c1, c2, c3, c4 = tet_project(inv_mass, ids, rest6v, alpha, inv_h2, reset, x, lam, j)
    if not ok:
        idle(lam, j, reset, slots, s, nc, 4)
        return
    lam[j] = lam_new
    scatter(delta, slots, s + 0 * nc, i1, c1)
    scatter(delta, slots, s + 1 * nc, i2, c2)
    scatter(delta, slots, s + 2 * nc, i3, c3)
    scatter(delta, slots, s + 3 * nc, i4, c4)


@wp.func
def tet_project(inv_mass: wp.array(dtype=float), ids: wp.array2d(dtype=int), rest6v: wp.array(dtype=float),
                alpha: wp.array(dtype=float), inv_h2: float, reset: int, x: wp.array(dtype=wp.vec3),
                lam: wp.array(dtype=float), j: int):
    """Tet j's projection (Eq. 3): C(x1..x4) = x21 x x31 . x41 - 6V. Gradients: g2 = x31 x x41,
    g3 = x41 x x21, g4 = x21 x x31, g1 = -(g2 + g3 + g4); A = sum_i w_i |g_i|^2 + alpha~ (see
    solver/__init__.py). Kinematic vertices have w = 0, so their update adds zero. An inverted tet
    has C < -6V, so the projection pushes it back through zero volume. Returns (moves, its new
    lambda, its 4 vertex ids, their 4 corrections w_l g_l dlambda); ``moves`` 0 when every vertex
    is kinematic or the gradient degenerates (nothing moves)."""
    i1 = ids[j, 0]
    i2 = ids[j, 1]
    i3 = ids[j, 2]
    i4 = ids[j, 3]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    w3 = inv_mass[i3]
    w4 = inv_mass[i4]
    zero = wp.vec3(0.0)
    if w1 == 0.0 and w2 == 0.0 and w3 == 0.0 and w4 == 0.0:  # every vertex kinematic: nothing moves
        return False, 0.0, i1, i2, i3, i4, zero, zero, zero, zero
    x1 = x[i1]
    x21 = x[i2] - x1
    x31 = x[i3] - x1
    x41 = x[i4] - x1
    g2 = wp.cross(x31, x41)
    g3 = wp.cross(x41, x21)
    g4 = wp.cross(x21, x31)
    g1 = -(g2 + g3 + g4)
    at = alpha[j] * inv_h2
    a = (w1 * wp.length_sq(g1) + w2 * wp.length_sq(g2) + w3 * wp.length_sq(g3)
         + w4 * wp.length_sq(g4) + at)
    if a <= 1.0e-20:
        return False, 0.0, i1, i2, i3, i4, zero, zero, zero, zero
    lam_j = float(0.0)
    if reset == 0:  # Algorithm 1 line 4: lambda <- 0 each substep
        lam_j = lam[j]
    dlam = -(wp.dot(g4, x41) - rest6v[j] + at * lam_j) / a
    return True, lam_j + dlam, i1, i2, i3, i4, g1 * (w1 * dlam), g2 * (w2 * dlam), g3 * (w3 * dlam), g4 * (w4 * dlam)


@wp.kernel
def solve_tets_gathered(
    # Model:
    inv_mass: wp.array(dtype=float),
    ids: wp.array2d(dtype=int),
    rest6v: wp.array(dtype=float),
    alpha: wp.array(dtype=float),
    # Solver in:
    inv_h2: float,
    reset: int,
    # State in/out:
    x: wp.array(dtype=wp.vec3),
    lam: wp.array(dtype=float),
    # Model (the group's gather lists, solver/gather.py):
    gather_off: wp.array(dtype=int),
    gather_slot: wp.array(dtype=int),
    lanes: int,
    # out:
    delta: wp.array(dtype=wp.vec3),
):
    """:func:`solve_tets` and its gather in one pass by vertex (solver/gather.py, "by vertex"):
    ``lanes`` threads of vertex i walk its row of the tet group's list, project each tet there
    (:func:`tet_project`) and keep corner l's correction; ``delta[i]`` = their sum, in the gather's
    order (apply_jacobi's atomic path adds it). The tet's lambda is stored by its first movable
    corner's thread (Config.iterations 1: every thread reads lambda 0)."""
    t = wp.tid()
    i = t // lanes
    lane = t % lanes
    nc = ids.shape[0]
    d = wp.vec3(0.0)
    for k in range(gather_off[i] + lane, gather_off[i + 1], lanes):
        sl = gather_slot[k]  # corner l of tet j: slot l C + j (the group's one family, base 0)
        l = sl // nc
        j = sl - l * nc
        ok, lam_new, i1, i2, i3, i4, c1, c2, c3, c4 = tet_project(inv_mass, ids, rest6v, alpha, inv_h2, reset, x, lam, j)
        c = c1
        if l == 1:
            c = c2
        elif l == 2:
            c = c3
        elif l == 3:
            c = c4
        d = d + c
        if first_movable(inv_mass, i1, i2, i3, i4) == l:
            lam[j] = wp.where(ok, lam_new, wp.where(reset != 0, 0.0, lam[j]))
    d = lanes_sum(d, lanes)
    if lane == 0:
        delta[i] = d
