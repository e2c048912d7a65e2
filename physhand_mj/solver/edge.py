"""Edge length constraint, paper Eq. 2 (also the flesh attachment of Eq. 4, see attach.py)."""

import warp as wp

from physhand_mj.solver.xpbd import constraint_kernel, multiplier_step

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.func
def edge_correction(x1: wp.vec3, x2: wp.vec3, w1: float, w2: float, rest: float, at: float, lam_j: float):
    """Eq. 2's XPBD step for one edge: (moves, dlam, dx1, dx2); ``at`` = alpha / h^2, ``lam_j`` its
    lambda so far. moves = 0 for a degenerate edge or two kinematic vertices (nothing moves). A
    negative ``rest`` is a stretch-only edge of length -rest (Config.skin_compression /
    flesh_compression False): shorter than that, it does nothing."""
    d = x1 - x2
    length = wp.length(d)
    a = w1 + w2 + at
    z = wp.vec3(0.0)
    if length < 1.0e-12 or a <= 1.0e-20 or (w1 == 0.0 and w2 == 0.0):  # (both kinematic: nothing moves)
        return 0, 0.0, z, z
    if rest < 0.0 and length < -rest:  # a stretch-only edge, compressed: no force
        return 0, 0.0, z, z
    dlam = multiplier_step(length - wp.abs(rest), at, lam_j, a)
    n = d * (dlam / length)
    return 1, dlam, n * w1, -(n * w2)


solve_edges = constraint_kernel(edge_correction, 2, True, "solve_edges", __name__)
"""C(x1, x2) = |x1 - x2| - L  (Eq. 2);  grad_x1 C = n = (x1 - x2)/|x1 - x2| = -grad_x2 C,
so A = w1 + w2 + alpha~ and dx1 = w1 n dlam, dx2 = -w2 n dlam (solver/xpbd.py)."""
