"""Tetrahedron volume constraint, paper Eq. 3."""

import warp as wp

from physhand_mj.solver.gather import constraint_at, idle, scatter



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
    if w1 == 0.0 and w2 == 0.0 and w3 == 0.0 and w4 == 0.0:  # every vertex kinematic: nothing moves
        idle(lam, j, reset, slots, s, nc, 4)
        return
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
        idle(lam, j, reset, slots, s, nc, 4)
        return
    lam_j = wp.where(reset != 0, 0.0, lam[j])  # Algorithm 1 line 4: lambda <- 0 each substep
    dlam = -(wp.dot(g4, x41) - rest6v[j] + at * lam_j) / a
    lam[j] = lam_j + dlam
    scatter(delta, slots, s + 0 * nc, i1, g1 * (w1 * dlam))
    scatter(delta, slots, s + 1 * nc, i2, g2 * (w2 * dlam))
    scatter(delta, slots, s + 2 * nc, i3, g3 * (w3 * dlam))
    scatter(delta, slots, s + 3 * nc, i4, g4 * (w4 * dlam))
