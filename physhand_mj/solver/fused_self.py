"""Skin self-contact's substep passes inside the fused substep kernel (solver/fused.py), a fourth
group after the edges, tets and dihedrals: with ``Config.self_collision`` and the fused substep, a
frame without objects stays one frame launch (plus self_contact.py's once-a-frame query), and with
objects one launch per substep (docs/self_collision.md "How it runs").

The frame's list (self_contact.SelfContact.record_frame: per listed vertex up to SLOTS triangles;
with the passes in the kernel its broadphase also lists each world's listed and involved vertices in
the world's own segment, ``wvlist`` / ``winvolved`` from ``w ns`` on, counted in ``wcounts``) is in
global memory; the world's positions are the block's shared tile. Block w reads only world w's
segment, so batched worlds run as one world does. Each of ``self_passes`` passes: per listed vertex
its nearest listed triangle (self_contact.nearest_listed, equal distances to the lower triangle; the
first pass finds it, the others keep it) and the correction (self_contact.pair_correction), its
moves added into the shared accumulator, the counts per vertex and the x_prev share into global
arrays; a block barrier; per involved vertex the average applied to the shared position and to
x_prev (global, which the next substep's finish reads for the velocity, and which this substep's
start wrote: both in the same launch, barriers between); a barrier. Same math and, on the CPU (one
lane, a world's listed vertices in the order the broadphase listed them, which the launches' list
keeps too), the same float sums in the same order as self_contact's resolve / apply launches: bit
for bit. With the fused kernel's fixed-point sum (ACCUM, CUDA) the moves are added as int32 in steps
of 2^-SELF_FIXED_BITS m (the shared accumulator and the x_prev share), exact, so the result repeats
bit for bit in any order."""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from physhand_mj.solver.fused_tile import block_sync, fixed_to_float, shared_add, shared_add_fixed, shared_set, shared_set_int
from physhand_mj.solver.self_contact import nearest_listed, pair_correction_fn

wp.set_module_options({"enable_backward": False})

# The fixed-point sum's step for the self passes (ACCUM "fixed"): 2^-24 m = 60 nm. A vertex may take
# a correction from every listed vertex in one pass (n_skin at most: no smaller bound holds), so each
# component is clamped to 0.99 x 2^31 steps / n_skin (one world's; 25 mm for the hand's 5,000 skin vertices, 5 x
# the largest correction self_depth + self_thickness allows a vertex); at FIXED_BITS' 2^-28 that
# bound would be 1.6 mm, under the corrections a fist makes (up to 2.3 mm). With Tuning.self_friction mu a
# correction reaches (1 + mu) x that at most: the bound holds to mu ~3.5 (validate() allows up to 2).
SELF_FIXED_BITS = 24

_PASSES: dict = {}


@wp.func
def _fixed(c: float, scale: float, bound: float) -> int:
    """One component in fixed point (as fused_tile.shared_add_fixed: clamped, rounded to even; NaN: 0)."""
    if c != c:
        return 0
    return int(wp.rint(wp.clamp(c, -bound, bound) * scale))


@wp.func
def _prev_add_fixed(dprev: wp.array(dtype=wp.vec3i), i: int, d: wp.vec3, scale: float, bound: float):
    """``dprev[i] += d`` as int32 steps (global, atomic)."""
    wp.atomic_add(dprev, i, wp.vec3i(_fixed(d[0], scale, bound), _fixed(d[1], scale, bound), _fixed(d[2], scale, bound)))


@wp.func
def _prev_add_float(dprev: wp.array(dtype=wp.vec3), i: int, d: wp.vec3, scale: float, bound: float):
    """``dprev[i] += d`` (global, atomic)."""
    wp.atomic_add(dprev, i, d)


