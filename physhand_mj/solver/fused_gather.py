"""The fused substep's groups summed by vertex (``physhand_mj.solver.fused.SUM = "gather"``).

Each movable vertex recomputes the constraints that touch it, in constraint order, and adds its own
corner's correction (solver/gather.py's order: on the CPU the atomic path's sum bit for bit; on CUDA
a fixed order, so runs repeat bit for bit), with no atomics and one barrier per pass over the
vertices; the price is recomputing each constraint once per movable corner (a tet up to 4 times).
A vertex's entries (:func:`vertex_entries`) code (j K + corner) 2 + writer, writer 1 on the
constraint's first movable corner, which also stores its lambda.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from physhand_mj.solver.edge import edge_correction
from physhand_mj.solver.smooth import dihedral_correction
from physhand_mj.solver.tet import tet_correction

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


def constraints_of_vertex(correction, corners: int, alpha_per_constraint: bool, name: str):
    """The ``wp.func`` ``name`` summing movable vertex ``l``'s corrections from a family of
    ``corners``-vertex constraints (2 or 4) whose XPBD step is ``correction`` (edge.edge_correction,
    tet.tet_correction, smooth.dihedral_correction), in constraint order, storing lambda where the
    entry is the writer; ``alpha_per_constraint``: the compliance an array (one per constraint) or
    one float."""
    FOUR = corners == 4

    def of_vertex(l: int, w: int, off: wp.array(dtype=int), ent: wp.array(dtype=int), ids: wp.array2d(dtype=int),
                  rest: wp.array(dtype=float), alpha: Any, inv_mass: wp.array(dtype=float), xs: Any, inv_h2: float,
                  lam: wp.array(dtype=float)):
        d = wp.vec3(0.0)
        nc = ids.shape[0]
        for e in range(off[l], off[l + 1]):
            code = ent[e]
            jc = code // 2
            j = jc // corners
            c = jc % corners
            at = float(0.0)
            if wp.static(alpha_per_constraint):
                at = alpha[j] * inv_h2
            else:
                at = alpha * inv_h2
            i1 = ids[j, 0]
            i2 = ids[j, 1]
            if wp.static(FOUR):
                i3 = ids[j, 2]
                i4 = ids[j, 3]
                moves, dlam, d1, d2, d3, d4 = correction(xs[i1], xs[i2], xs[i3], xs[i4], inv_mass[i1], inv_mass[i2],
                                                         inv_mass[i3], inv_mass[i4], rest[j], at, 0.0)
            else:
                moves, dlam, d1, d2 = correction(xs[i1], xs[i2], inv_mass[i1], inv_mass[i2], rest[j], at, 0.0)
            if code % 2 == 1:
                lam[w * nc + j] = dlam
            if moves != 0:
                if wp.static(FOUR):
                    d = d + corner_of(c, d1, d2, d3, d4)
                else:
                    d = d + wp.where(c == 0, d1, d2)
        return d

    of_vertex.__name__ = of_vertex.__qualname__ = name
    return wp.func(of_vertex)


@wp.func
def corner_of(c: int, d1: wp.vec3, d2: wp.vec3, d3: wp.vec3, d4: wp.vec3):
    if c == 0:
        return d1
    if c == 1:
        return d2
    if c == 2:
        return d3
    return d4


edges_of_vertex = constraints_of_vertex(edge_correction, 2, True, "edges_of_vertex")
tets_of_vertex = constraints_of_vertex(tet_correction, 4, True, "tets_of_vertex")
dihedrals_of_vertex = constraints_of_vertex(dihedral_correction, 4, False, "dihedrals_of_vertex")


def vertex_entries(ids: np.ndarray, n_soft: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR of one family (C, K) one-world ids over the movable vertices [0, n_soft): (off (n_soft + 1,),
    ent) with each vertex's entries in constraint order, coded (j K + corner) 2 + writer."""
    ids = np.asarray(ids).reshape(len(ids), -1)
    c, k = ids.shape
    movable = ids < n_soft
    first = np.argmax(movable, axis=1)  # each constraint's first movable corner (its lambda's writer)
    code = (np.arange(c)[:, None] * k + np.arange(k)[None, :]) * 2 + (np.arange(k)[None, :] == first[:, None])
    vert, code = ids[movable], code[movable]
    order = np.lexsort((code, vert))
    off = np.zeros(n_soft + 1, np.int64)
    np.cumsum(np.bincount(vert, minlength=n_soft), out=off[1:])
    if off[-1] >= 2**31 or code.size and code.max() >= 2**31:
        raise ValueError("fused substep: a family too large for int32 entry codes")
    return off.astype(np.int32), code[order].astype(np.int32)
