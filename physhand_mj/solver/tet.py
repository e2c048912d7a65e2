"""Tetrahedron volume constraint, paper Eq. 3."""

import warp as wp

from physhand_mj.solver.xpbd import constraint_kernel, multiplier_step

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
    dlam = multiplier_step(wp.dot(g4, x41) - rest6v, at, lam_j, a)
    return 1, dlam, g1 * (w1 * dlam), g2 * (w2 * dlam), g3 * (w3 * dlam), g4 * (w4 * dlam)


solve_tets = constraint_kernel(tet_correction, 4, True, "solve_tets", __name__)
"""C(x1..x4) = x21 x x31 . x41 - 6V (Eq. 3). Gradients: g2 = x31 x x41, g3 = x41 x x21,
g4 = x21 x x31, g1 = -(g2 + g3 + g4); A = sum_i w_i |g_i|^2 + alpha~ (solver/xpbd.py).
Kinematic vertices have w = 0, so their update adds zero.
An inverted tet has C < -6V, so the projection pushes it back through zero volume."""
