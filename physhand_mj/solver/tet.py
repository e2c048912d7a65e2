"""Tetrahedron volume constraint, paper Eq. 3."""

import warp as wp

from physhand_mj.solver.gather import constraint_at, idle, scatter

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time



@wp.func
def six_volume(x1: wp.vec3, x2: wp.vec3, x3: wp.vec3, x4: wp.vec3):
    """x21 x x31 . x41 = 6 x signed volume (positive for a positively oriented tet)."""
    return wp.dot(wp.cross(x2 - x1, x3 - x1), x4 - x1)


@wp.func
def tet_correction(x1: wp.vec3, x2: wp.vec3, x3: wp.vec3, x4: wp.vec3, w1: float, w2: float, w3: float,
                   w4: float, rest6v: float, at: float, lam_j: float):
    """Eq. 3's XPBD step for one tet: (moves, dlam, dx1, dx2, dx3, dx4); ``at`` = alpha / h^2.
    moves = 0 where every vertex is kinematic or the gradient vanishes."""
    z = wp.vec3(0.0)
    if w1 == 0.0 and w2 == 0.0 and w3 == 0.0 and w4 == 0.0:  # every vertex kinematic: nothing moves
        return 0, 0.0, z, z, z, z
    x21 = x2 - x1
    x31 = x3 - x1
    x41 = x4 - x1
    g2 = wp.cross(x31, x41)
    g3 = wp.cross(x41, x21)
    g4 = wp.cross(x21, x31)
    g1 = -(g2 + g3 + g4)
    a = (w1 * wp.length_sq(g1) + w2 * wp.length_sq(g2) + w3 * wp.length_sq(g3)
         + w4 * wp.length_sq(g4) + at)
    if a <= 1.0e-20:
        return 0, 0.0, z, z, z, z
    dlam = -(wp.dot(g4, x41) - rest6v + at * lam_j) / a
    return 1, dlam, g1 * (w1 * dlam), g2 * (w2 * dlam), g3 * (w3 * dlam), g4 * (w4 * dlam)


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
    # Per-region sleeping (physhand_mj/solver/regions.py; empty when off): the constraints to solve,
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
    i1 = ids[j, 0]
    i2 = ids[j, 1]
    i3 = ids[j, 2]
    i4 = ids[j, 3]
    w1 = inv_mass[i1]
    w2 = inv_mass[i2]
    w3 = inv_mass[i3]
    w4 = inv_mass[i4]
    s = slot_base + j  # corner l's slot: s + l C (solver/gather.py; unused by the atomic path)
    nc = ids.shape[0]
    at = alpha[j] * inv_h2
    lam_j = wp.where(reset != 0, 0.0, lam[j])  # Algorithm 1 line 4: lambda <- 0 each substep
    moves = int(0)
    dlam = float(0.0)
    d1 = wp.vec3(0.0)
    d2 = wp.vec3(0.0)
    d3 = wp.vec3(0.0)
    d4 = wp.vec3(0.0)
    if not (w1 == 0.0 and w2 == 0.0 and w3 == 0.0 and w4 == 0.0):  # (kinematic tets read no positions)
        moves, dlam, d1, d2, d3, d4 = tet_correction(x[i1], x[i2], x[i3], x[i4], w1, w2, w3, w4, rest6v[j], at, lam_j)
    if moves == 0:
        idle(lam, j, reset, slots, s, nc, 4)
        return
    lam[j] = lam_j + dlam
    scatter(delta, slots, s + 0 * nc, i1, d1)
    scatter(delta, slots, s + 1 * nc, i2, d2)
    scatter(delta, slots, s + 2 * nc, i3, d3)
    scatter(delta, slots, s + 3 * nc, i4, d4)