def self_passes(fixed: bool, keep: bool = True, friction: bool = True):
    """The ``wp.func`` that runs a substep's self-contact passes over a world's shared positions
    ``xs`` and accumulator ``ds`` (zero on entry, zero on return): every thread of the block calls
    it, the barriers are inside (none where nothing is listed). ``fixed``: ACCUM "fixed" (``ds`` a
    vec3i tile, ``dprev`` a vec3i array); ``keep`` / ``friction``: Tuning.self_tet_keep's guard and
    Tuning.self_friction compiled in (else the ``keep`` / ``mu`` arguments are not read:
    self_contact.pair_correction_fn, SelfContact.features)."""
    key = (bool(fixed), bool(keep), bool(friction))
    if key in _PASSES:
        return _PASSES[key]
    FIXED, KEEP, FRICTION = key
    PREV_ADD = _prev_add_fixed if FIXED else _prev_add_float
    pair_correction = pair_correction_fn(KEEP, FRICTION)

    def run_self_passes(xs: Any, ds: Any, n_soft: int, w: int, lane: int, bd: int, inv_mass: wp.array(dtype=float),
                        faces: wp.array2d(dtype=int), wcounts: wp.array2d(dtype=int), ns: int,
                        vlist: wp.array(dtype=int), cand: wp.array2d(dtype=int), cand_n: wp.array(dtype=int),
                        nearest: wp.array(dtype=int), involved: wp.array(dtype=int), passes: int, thickness: float,
                        depth: float, keep: float, mu: float, vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
                        tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float), x_prev: wp.array(dtype=wp.vec3),
                        hits: wp.array(dtype=int), dprev: Any, active: wp.array(dtype=int), fx: wp.vec3):
        # world w: its skin vertices are w ns on (every world's indices: vlist, cand, faces, hits, x_prev,
        # dprev); its shared tile and one world's inv_mass hold vertex g at g - vo; its listed and involved
        # vertices are vlist's and involved's from vo on (wcounts[w, 0] and [w, 4] long)
        vo = w * ns
        n = wcounts[w, 0]  # (the same for every thread of the block: the barriers below are all its threads' or none)
        ni = wcounts[w, 4]
        if n > 0:
            for k in range(passes):
                for r in range((n + bd - 1) // bd):  # the corrections (self_contact.resolve)
                    i = r * bd + lane
                    if i < n:
                        v = vlist[vo + i]
                        best = int(-1)
                        if k == 0:
                            best = nearest_listed(v, vo, xs, faces, cand, cand_n)
                            nearest[v] = best
                        else:
                            best = nearest[v]
                        if best >= 0:
                            # (the tile's indices: the world's own less vo; FusedSelf.tets: one world's, to 0)
                            moves, a, b, c, dv, da, db, dc, fr, fv, fa, fb, fc = wp.static(pair_correction)(
                                v, best, vo, vo, 0, xs, inv_mass, faces, thickness, depth, keep, mu, vt_off, vt, tets,
                                vol0, x_prev)
                            if moves != 0:
                                la = a - vo
                                lb = b - vo
                                lc = c - vo
                                if fr > 0.0:
                                    wp.static(PREV_ADD)(dprev, v, fr * dv, fx[0], fx[2])
                                    wp.static(PREV_ADD)(dprev, a, fr * da, fx[0], fx[2])
                                    wp.static(PREV_ADD)(dprev, b, fr * db, fx[0], fx[2])
                                    wp.static(PREV_ADD)(dprev, c, fr * dc, fx[0], fx[2])
                                if wp.static(FRICTION):  # (Tuning.self_friction: its moves change the velocity,
                                    if mu > 0.0:  # x_prev keeps them out)
                                        dv = dv + fv
                                        da = da + fa
                                        db = db + fb
                                        dc = dc + fc
                                if wp.static(FIXED):
                                    shared_add_fixed(ds, v - vo, dv, v - vo < n_soft, fx[0], fx[2])
                                    shared_add_fixed(ds, la, da, inv_mass[la] > 0.0, fx[0], fx[2])
                                    shared_add_fixed(ds, lb, db, inv_mass[lb] > 0.0, fx[0], fx[2])
                                    shared_add_fixed(ds, lc, dc, inv_mass[lc] > 0.0, fx[0], fx[2])
                                else:
                                    shared_add(ds, v - vo, dv, v - vo < n_soft)
                                    shared_add(ds, la, da, inv_mass[la] > 0.0)
                                    shared_add(ds, lb, db, inv_mass[lb] > 0.0)
                                    shared_add(ds, lc, dc, inv_mass[lc] > 0.0)
                                wp.atomic_add(hits, v, 1)
                                if inv_mass[la] > 0.0:
                                    wp.atomic_add(hits, a, 1)
                                if inv_mass[lb] > 0.0:
                                    wp.atomic_add(hits, b, 1)
                                if inv_mass[lc] > 0.0:
                                    wp.atomic_add(hits, c, 1)
                                wp.atomic_add(active, 0, 1)
                                wp.atomic_add(wcounts, w, 3, 1)
                block_sync()
                for r in range((ni + bd - 1) // bd):  # the average per involved vertex (self_contact.apply)
                    j = r * bd + lane
                    if j < ni:
                        i = involved[vo + j]
                        li = i - vo
                        h = hits[i]
                        if h > 0 and li < n_soft:
                            if wp.static(FIXED):
                                shared_set(xs, li, xs[li] + fixed_to_float(ds[li], fx[1]) / float(h), True)
                                x_prev[i] = x_prev[i] + fixed_to_float(dprev[i], fx[1]) / float(h)
                                shared_set_int(ds, li, wp.vec3i(0), True)
                                dprev[i] = wp.vec3i(0)
                            else:
                                shared_set(xs, li, xs[li] + ds[li] / float(h), True)
                                x_prev[i] = x_prev[i] + dprev[i] / float(h)
                                shared_set(ds, li, wp.vec3(0.0), True)
                                dprev[i] = wp.vec3(0.0)
                            hits[i] = 0
                block_sync()

    run_self_passes.__name__ = run_self_passes.__qualname__ = (
        f"run_self_passes{'_fixed' if FIXED else ''}{'_keep' if KEEP else ''}{'_friction' if FRICTION else ''}")
    _PASSES[key] = wp.func(run_self_passes, inline=True)
    return _PASSES[key]


class FusedSelf:
    """The fused kernel's self-contact inputs: a :class:`~physhand_mj.solver.self_contact.SelfContact`'s
    frame list and buffers (its hits, and its x_prev share: float, or a vec3i buffer of its own for
    the fixed-point sum)."""

    def __init__(self, selfc, fixed: bool, n_soft: int):
        sc = selfc
        if int(sc.ns1) > int(n_soft):
            raise ValueError("Config.self_collision in the fused substep needs every skin vertex movable")
        self.selfc, self.fixed = sc, bool(fixed)
        self.dprev = wp.zeros(sc.n_skin, dtype=wp.vec3i, device=sc.device) if self.fixed else sc.dprev
        scale = float(2.0 ** SELF_FIXED_BITS)
        self.fx = wp.vec3(scale, 1.0 / scale, float(0.99 * 2.0 ** 31 / scale / max(int(sc.ns1), 1)))
        sc.in_kernel = True  # (its broadphase then lists per world too: the blocks' segments)
        # Tuning.self_tet_keep's tets in one world's indices (the block's tile): world 0's rows, whose
        # vertices past the skin lie after every world's skin (solver/worlds.py's layout)
        t1 = sc.tets[: sc.nt1].numpy().astype(np.int64)
        t1 = np.where(t1 >= sc.n_skin, t1 - sc.n_skin + sc.ns1, t1)
        self.tets = wp.array(t1.astype(np.int32), dtype=int, device=sc.device)

    def inputs(self) -> list:
        """The kernel's self-contact arguments (solver/fused.py's ``self_*``)."""
        sc, cfg = self.selfc, self.selfc.config
        return [sc.wcounts, int(sc.ns1), sc.wvlist, sc.cand, sc.cand_n, sc.nearest, sc.winvolved, sc.faces,
                int(cfg.self_passes), float(cfg.self_thickness), float(cfg.self_depth), float(cfg.self_tet_keep),
                float(cfg.self_friction), sc.vt_off, sc.vt, self.tets, sc.vol0, sc.hits, self.dprev, sc.active, self.fx]

    @staticmethod
    def empty_inputs(device, fixed: bool) -> list:
        """The same arguments for a kernel without self-contact (empty arrays, never read)."""
        i1 = wp.empty(0, dtype=int, device=device)
        i2 = wp.empty((0, 0), dtype=int, device=device)
        f1 = wp.empty(0, dtype=float, device=device)
        acc = wp.empty(0, dtype=wp.vec3i if fixed else wp.vec3, device=device)
        return [i2, 0, i1, i2, i1, i1, i1, i2, 0, 0.0, 0.0, 0.0, 0.0, i1, i1, i2, f1, i1, acc, i1, wp.vec3(0.0)]

