"""One XPBD constraint kernel for every family (edge.py Eq. 2 and the attachments, tet.py Eq. 3,
smooth.py Eq. 6), made from the family's correction ``wp.func`` by :func:`constraint_kernel`.

For constraint j with gradient g_i at vertex i (Algorithm 1 of the paper, solver/__init__.py):

    A = sum_i w_i |g_i|^2 + alpha~,   dlam = -(C(x) + alpha~ lam_j) / A,   dx_i = w_i g_i dlam

:func:`multiplier_step` is the dlam of every family's correction; the kernel does the rest the
families share: the constraint of the thread (regions.py's compacted list), its inverse masses,
lambda reset each substep (Algorithm 1 line 4), a constraint whose vertices are all kinematic or
whose correction moves nothing left idle (solver/gather.py), and the corrections scattered
(atomics, or the gather's slots).
"""

import warp as wp

from physhand_mj.solver.gather import constraint_at, idle, scatter

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.func
def multiplier_step(c: float, at: float, lam_j: float, a: float):
    """XPBD's dlam = -(C + alpha~ lambda) / A for constraint value ``c``, ``at`` = alpha / h^2,
    ``lam_j`` its lambda so far and A = sum_i w_i |grad_i C|^2 + alpha~ (``a``)."""
    return -(c + at * lam_j) / a


def constraint_kernel(correction, corners: int, alpha_per_constraint: bool, name: str, module: str):
    """The solve kernel ``name`` of a family of ``corners``-vertex constraints (2 or 4) whose XPBD
    step is ``correction`` ((x..., w..., rest, alpha~, lambda) -> (moves, dlam, dx...)), in the
    family's Warp ``module``; ``alpha_per_constraint``: the compliance an array (one per
    constraint) or one float. Arguments: (inv_mass, ids, rest, alpha, inv_h2, start, reset, x, lam,
    delta, slots, slot_base, order, order_count) as Solver launches them. Call once per family (a
    kernel per module)."""
    if corners not in (2, 4):
        raise ValueError(f"constraint_kernel: corners must be 2 or 4, got {corners}")
    FOUR = corners == 4
    alpha_type = wp.array(dtype=float) if alpha_per_constraint else float

    def solve(
        # Model:
        inv_mass: wp.array(dtype=float),
        ids: wp.array2d(dtype=int),
        rest: wp.array(dtype=float),
        alpha: alpha_type,
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
        t = wp.tid()
        j = constraint_at(t, start, order, order_count)
        if j < 0:
            return
        s = slot_base + j  # corner l's slot: s + l C (solver/gather.py; unused by the atomic path)
        nc = ids.shape[0]
        i1 = ids[j, 0]
        i2 = ids[j, 1]
        w1 = inv_mass[i1]
        w2 = inv_mass[i2]
        kinematic = w1 == 0.0 and w2 == 0.0
        if wp.static(FOUR):
            i3 = ids[j, 2]
            i4 = ids[j, 3]
            w3 = inv_mass[i3]
            w4 = inv_mass[i4]
            kinematic = kinematic and w3 == 0.0 and w4 == 0.0
        if kinematic:  # every vertex kinematic: nothing moves (no positions read)
            idle(lam, j, reset, slots, s, nc, corners)
            return
        at = float(0.0)
        if wp.static(alpha_per_constraint):
            at = alpha[j] * inv_h2
        else:
            at = alpha * inv_h2
        lam_j = wp.where(reset != 0, 0.0, lam[j])  # Algorithm 1 line 4: lambda <- 0 each substep
        if wp.static(FOUR):
            moves, dlam, d1, d2, d3, d4 = correction(x[i1], x[i2], x[i3], x[i4], w1, w2, w3, w4, rest[j], at, lam_j)
        else:
            moves, dlam, d1, d2 = correction(x[i1], x[i2], w1, w2, rest[j], at, lam_j)
        if moves == 0:
            idle(lam, j, reset, slots, s, nc, corners)
            return
        lam[j] = lam_j + dlam
        scatter(delta, slots, s, i1, d1)
        scatter(delta, slots, s + nc, i2, d2)
        if wp.static(FOUR):
            scatter(delta, slots, s + 2 * nc, i3, d3)
            scatter(delta, slots, s + 3 * nc, i4, d4)

    solve.__name__ = solve.__qualname__ = name  # (the kernel's key: profiles, tests)
    return wp.kernel(solve, module=module)
