"""Edge length constraint, paper Eq. 2 (also the flesh attachment of Eq. 4, see attach.py)."""

import warp as wp

from physhand_mj.solver.gather import constraint_at, first_movable, idle, lanes_sum, scatter


@wp.kernel
def solve_edges(
    # Model:
    inv_mass: wp.array(dtype=float),
    ids: wp.array2d(dtype=int),
    rest: wp.array(dtype=float),
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
    """C(x1, x2) = |x1 - x2| - L  (Eq. 2);  grad_x1 C = n = (x1 - x2)/|x1 - x2| = -grad_x2 C,
    so A = w1 + w2 + alpha~ and dx1 = w1 n dlam, dx2 = -w2 n dlam (see solver/__init__.py)."""
    t = wp.tid()
    j = constraint_at(t, start, order, order_count)
    if j < 0:
        return
    s = slot_base + j  # corner l's slot: s + l C (solver/gather.py; unused by the atomic path)
    nc = ids.shape[0]
    ok, lam_new, i1, i2, c1, c2 = edge_project(inv_mass, ids, rest, alpha, inv_h2, reset, x, lam, j)
    if not ok:
        idle(lam, j, reset, slots, s, nc, 2)
        return
    lam[j] = lam_new
    scatter(delta, slots, s, i1, c1)
    scatter(delta, slots, s + nc, i2, c2)


@wp.func
def edge_project(inv_mass: wp.array(dtype=float), ids: wp.array2d(dtype=int), rest: wp.array(dtype=float),
                 alpha: wp.array(dtype=float), inv_h2: float, reset: int, x: wp.array(dtype=wp.vec3),
                 lam: wp.array(dtype=float), j: int):
    """Edge j's projection (Eq. 2): (moves, its new lambda, its 2 vertex ids, their corrections);
    ``moves`` 0 for a degenerate edge or two kinematic vertices (nothing moves)."""
    i1 = ids[j, 0]
    i2 = ids[j, 1]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    d = x[i1] - x[i2]
    length = wp.length(d)
    at = alpha[j] * inv_h2
    a = w1 + w2 + at
    zero = wp.vec3(0.0)
    if length < 1.0e-12 or a <= 1.0e-20 or (w1 == 0.0 and w2 == 0.0):  # (both kinematic: nothing moves)
        return False, 0.0, i1, i2, zero, zero
    lam_j = float(0.0)
    if reset == 0:  # Algorithm 1 line 4: lambda <- 0 each substep
        lam_j = lam[j]
    dlam = -(length - rest[j] + at * lam_j) / a
    n = d * (dlam / length)
    return True, lam_j + dlam, i1, i2, n * w1, -(n * w2)


@wp.kernel
def solve_edges_gathered(
    # Model:
    inv_mass: wp.array(dtype=float),
    ids: wp.array2d(dtype=int),
    rest: wp.array(dtype=float),
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
    """:func:`solve_edges` and its gather in one pass by vertex (as tet.solve_tets_gathered)."""
    t = wp.tid()
    i = t // lanes
    lane = t % lanes
    nc = ids.shape[0]
    d = wp.vec3(0.0)
    for k in range(gather_off[i] + lane, gather_off[i + 1], lanes):
        sl = gather_slot[k]  # corner l of edge j: slot l C + j (the group's one family, base 0)
        l = sl // nc
        j = sl - l * nc
        ok, lam_new, i1, i2, c1, c2 = edge_project(inv_mass, ids, rest, alpha, inv_h2, reset, x, lam, j)
        d = d + wp.where(l == 0, c1, c2)
        if first_movable(inv_mass, i1, i2, i2, i2) == l:
            lam[j] = wp.where(ok, lam_new, wp.where(reset != 0, 0.0, lam[j]))
    d = lanes_sum(d, lanes)
    if lane == 0:
        delta[i] = d
