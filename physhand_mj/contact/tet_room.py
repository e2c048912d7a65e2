"""How far a skin vertex may move before one of its tets flattens: the test both the bones' hold
(contact/bones.py: pushes in a gripped world) and self-contact's ``Tuning.self_tet_keep``
(solver/self_contact.py) apply to a move, and the per-vertex tet lists it reads."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


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
    if nt1 == 0:  # (a body without tets, such as a sheet: every vertex has none)
        return (tets, 0, wp.zeros(0, dtype=float, device=d), wp.zeros(ns1 + 1, dtype=int, device=d),
                wp.zeros(0, dtype=int, device=d))
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
