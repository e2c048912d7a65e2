"""A substep's three Jacobi groups in one launch, a block per world in shared memory (``Config.execution.fused_substep``).

The default Jacobi substep is five launches over the whole batch (edges, apply, tets, apply,
dihedrals; the last apply rides in ``advance``), and on the GPU each writes every constraint's
corrections to global memory (atomics, or the gather's slots) for the apply to read back: about
4 MB written and read per hand and substep, which bounds a batch's frame (docs/scale.md). Here one
block holds one world: it copies the world's positions into shared memory, and for each group
(edges Eq. 2 with the attachments Eq. 4-5, tets Eq. 3, dihedrals Eq. 6) its threads walk the
group's constraints, add the corrections into a shared accumulator of the soft vertices, then
average them into the shared positions (x_i += omega / n_i sum, as ``integrate.apply_jacobi``);
last it writes the soft vertices back. Global memory sees one read of the world's positions and one
write of its soft ones per substep; the constraints' rest data is one world's, shared by every
block (L2-resident).

Where no contact stage comes between a substep's start and its constraints, the launch also makes
the start while it loads the positions (``start`` >= 0: integrate.advance's ``finish_substep`` of
the previous substep and ``start_substep``, per vertex of the world), so a substep is one launch.
A frame without contact runs all its substeps in one such launch (FRAME_LAUNCH), which also ends
the frame (FOLD_END: the last substep's velocities, x_safe and fast vertices, then the inverted
tets counted from shared memory) and keeps the skeleton's positions in shared memory between its
first and last substeps (SKIP_BONES).

With ``Config.self_collision`` (``SELF_IN_KERNEL``) a fourth group follows the three: the skin
self-contact passes over the frame's pair list (solver/fused_self.py), so such a frame stays one
launch too; each block walks its own world's listed and involved vertices (per-world segments of
the frame's lists); their x_prev shares go to global memory, which this substep's start wrote and
the next substep's start reads (barriers between, one block per world).

A group's corrections are summed per vertex with shared-memory atomics (``SUM = "scatter"``, the
default) or by each vertex recomputing its constraints in a fixed order (``SUM = "gather"``:
solver/fused_gather.py).

Same math as the family kernels (``edge_correction``, ``tet_correction``, ``dihedral_correction``
are theirs), the same Jacobi groups in the same order, lambda reset each substep (Algorithm 1 line
4; one iteration) and written back as the family kernels write it (0 + dlam), in a frame's last
substep. The sum: on the CPU Warp runs one lane per block, in constraint order, the atomic path's
order and float sum (bit for bit the five-launch substep); on CUDA a fixed-point int32 sum (ACCUM),
exact, so a batch repeats bit for bit (a float add to shared memory is a compare-and-swap loop on
NVIDIA GPUs). docs/solver.md has each measured step (benchmarks/fused_variants.py).

Shared memory per block: 12 bytes per vertex and per soft vertex, each tile 16-byte aligned, and on
CUDA 4 bytes per thread for Warp's tile allocator (the embedded hand: 10,480 and 6,811 vertices,
207,504 + 2,560 bytes at 640 threads; an H100 or H200 block may hold 227 KB). Warp's CPU runs a tiled kernel's
block as one lane over a fixed 256 KiB arena (a larger request aborts the process), so
:func:`choose` checks the size for the device before building the kernel: a body of more than about
21,800 vertices plus movable vertices per world does not fit the CPU, about 19,000 a Hopper block.
Requires: the Jacobi scheme, one iteration per substep, no per-region sleeping, soft vertices first
in each world (the asset's layout: skin, flesh, skeleton).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from physhand_mj.solver.worlds import shifted_id
from physhand_mj.solver.edge import edge_correction
from physhand_mj.solver.fused_gather import dihedrals_of_vertex, edges_of_vertex, tets_of_vertex, vertex_entries
from physhand_mj.solver.fused_tile import (add2, add2_fixed, add_corners, add_corners_fixed, apply_group,
                                           apply_group_fixed, block_sync, corners2, corners4, fixed_to_float,
                                           keep_multiplier, shared_set, shared_set_int)
from physhand_mj.solver.fused_tile import row4i
from physhand_mj.solver.fused_self import FusedSelf, self_passes
from physhand_mj.solver.integrate import count_guard, fast_vertex, finish_substep, start_substep
from physhand_mj.solver.smooth import dihedral_correction
from physhand_mj.solver.tet import six_volume, tet_correction

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

# Threads per world's block on CUDA (the CPU runs one lane per block). 640 since 2026-11-27: with the
# fixed-point sum the kernel needs more than the 64 registers a thread that 1,024 threads leave (it
# spilled); W = 4,096 on one H100, hand-frames/s: 384 threads 29,820, 512 36,271, 576 37,919, 640
# 39,898-40,557, 704 39,818, 768 38,188, 896 33,437, 1,024 27,037 (benchmarks/fused_variants.py --block;
# docs/benchmarks/fused_variants_cuda_block*_4096.json). The float-sum kernel had been fastest at 1,024.
BLOCK_DIM = 640
CUDA_BLOCK = 640  # the block Config.execution.fused_substep=None takes on CUDA (cuda_auto)
# How a group's corrections are summed per vertex: "scatter" (each constraint once, its corners
# added into the shared accumulator with shared-memory atomics: the CPU's default) or "gather"
# (each movable vertex recomputes its constraints in constraint order: no atomics, repeatable bit
# for bit on CUDA, ~3 x the constraint arithmetic: 0.52 x the gathers' frame on an H100 at W = 1024,
# where "scatter" is 1.53 x; benchmarks/fused_substep.py --sum).
SUM = "scatter"
# The order a block walks a family's constraints in with SUM "scatter": "asset" (the CPU's, bit for bit
# the five-launch substep) or "strided" (stored permuted so that a warp's 32 lanes take constraints
# ~C / 32 apart, 1.0-1.1 lanes per shared address instead of ~9 for edges; the CPU result then differs
# by rounding). 0.90-0.96 x the asset's order on an H100 with the float sum (docs/solver.md).
ORDER = "asset"
# How a group's corrections are added into the shared accumulator with SUM "scatter": "float" (float
# atomics: on NVIDIA GPUs a shared-memory float add is a compare-and-swap loop, ATOMS.CAST.SPIN in
# the H100's SASS, that retries while lanes of a warp meet on one address), "fixed" (each correction
# rounded to a multiple of 2^-FIXED_BITS m and added as int32, a native shared-memory atomic; the
# sum is exact, so a world's result is the same bits in any order: repeatable on CUDA, and the same
# with one lane or many) or "auto" (fixed on CUDA, where it took the solver's batch frame 1.65-1.70 x
# faster, float on the CPU, where it is slower and float keeps the five-launch substep's bits).
# Each correction component is clamped to +-fx_bounds[g] m first (FusedSubstep: 0.99 * 2^31 steps
# over the most corrections any vertex takes in group g), so no vertex's sum can overflow.
ACCUM = "auto"
FIXED_BITS = 28  # the fixed-point sum's step: 2^-28 m = 3.7 nm (float32's step at 0.03-0.06 m)
# Where a constraint's inverse masses come from: "vertex" (inv_mass[i] per corner, a load that waits
# for the constraint's ids) or "row" (stored per constraint, loaded beside its ids).
MASS = "row"
# Whether the constraints' rest data is loaded with load_here (where the code asks for it) instead of
# where the compiler moves it (SUM "scatter").
PIN_LOADS = True
# Whether a constraint's ids and inverse masses come in one vector load each (MASS "row" only; the
# families' arrays are contiguous and aligned, FusedSubstep checks).
VEC_LOADS = True
# Whether a frame with no contact stage runs all its substeps in one launch, the positions kept in
# shared memory from one substep to the next (Solver.step; a contact stage needs them in global memory).
FRAME_LAUNCH = True
# Whether every substep's launch writes the constraints' multipliers (True; a frame launch, in its last
# substep) or only a frame's last substep (False: lambda is reset each substep, so the others' are
# overwritten unread; diagnostics read the last). True is benchmarks/fused_variants.py's old kernel.
LAM_EVERY_SUBSTEP = False
# Whether a frame launch (FRAME_LAUNCH, no contact) also ends the frame: the last substep's velocities,
# x_safe and the fast-vertex count (integrate.advance's last launch), then the inverted-tet count over
# the positions still in shared memory (integrate.count_inverted, which read them from global memory
# at random: 3.8 ms of a 86.5 ms frame at W = 4,096 on an H100). The frame is then 2 launches.
FOLD_END = True
# Whether a frame launch's substeps between the first and the last leave a skeleton vertex's global
# rows alone: its position is its bone's, kept in shared memory; its velocity never changes (w = 0),
# and its x^i and x are read only after the frame (written in the last substep, as before).
SKIP_BONES = True
# Whether Config.self_collision's substep passes run inside the fused kernel, after the three groups
# (solver/fused_self.py: a frame without objects stays one frame launch), or as self_contact.py's
# 2 x self_passes launches a substep after it (False: the frame then takes a launch per substep).
SELF_IN_KERNEL = True
CPU_ARENA = 256 * 1024  # bytes: Warp's CPU tile arena (warp/native/tile.h WP_MAX_CPU_SHARED)
TILE_ALIGN = 16  # bytes: Warp aligns each shared tile to this


_KERNELS: dict = {}
_PASSES: dict = {}
# Each family's XPBD step, its sum by vertex (SUM "gather"), corners, and whether its compliance is per constraint
FAMILIES = {"edges": (edge_correction, edges_of_vertex, 2, True), "tets": (tet_correction, tets_of_vertex, 4, True),
            "dihedrals": (dihedral_correction, dihedrals_of_vertex, 4, False)}


def family_pass(family: str, gather: bool, fixed: bool):
    """The ``wp.func`` that adds one family's corrections (``FAMILIES``) into a world's shared
    accumulator ``ds`` from its shared positions ``xs``: one Jacobi group of :func:`substep_kernel`,
    which every thread of the block calls. ``gather``: SUM "gather" (each movable vertex sums its own
    constraints, in constraint order), else each constraint once, its corners added atomically
    (``fixed``: ACCUM "fixed"). Its int arguments ``vec``, ``pin``, ``row_mass``, ``strided`` are the
    kernel's constants (folded once inlined: the function is forced inline, so the kernel's code is
    the loop written out in place)."""
    key = (family, bool(gather), bool(fixed))
    if key in _PASSES:
        return _PASSES[key]
    correction, of_vertex, corners, alpha_per_constraint = FAMILIES[family]
    FOUR = corners == 4
    GATHER = key[1]
    FIXED = key[2]

    def add_family(xs: Any, ds: Any, n_soft: int, w: int, lane: int, bd: int, inv_mass: wp.array(dtype=float),
                   ids: wp.array2d(dtype=int), rest: wp.array(dtype=float), alpha: Any, masses: wp.array2d(dtype=float),
                   off: wp.array(dtype=int), ent: wp.array(dtype=int), asset_row: wp.array(dtype=int),
                   lam: wp.array(dtype=float), inv_h2: float, keep: int, fx_scale: float, fx_bound: float, vec: int,
                   pin: int, row_mass: int, strided: int):
        if wp.static(GATHER):
            for k in range((n_soft + bd - 1) // bd):
                l = k * bd + lane
                d = wp.vec3(0.0)
                if l < n_soft:
                    d = of_vertex(l, w, off, ent, ids, rest, alpha, inv_mass, xs, inv_h2, lam)
                shared_set(ds, l, d, l < n_soft)
        else:
            nc = ids.shape[0]
            for k in range((nc + bd - 1) // bd):
                j = k * bd + lane
                i1 = int(0)
                i2 = int(0)
                if wp.static(FOUR):
                    i3 = int(0)
                    i4 = int(0)
                moves = int(0)
                d1 = wp.vec3(0.0)
                d2 = wp.vec3(0.0)
                if wp.static(FOUR):
                    d3 = wp.vec3(0.0)
                    d4 = wp.vec3(0.0)
                if j < nc:
                    at = float(0.0)
                    if wp.static(FOUR):
                        i1, i2, i3, i4, w1, w2, w3, w4, r = corners4(ids, masses, inv_mass, rest, j, vec, pin, row_mass)
                    else:
                        i1, i2, w1, w2, r = corners2(ids, masses, inv_mass, rest, j, vec, pin, row_mass)
                    if wp.static(alpha_per_constraint):
                        at = alpha[j] * inv_h2
                    else:
                        at = alpha * inv_h2
                    if wp.static(FOUR):
                        moves, dlam, d1, d2, d3, d4 = correction(xs[i1], xs[i2], xs[i3], xs[i4], w1, w2, w3, w4, r, at,
                                                                 0.0)
                    else:
                        moves, dlam, d1, d2 = correction(xs[i1], xs[i2], w1, w2, r, at, 0.0)
                    # (lambda reset this substep: 0 + dlam; 0 where nothing moves)
                    keep_multiplier(lam, asset_row, w * nc, j, dlam, keep, strided)
                if wp.static(FOUR and FIXED):
                    add_corners_fixed(ds, n_soft, i1, i2, i3, i4, d1, d2, d3, d4, moves, fx_scale, fx_bound)
                if wp.static(FOUR and not FIXED):
                    add_corners(ds, n_soft, i1, i2, i3, i4, d1, d2, d3, d4, moves)
                if wp.static(not FOUR and FIXED):
                    add2_fixed(ds, n_soft, i1, i2, d1, d2, moves, fx_scale, fx_bound)
                if wp.static(not FOUR and not FIXED):
                    add2(ds, n_soft, i1, i2, d1, d2, moves)

    add_family.__name__ = add_family.__qualname__ = f"add_{family}{'_gather' if GATHER else ''}{'_fixed' if FIXED else ''}"
    _PASSES[key] = wp.func(add_family, inline=True)
    return _PASSES[key]


def substep_kernel(n: int, n_soft: int, block_dim: int, gather: bool = False, strided: bool = False,
                   fixed: bool = False, row_mass: bool = False, pin: bool = False, vec: bool = False,
                   self_contact: bool = False, self_features: tuple = (True, True)):
    """The fused kernel for worlds of ``n`` vertices whose first ``n_soft`` are the movable ones,
    launched with ``block_dim`` threads a block (shared-memory tiles need their shapes at compile
    time, and the launch bound caps the registers so that a block fits an SM: one kernel per body
    size and block); ``strided``: the families come permuted (``ORDER``) with each row's asset index
    for its multiplier; ``fixed``: ACCUM "fixed"; ``row_mass``: MASS "row" (both SUM "scatter" only);
    ``self_contact``: the skin self-contact passes as a fourth group (solver/fused_self.py), with
    ``self_features`` (Tuning.self_tet_keep's guard, Tuning.self_friction) compiled in
    (SelfContact.features)."""
    key = (int(n), int(n_soft), int(block_dim), bool(gather), bool(strided) and not gather,
           bool(fixed) and not gather, bool(row_mass) and not gather, bool(pin) and not gather,
           bool(vec) and bool(row_mass) and not gather, bool(self_contact),
           tuple(bool(f) for f in self_features) if self_contact else (False, False))
    if key in _KERNELS:
        return _KERNELS[key]
    N = key[0]
    NS = key[1]
    GATHER = key[3]
    STRIDED = key[4]
    FIXED = key[5]
    ROWM = key[6]
    # (as ints for corners2 / corners4 / keep_multiplier: constants of this kernel, folded once inlined)
    ROWM_I = int(ROWM)
    PIN_I = int(key[7])  # (PIN_LOADS: the rest data loaded at the top of each constraint's iteration)
    VEC_I = int(key[8])  # (VEC_LOADS: a constraint's ids and masses in one vector load each)
    STRIDED_I = int(STRIDED)
    ACC = wp.vec3i if FIXED else wp.vec3
    edges, tets, dihedrals = (family_pass(f, GATHER, FIXED) for f in ("edges", "tets", "dihedrals"))
    SELF = key[9]
    self_group = self_passes(FIXED, *key[10])

    @wp.kernel(module="unique", enable_backward=False, launch_bounds=key[2])
    def solve_substep_shared(
        # Model (one world's, one-world vertex ids):
        inv_mass: wp.array(dtype=float),
        vertex_count: wp.array2d(dtype=float),
        edge_ids: wp.array2d(dtype=int),
        edge_rest: wp.array(dtype=float),
        edge_alpha: wp.array(dtype=float),
        edge_w: wp.array2d(dtype=float),
        tet_ids: wp.array2d(dtype=int),
        tet_rest6v: wp.array(dtype=float),
        tet_alpha: wp.array(dtype=float),
        tet_w: wp.array2d(dtype=float),
        dih_ids: wp.array2d(dtype=int),
        dih_rest: wp.array(dtype=float),
        dih_w: wp.array2d(dtype=float),
        dih_alpha: float,
        # Model (SUM "gather": per group, the movable vertices' entries, vertex_entries; else empty):
        edge_off: wp.array(dtype=int),
        edge_ent: wp.array(dtype=int),
        tet_off: wp.array(dtype=int),
        tet_ent: wp.array(dtype=int),
        dih_off: wp.array(dtype=int),
        dih_ent: wp.array(dtype=int),
        # Model (ORDER "strided": each permuted row's index in the asset's order; else empty):
        edge_row: wp.array(dtype=int),
        tet_row: wp.array(dtype=int),
        dih_row: wp.array(dtype=int),
        # Solver in:
        inv_h2: float,
        relaxation: float,
        ns: int,
        worlds: int,
        keep_lam: int,
        count: int,
        fx_scale: float,
        fx_step: float,
        fx_bounds: wp.vec3,
        # State in/out (every world; lambda rows world by world, w C + j):
        x: wp.array(dtype=wp.vec3),
        lam_edge: wp.array(dtype=float),
        lam_tet: wp.array(dtype=float),
        lam_dih: wp.array(dtype=float),
        # The substep's start (integrate.advance's, folded in when ``start`` >= 0: the previous
        # substep's end where ``finish``, then the prediction; every world's arrays):
        start: int,
        finish: int,
        h: float,
        damp: float,
        gravity: wp.vec3,
        vertex_body: wp.array(dtype=int),
        body_local: wp.array(dtype=wp.vec3),
        body_sub: wp.array2d(dtype=wp.transform),
        v: wp.array(dtype=wp.vec3),
        x_prev: wp.array(dtype=wp.vec3),
        x_safe: wp.array(dtype=wp.vec3),
        guard: wp.array(dtype=int),
        # The frame's end, folded in where ``end`` != 0 (a frame launch: FOLD_END), and the substeps
        # between the first and the last without a skeleton vertex's global rows (``skip_bones``):
        end: int,
        skip_bones: int,
        speed_limit: float,
        vertex_carrier: wp.array(dtype=int),
        guard_tets: wp.array2d(dtype=int),
        # Skin self-contact (SELF: Config.self_collision, solver/fused_self.py's FusedSelf.inputs; else
        # empty): the frame's per-world lists and buffers (self_contact.SelfContact's; a world's skin
        # self_ns long), the Tuning's self_* figures, the x_prev share's accumulator and the fixed-point
        # sum's (scale, step, bound)
        self_wcounts: wp.array2d(dtype=int),
        self_ns: int,
        self_vlist: wp.array(dtype=int),
        self_cand: wp.array2d(dtype=int),
        self_cand_n: wp.array(dtype=int),
        self_nearest: wp.array(dtype=int),
        self_involved: wp.array(dtype=int),
        skin_faces: wp.array2d(dtype=int),
        self_pass_count: int,
        self_thickness: float,
        self_depth: float,
        self_keep: float,
        self_friction: float,
        self_vt_off: wp.array(dtype=int),
        self_vt: wp.array(dtype=int),
        self_tets: wp.array2d(dtype=int),
        self_vol0: wp.array(dtype=float),
        self_hits: wp.array(dtype=int),
        self_dprev: wp.array(dtype=ACC),
        self_active: wp.array(dtype=int),
        self_fx: wp.vec3,
    ):
        w, lane = wp.tid()
        bd = wp.block_dim()
        xs = wp.tile_zeros(shape=N, dtype=wp.vec3, storage="shared")
        ds = wp.tile_zeros(shape=NS, dtype=ACC, storage="shared")
        for sub in range(count):  # count substeps in this launch (a frame without contact stages: all)
            for k in range((N + bd - 1) // bd):  # the world's positions into the zeroed tile
                l = k * bd + lane
                p = wp.vec3(0.0)
                if l < N:
                    g = shifted_id(l, w, N, ns, worlds)
                    if sub == 0:
                        p = x[g]
                    else:
                        p = xs[l]  # (the previous substep's end, kept in shared memory)
                    if (skip_bones != 0 and l >= NS and sub > 0 and sub < count - 1 and wp.isfinite(p[0])
                            and wp.isfinite(p[1]) and wp.isfinite(p[2])):
                        # a skeleton vertex between the first and the last substep: its bone's pose,
                        # as start_substep gives it (finish_substep leaves a finite w = 0 vertex be);
                        # its x^i is read only where x is not finite, its v never changes
                        b = vertex_body[g]
                        if b >= 0:
                            p = wp.transform_point(body_sub[start + sub, b], body_local[g])
                    elif start >= 0:  # the substep's start, as integrate.advance makes it
                        vi = v[g]
                        if finish != 0 or sub > 0:
                            p, vi = finish_substep(g, w, p, vi, inv_mass[l], h, x_prev, guard)
                        p, vi = start_substep(g, w, p, vi, inv_mass[l], start + sub, h, damp, gravity, vertex_body,
                                              body_local, body_sub, x_prev, x_safe, guard)
                        v[g] = vi
                        if l >= NS:
                            x[g] = p  # (a skeleton vertex: the constraints leave it where its bone puts it)
                shared_set(xs, l, p, l < N)
            block_sync()
            keep = int(0)  # (the multipliers: a frame's last substep only)
            if keep_lam != 0 and sub == count - 1:
                keep = 1

            # group 0: edges and attachments (Eq. 2, 4-5)
            edges(xs, ds, NS, w, lane, bd, inv_mass, edge_ids, edge_rest, edge_alpha, edge_w, edge_off, edge_ent,
                  edge_row, lam_edge, inv_h2, keep, fx_scale, fx_bounds[0], VEC_I, PIN_I, ROWM_I, STRIDED_I)
            if wp.static(FIXED):
                apply_group_fixed(xs, ds, NS, vertex_count, 0, relaxation, lane, bd, fx_step)
            else:
                apply_group(xs, ds, NS, vertex_count, 0, relaxation, lane, bd)
            # group 1: tets (Eq. 3)
            tets(xs, ds, NS, w, lane, bd, inv_mass, tet_ids, tet_rest6v, tet_alpha, tet_w, tet_off, tet_ent, tet_row,
                 lam_tet, inv_h2, keep, fx_scale, fx_bounds[1], VEC_I, PIN_I, ROWM_I, STRIDED_I)
            if wp.static(FIXED):
                apply_group_fixed(xs, ds, NS, vertex_count, 1, relaxation, lane, bd, fx_step)
            else:
                apply_group(xs, ds, NS, vertex_count, 1, relaxation, lane, bd)
            # group 2: skin smoothness (Eq. 6)
            dihedrals(xs, ds, NS, w, lane, bd, inv_mass, dih_ids, dih_rest, dih_alpha, dih_w, dih_off, dih_ent,
                      dih_row, lam_dih, inv_h2, keep, fx_scale, fx_bounds[2], VEC_I, PIN_I, ROWM_I, STRIDED_I)
            block_sync()
            for k in range((NS + bd - 1) // bd):  # the last apply, then the soft vertices back
                l = k * bd + lane
                if l < NS:
                    c = vertex_count[2, l]
                    p = xs[l]
                    if c > 0.0:
                        dsum = wp.vec3(0.0)
                        if wp.static(FIXED):
                            dsum = fixed_to_float(ds[l], fx_step)
                        else:
                            dsum = ds[l]
                        p = p + dsum * (relaxation / c)
                    if sub == count - 1 and end == 0 and not wp.static(SELF):
                        x[shifted_id(l, w, N, ns, worlds)] = p
                    else:  # (the next substep, the self-contact group or the frame's end starts from shared
                        shared_set(xs, l, p, True)  # memory, its accumulator zeroed)
                        if wp.static(FIXED):
                            shared_set_int(ds, l, wp.vec3i(0), True)
                        else:
                            shared_set(ds, l, wp.vec3(0.0), True)
            block_sync()
            if wp.static(SELF):  # group 3: skin self-contact (solver/fused_self.py), then the soft vertices back
                self_group(xs, ds, NS, w, lane, bd, inv_mass, skin_faces, self_wcounts, self_ns, self_vlist, self_cand,
                           self_cand_n, self_nearest, self_involved, self_pass_count, self_thickness, self_depth,
                           self_keep, self_friction, self_vt_off, self_vt, self_tets, self_vol0, x_prev, self_hits, self_dprev,
                           self_active, self_fx)
                if sub == count - 1 and end == 0:
                    for k in range((NS + bd - 1) // bd):
                        l = k * bd + lane
                        if l < NS:
                            x[shifted_id(l, w, N, ns, worlds)] = xs[l]
        if end != 0:  # the frame's end: integrate.advance's last launch, per vertex of the world
            for k in range((N + bd - 1) // bd):
                l = k * bd + lane
                p = wp.vec3(0.0)
                if l < N:
                    g = shifted_id(l, w, N, ns, worlds)
                    p, vi = finish_substep(g, w, xs[l], v[g], inv_mass[l], h, x_prev, guard)
                    x_safe[g] = p
                    if speed_limit > 0.0 and inv_mass[l] > 0.0:
                        if fast_vertex(g, vi, h, speed_limit, vertex_carrier, body_sub, x_prev):
                            count_guard(guard, 3, w)
                    x[g] = p
                    v[g] = vi
                shared_set(xs, l, p, l < N)
            block_sync()
            for k in range((guard_tets.shape[0] + bd - 1) // bd):  # integrate.count_inverted, from shared memory
                j = k * bd + lane
                if j < guard_tets.shape[0]:
                    t = row4i(guard_tets, j)
                    if six_volume(xs[t[0]], xs[t[1]], xs[t[2]], xs[t[3]]) <= 0.0:
                        count_guard(guard, 1, w)

    _KERNELS[key] = solve_substep_shared
    return solve_substep_shared


class FusedSubstep:
    """One world's constraint arrays (one-world vertex ids) for :func:`substep_kernel`, taken from
    a (possibly W-world) :class:`~physhand_mj.types.Model` whose families are stored world by world
    (solver/worlds.py's layout: rows [0, C) are world 0's)."""

    def __init__(self, m, device):
        W = int(m.worlds)
        n = m.n_vertices // W
        ns = m.n_skin // W

        def rows(arr, a, b):
            """arr[a:b] on the host (Warp slices no empty range)."""
            return arr[a:b].numpy() if b > a else np.zeros((0, *arr.shape[1:]), dtype=wp.dtype_to_numpy(arr.dtype))

        def world0(arr):
            """World 0's entries of a per-vertex array in one-world order (skins first: world 0's
            skin is [0, ns), its other vertices start at W ns); only those leave the device."""
            return np.concatenate([rows(arr, 0, ns), rows(arr, W * ns, W * ns + n - ns)])

        inv1 = world0(m.inv_mass)
        soft = np.flatnonzero(inv1 > 0.0)
        n_soft = int(soft.max()) + 1 if soft.size else 0
        if soft.size != n_soft:
            raise ValueError("Config.execution.fused_substep needs each world's movable vertices first (skin, flesh, then "
                             "the skeleton); this body interleaves them")

        def to_local(ids):
            ids = np.asarray(ids)
            return np.where(ids < W * ns, ids, ids - W * ns + ns).astype(np.int32)

        def first(arr):
            """World 0's rows of a family's array (rows world by world); only those leave the device."""
            return rows(arr, 0, arr.shape[0] // W)

        self.n, self.ns, self.n_soft, self.worlds = n, ns, n_soft, W
        dev = device
        self.inv_mass = wp.array(inv1.astype(np.float32), dtype=float, device=dev)
        counts = np.stack([world0(m.vertex_count[g]) for g in range(m.vertex_count.shape[0])])
        self.vertex_count = wp.array(counts.astype(np.float32), dtype=float, device=dev)
        self.edge_ids = wp.array(to_local(first(m.edge_ids)).reshape(-1, 2), dtype=int, device=dev)
        self.edge_rest = wp.array(first(m.edge_rest), dtype=float, device=dev)
        self.edge_alpha = wp.array(first(m.edge_alpha), dtype=float, device=dev)
        self.tet_ids = wp.array(to_local(first(m.tet_ids)).reshape(-1, 4), dtype=int, device=dev)
        self.tet_rest6v = wp.array(first(m.tet_rest6v), dtype=float, device=dev)
        self.tet_alpha = wp.array(first(m.tet_alpha), dtype=float, device=dev)
        self.dih_ids = wp.array(to_local(first(m.dih_ids)).reshape(-1, 4), dtype=int, device=dev)
        self.dih_rest = wp.array(first(m.dih_rest), dtype=float, device=dev)
        self.dih_alpha = float(m.dih_alpha)
        self.guard_tets = wp.array(to_local(first(m.guard_tets)).reshape(-1, 4), dtype=int, device=dev)
        # ACCUM and MASS as they were when this body was built (a benchmark builds one of each)
        if ACCUM not in ("float", "fixed", "auto"):
            raise ValueError(f"physhand_mj.solver.fused.ACCUM must be 'float', 'fixed' or 'auto', got {ACCUM!r}")
        if MASS not in ("vertex", "row"):
            raise ValueError(f"physhand_mj.solver.fused.MASS must be 'vertex' or 'row', got {MASS!r}")
        self.fixed = (ACCUM == "fixed" or (ACCUM == "auto" and wp.get_device(dev).is_cuda)) and SUM == "scatter"
        self.row_mass = MASS == "row"
        self.lam_every = bool(LAM_EVERY_SUBSTEP)
        self.pin = bool(PIN_LOADS)
        self.vec = bool(VEC_LOADS) and self.row_mass
        self.frame_launch = bool(FRAME_LAUNCH)
        self.fold_end = bool(FOLD_END) and self.frame_launch
        self.skip_bones = bool(SKIP_BONES)
        self.fx_scale = float(2.0 ** FIXED_BITS)
        # no vertex's sum overflows int32: in group g it takes at most max_i n_i(g) corrections (the
        # group's vertex_count, a count of every id in it), each clamped to the group's bound
        most = [max(float(counts[g].max()) if counts.shape[1] else 1.0, 1.0) for g in range(3)]
        self.fx_bounds = tuple(float(0.99 * 2.0 ** 31 / self.fx_scale / k) for k in most)
        empty2 = wp.empty((0, 0), dtype=float, device=dev)
        if self.row_mass:
            def masses(ids):
                host = ids.numpy()
                return wp.array(inv1[host].astype(np.float32), dtype=float, device=dev) if host.size else empty2
            self.edge_w, self.tet_w, self.dih_w = (masses(a) for a in (self.edge_ids, self.tet_ids, self.dih_ids))
        else:
            self.edge_w = self.tet_w = self.dih_w = empty2
        self._ent = None  # (SUM "gather": built on first use)
        self._strided = None  # (ORDER "strided": the permuted families, built on first use)
        self._none = wp.empty(0, dtype=int, device=dev)
        self._vec = wp.empty(0, dtype=wp.vec3, device=dev)
        self._sub = wp.empty((0, 0), dtype=wp.transform, device=dev)
        self.device = dev
        self.self_contact = None  # (attach_self: the skin self-contact group's inputs, solver/fused_self.py)
        self._no_self = FusedSelf.empty_inputs(dev, self.fixed)

    def attach_self(self, selfc) -> None:
        """Run ``selfc``'s (a :class:`~physhand_mj.solver.self_contact.SelfContact`) substep passes in
        the kernel, after the three groups (solver/fused_self.py); each block its own world's."""
        self.self_contact = FusedSelf(selfc, self.fixed, self.n_soft)

    @property
    def kernel(self):
        """The kernel for this body and the current ``BLOCK_DIM``, ``SUM`` and ``ORDER``."""
        if SUM not in ("scatter", "gather"):
            raise ValueError(f"physhand_mj.solver.fused.SUM must be 'scatter' or 'gather', got {SUM!r}")
        if ORDER not in ("asset", "strided"):
            raise ValueError(f"physhand_mj.solver.fused.ORDER must be 'asset' or 'strided', got {ORDER!r}")
        return substep_kernel(self.n, self.n_soft, BLOCK_DIM, SUM == "gather", self._use_strided(), self.fixed,
                              self.row_mass, self.pin, self._vec_ok(), self.self_contact is not None,
                              self.self_contact.selfc.features() if self.self_contact is not None else (False, False))

    def _vec_ok(self) -> bool:
        """VEC_LOADS where the arrays the kernel reads rows of are contiguous and 16-byte aligned."""
        if not self.vec:
            return False
        fam, _ = self._families()
        rows2d = [a for a in fam if len(a.shape) == 2 and a.shape[0] > 0]
        return all(a.is_contiguous and a.ptr % 16 == 0 for a in rows2d)

    @staticmethod
    def _use_strided() -> bool:
        return ORDER == "strided" and SUM == "scatter"

    @staticmethod
    def strided_rows(count: int, lanes: int = 32) -> np.ndarray:
        """The asset row each permuted row holds: row p takes (p % lanes) * ceil(count / lanes) +
        p // lanes, so the ``lanes`` lanes of a warp walking rows p .. p + lanes - 1 take constraints
        ceil(count / lanes) apart (a permutation of range(count))."""
        per = -(-count // lanes)
        p = np.arange(per * lanes)
        rows = (p % lanes) * per + p // lanes
        return rows[rows < count].astype(np.int32)

    def _families(self) -> tuple:
        """The three families' arrays as the kernel takes them (asset order, or permuted by
        :meth:`strided_rows` with each row's asset index last)."""
        groups = [[self.edge_ids, self.edge_rest, self.edge_alpha, self.edge_w],
                  [self.tet_ids, self.tet_rest6v, self.tet_alpha, self.tet_w], [self.dih_ids, self.dih_rest, self.dih_w]]
        if not self._use_strided():
            return [a for g in groups for a in g], [self._none] * 3
        if self._strided is None:
            out, rows = [], []
            for group in groups:
                r = self.strided_rows(group[0].shape[0])
                rows.append(wp.array(r, dtype=int, device=self.device))
                for arr in group:
                    host = arr.numpy()
                    out.append(wp.array(host[r], dtype=arr.dtype, device=self.device) if host.size else arr)
            self._strided = (out, rows)
        return self._strided

    def _entries(self):
        """Per group, the movable vertices' entries (vertex_entries) on the device, built on first use."""
        if self._ent is None:
            groups = [(self.edge_ids, 2), (self.tet_ids, 4), (self.dih_ids, 4)]
            self._ent = []
            for ids, k in groups:
                host = ids.numpy().reshape(-1, k) if ids.shape[0] else np.zeros((0, k), np.int32)
                off, ent = vertex_entries(host, self.n_soft)
                self._ent += [wp.array(off, dtype=int, device=self.device), wp.array(ent, dtype=int, device=self.device)]
        return self._ent

    def shared_bytes(self, device=None) -> int:
        """Shared memory one world's block takes (bytes): :func:`block_bytes`."""
        return block_bytes(self.n, self.n_soft, device is not None and device.is_cuda)

    def fits(self, device) -> tuple[bool, int]:
        """(whether a world's block fits ``device``, the bytes it may hold a block)."""
        limit = device.max_shared_memory_per_block if device.is_cuda else CPU_ARENA
        return self.shared_bytes(device) <= limit, limit

    def inputs(self, inv_h2: float, relaxation: float, state, start: int = -1, finish: int = 0, h: float = 0.0,
               damp: float = 1.0, gravity=None, model=None, keep_lam: bool = True, count: int = 1, end: bool = False,
               speed_limit: float = 0.0) -> list:
        """The launch's inputs; ``start`` >= 0 folds integrate.advance's start of substep ``start``
        (and with ``finish`` the previous substep's end) into the launch (``model``: the solver's,
        for the bones of every world's vertices); ``keep_lam``: write the multipliers (a frame's last
        substep; the others' are overwritten unread); ``count``: substeps in the launch (from ``start``
        on, each but the first finishing the one before: ``start`` >= 0 where ``count`` > 1); ``end``:
        the launch also ends the frame (its last substep's velocities, x_safe, soft vertices faster
        than ``speed_limit`` m/s counted in guard[3], inverted tets in guard[1]: FOLD_END), so
        integrate.advance's last launch and integrate.count_inverted do not run."""
        if count > 1 and start < 0:
            raise ValueError("FusedSubstep.inputs: several substeps in one launch need start >= 0")
        if end and start < 0:
            raise ValueError("FusedSubstep.inputs: the frame's end in the launch needs start >= 0")
        if start >= 0:
            kin = [model.vertex_body, model.body_local, state.body_sub]
        else:
            kin = [self._none, self._vec, self._sub]
        fam, rows = self._families()
        return [self.inv_mass, self.vertex_count, *fam, self.dih_alpha,
                *(self._entries() if SUM == "gather" else [self._none] * 6), *rows, float(inv_h2),
                float(relaxation), self.ns, self.worlds, int(bool(keep_lam) or self.lam_every), int(count),
                self.fx_scale, 1.0 / self.fx_scale, wp.vec3(*self.fx_bounds), state.x, state.lam_edge, state.lam_tet,
                state.lam_dih,
                int(start), int(finish), float(h), float(damp), gravity if gravity is not None else wp.vec3(0.0),
                *kin, state.v, state.x_prev, state.x_safe, state.guard, int(bool(end)), int(self.skip_bones),
                float(speed_limit), model.vertex_carrier if end else self._none, self.guard_tets,
                *(self.self_contact.inputs() if self.self_contact is not None else self._no_self)]


def block_bytes(n: int, n_soft: int, cuda: bool) -> int:
    """Shared memory one world's block takes (bytes): its two tiles (12 bytes per vertex and per
    movable vertex, each tile ``TILE_ALIGN``-aligned), and on CUDA Warp's allocator slot per thread."""
    tiles = sum(-(-12 * k // TILE_ALIGN) * TILE_ALIGN for k in (n, n_soft))
    return tiles + (4 * BLOCK_DIM if cuda else 0)
