"""Tetrahedron volume constraint, paper Eq. 3."""

from typing import Any

import numpy as np
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


@wp.func
def tet_room(i: int, il: int, dp: wp.vec3, x: Any, vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
          tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float), keep: float, to: int) -> float:
    """The share t in [0, 1] of the move dp of vertex i that keeps each of its tets' signed volume at
    least ``keep`` x its rest volume (the volume is linear in one vertex's position). ``vt_off``,
    ``vt`` and ``vol0`` are one world's: ``il`` is the vertex's index in its world's skin, ``to`` the
    world's first row in ``tets``; ``i`` the vertex as those rows and ``x`` name it (the launches:
    every world's positions, the world's tets; the fused substep: its block's shared tile and one
    world's tets in the world's own indices, ``to`` 0: solver/fused_self.py)."""
    t = float(1.0)
    for k in range(vt_off[il], vt_off[il + 1]):
        e = vt[k]
        ge = e + to
        a = tets[ge, 0]
        b = tets[ge, 1]
        c = tets[ge, 2]
        d = tets[ge, 3]
        v = wp.dot(x[b] - x[a], wp.cross(x[c] - x[a], x[d] - x[a]))
        v1 = v
        if i == a:
            v1 = wp.dot(x[b] - x[a] - dp, wp.cross(x[c] - x[a] - dp, x[d] - x[a] - dp))
        elif i == b:
            v1 = wp.dot(x[b] + dp - x[a], wp.cross(x[c] - x[a], x[d] - x[a]))
        elif i == c:
            v1 = wp.dot(x[b] - x[a], wp.cross(x[c] + dp - x[a], x[d] - x[a]))
        else:
            v1 = wp.dot(x[b] - x[a], wp.cross(x[c] - x[a], x[d] + dp - x[a]))
        s0 = vol0[e]
        lo = keep * s0
        # in the rest volume's sign: v, v1 against lo
        if s0 < 0.0:
            v = -v
            v1 = -v1
            lo = -lo
        if v1 < lo and v1 < v:
            tt = float(0.0)
            if v > lo:
                tt = (v - lo) / (v - v1)
            t = wp.min(t, tt)
    return t


def skin_tet_lists(model, ns1: int) -> tuple:
    """For :func:`tet_room`: (tets (T, 4) int, every world's rows; tets per world; vol0 (T1,) float,
    world 0's rest 6 x volumes; vt_off (ns1 + 1,), vt: CSR of the tets of each of one world's ``ns1``
    skin vertices, world 0's rows). World w's are world 0's shifted by its offsets (the model's tets
    are world by world: solver/worlds.py), so only world 0's rows and rest positions are read."""
    d = model.device
    tets = model.tet_ids
    if not (isinstance(tets, wp.array) and tets.dtype == wp.int32 and tets.ndim == 2):
        tets = wp.array(np.asarray(model.tet_ids.numpy()).reshape(-1, 4).astype(np.int32), dtype=int, device=d)
    nt1 = int(tets.shape[0]) // max(int(getattr(model, "worlds", 1)), 1)
    t0 = np.asarray(tets[:nt1].numpy()).reshape(-1, 4)  # world 0's
    flesh = t0[t0 >= ns1]
    lo = int(flesh.min()) if len(flesh) else ns1
    hi = int(flesh.max()) + 1 if len(flesh) else ns1
    rs = model.rest_x[:ns1].numpy().astype(np.float64)  # world 0's skin, then the span of its other vertices
    rf = model.rest_x[lo:hi].numpy().astype(np.float64) if hi > lo else np.zeros((0, 3))
    A, B, C, D = (np.where((t0[:, k] < ns1)[:, None], rs[np.minimum(t0[:, k], ns1 - 1)],
                           rf[np.clip(t0[:, k] - lo, 0, max(hi - lo - 1, 0))] if hi > lo else 0.0) for k in range(4))
    vol0 = wp.array(np.einsum("ij,ij->i", B - A, np.cross(C - A, D - A)).astype(np.float32), dtype=float, device=d)
    sk = t0 < ns1
    tv = np.repeat(np.arange(len(t0)), 4)[sk.ravel()]
    vv = t0.ravel()[sk.ravel()]
    order = np.argsort(vv, kind="stable")
    cnt = np.bincount(vv, minlength=ns1)
    vt_off = wp.array(np.concatenate([[0], np.cumsum(cnt)]).astype(np.int32), dtype=int, device=d)
    vt = wp.array(tv[order].astype(np.int32), dtype=int, device=d)
    return tets, nt1, vol0, vt_off, vt
