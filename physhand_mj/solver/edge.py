"""Edge length constraint, paper Eq. 2 (also the flesh attachment of Eq. 4, see attach.py)."""

import warp as wp

from physhand_mj.solver.gather import constraint_at, idle, scatter

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.func
def edge_correction(x1: wp.vec3, x2: wp.vec3, w1: float, w2: float, rest: float, at: float, lam_j: float):
    """Eq. 2's XPBD step for one edge: (moves, dlam, dx1, dx2); ``at`` = alpha / h^2, ``lam_j`` its
    lambda so far. moves = 0 for a degenerate edge or two kinematic vertices (nothing moves)."""
    d = x1 - x2
    length = wp.length(d)
    a = w1 + w2 + at
    z = wp.vec3(0.0)
    if length < 1.0e-12 or a <= 1.0e-20 or (w1 == 0.0 and w2 == 0.0):  # (both kinematic: nothing moves)
        return 0, 0.0, z, z
    dlam = -(length - rest + at * lam_j) / a
    n = d * (dlam / length)
    return 1, dlam, n * w1, -(n * w2)


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
    # Per-region sleeping (physhand_mj/solver/regions.py; empty when off): the constraints to solve,
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
    i1 = ids[j, 0]
    i2 = ids[j, 1]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    at = alpha[j] * inv_h2
    s = slot_base + j  # corner l's slot: s + l C (solver/gather.py; unused by the atomic path)
    nc = ids.shape[0]
    lam_j = wp.where(reset != 0, 0.0, lam[j])  # Algorithm 1 line 4: lambda <- 0 each substep
    moves, dlam, d1, d2 = edge_correction(x[i1], x[i2], w1, w2, rest[j], at, lam_j)
    if moves == 0:
        idle(lam, j, reset, slots, s, nc, 2)
        return
    lam[j] = lam_j + dlam
    scatter(delta, slots, s, i1, d1)
    scatter(delta, slots, s + nc, i2, d2)
