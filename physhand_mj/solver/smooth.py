"""Skin smoothness constraint, paper Eq. 6: keep the rest dihedral angle of adjacent skin triangles.

The paper writes C = arccos(n1 . n2) - phi. arccos has an infinite derivative at a flat pair
(n1 . n2 = 1), which is where most skin pairs rest, so this module uses the same angle with a sign,
theta = atan2((n1 x n0) . e/|e|, n0 . n1), whose gradient is finite everywhere and equals the classic
dihedral-angle gradient (Bridson et al. 2003). |theta| is the paper's arccos(n0 . n1).
"""

import warp as wp

from physhand_mj.solver.xpbd import constraint_kernel, multiplier_step

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time



@wp.func
def fast_atan2(y: float, x: float):
    """atan2 from the odd polynomial of Abramowitz & Stegun 4.4.49 on [0, 1] (|error| <= 2e-8 rad,
    below float32 resolution) and octant symmetries: libm's atan2f took a third of the smoothness
    kernel's time on Warp's CPU backend. Returns 0 for (0, 0)."""
    ax = wp.abs(x)
    ay = wp.abs(y)
    mx = wp.max(ax, ay)
    if mx == 0.0:
        return 0.0
    a = wp.min(ax, ay) / mx
    s = a * a
    p = 0.0028662257
    p = p * s - 0.0161657367
    p = p * s + 0.0429096138
    p = p * s - 0.0752896400
    p = p * s + 0.1065626393
    p = p * s - 0.1420889944
    p = p * s + 0.1999355085
    p = p * s - 0.3333314528
    r = (p * s + 1.0) * a
    if ay > ax:
        r = 1.57079637 - r
    if x < 0.0:
        r = 3.14159274 - r
    if y < 0.0:
        r = -r
    return r


@wp.func
def dihedral_angle_gradients(e0: wp.vec3, e1: wp.vec3, o0: wp.vec3, o1: wp.vec3):
    """Signed dihedral angle theta (rad) of triangles (e0, e1, o0) and (e1, e0, o1) sharing the edge
    e0-e1, and d theta / d (x_e0, x_e1, x_o0, x_o1) (Bridson et al. 2003). With E = e1 - e0,
    N0 = (o0 - e0) x (o0 - e1), N1 = (o1 - e1) x (o1 - e0) (the outward normals, |N| = 2 area),
    a = N0/|N0|^2, b = N1/|N1|^2:
        theta = atan2((N1 x N0) . E/|E|, N0 . N1)
        g_o0 = |E| a,  g_o1 = |E| b,
        g_e0 = ((o0 - e1).E/|E|) a + ((o1 - e1).E/|E|) b,
        g_e1 = -((o0 - e0).E/|E|) a - ((o1 - e0).E/|E|) b   (the four sum to zero).
    Degenerate triangles give theta = 0 and zero gradients."""
    e = e1 - e0
    elen = wp.length(e)
    n0 = wp.cross(o0 - e0, o0 - e1)
    n1 = wp.cross(o1 - e1, o1 - e0)
    q0 = wp.length_sq(n0)
    q1 = wp.length_sq(n1)
    z = wp.vec3(0.0)
    if elen < 1.0e-12 or q0 < 1.0e-30 or q1 < 1.0e-30:
        return 0.0, z, z, z, z
    # reciprocals once: Warp's vec / scalar divides per component
    eh = e * (1.0 / elen)
    theta = fast_atan2(wp.dot(wp.cross(n1, n0), eh), wp.dot(n0, n1))
    a = n0 * (1.0 / q0)
    b = n1 * (1.0 / q1)
    g0 = a * wp.dot(o0 - e1, eh) + b * wp.dot(o1 - e1, eh)
    g1 = -(a * wp.dot(o0 - e0, eh) + b * wp.dot(o1 - e0, eh))
    return theta, g0, g1, a * elen, b * elen


@wp.func
def dihedral_correction(e0: wp.vec3, e1: wp.vec3, o0: wp.vec3, o1: wp.vec3, w0: float, w1: float, w2: float,
                        w3: float, rest: float, at: float, lam_j: float):
    """Eq. 6's XPBD step for one pair of skin triangles: (moves, dlam, dx_e0, dx_e1, dx_o0, dx_o1);
    ``at`` = alpha / h^2. moves = 0 where every vertex is kinematic or the gradient vanishes."""
    z = wp.vec3(0.0)
    if w0 == 0.0 and w1 == 0.0 and w2 == 0.0 and w3 == 0.0:  # every vertex kinematic: nothing moves
        return 0, 0.0, z, z, z, z
    theta, g0, g1, g2, g3 = dihedral_angle_gradients(e0, e1, o0, o1)
    c = theta - rest
    # keep C in (-pi, pi]: the signed angle wraps at +-pi
    if c > wp.pi:
        c = c - 2.0 * wp.pi
    if c < -wp.pi:
        c = c + 2.0 * wp.pi
    a = w0 * wp.length_sq(g0) + w1 * wp.length_sq(g1) + w2 * wp.length_sq(g2) + w3 * wp.length_sq(g3) + at
    if a <= 1.0e-20:
        return 0, 0.0, z, z, z, z
    dlam = multiplier_step(c, at, lam_j, a)
    return 1, dlam, g0 * (w0 * dlam), g1 * (w1 * dlam), g2 * (w2 * dlam), g3 * (w3 * dlam)


solve_dihedrals = constraint_kernel(dihedral_correction, 4, False, "solve_dihedrals", __name__)
"""C_smo = theta(x_e0, x_e1, x_o0, x_o1) - phi (Eq. 6, signed angle as in the module doc; one
compliance ``alpha`` for every pair: solver/xpbd.py)."""
