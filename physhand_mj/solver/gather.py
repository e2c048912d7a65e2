"""Jacobi corrections gathered per vertex instead of added with atomics (``Config.execution.jacobi_gather``).

A constraint of k vertices writes its k position corrections into its own k *slots* of a buffer
(``State.corr``: slot ``base + l C + j`` for corner l of constraint j of a family of C
constraints, ``base`` the family's offset within its Jacobi group), with plain stores. Corner-major
slots make the stores of neighbouring threads neighbours in memory (one family's corner l is one
contiguous block): constraint-major slots (``base + j k + l``) left a warp's stores 48 bytes apart,
and the partial sector writes cost nearly what the atomics did. The group's apply (``advance`` /
``apply_jacobi``) then sums, for every movable vertex, the slots that name it: a CSR list per group
(``Model.gather_off`` / ``gather_slot``), each vertex's slots in constraint order (j, then l: the
order in which the atomics add them on the CPU).

Why: the atomic version adds 3 floats per vertex of every constraint into ``delta`` with float
atomics, in an unspecified order on a GPU (two CUDA runs differ by ~0.4 um after a closing, H100),
and on a GPU filled with batched worlds those atomics are most of the constraint kernels' time
(H100, W = 256: ``solve_tets`` 1.8 ms a launch with them, 0.28 ms with its writes left out). The
gather sums the same values in a fixed order: CUDA runs repeat bit for bit, a batch's frame takes
0.6 x the time (with the tets in Morton order, solver/model.py; benchmarks/batch_throughput.py
--profile, docs/scale.md), and on the CPU it is the atomic version bit for bit (Warp's CPU launch
runs threads in order, so the atomics added the corrections of each vertex in this order too,
starting from a zeroed ``delta``, as the gather starts from zero). One hand alone gains nothing
(0.45 against 0.42 ms a frame on an H100: launch-bound), and the CPU pays 10-20 %, so by default
only batches of several worlds on CUDA gather (``Config.execution.jacobi_gather``).

Kinematic (skeleton) vertices get no slots in the lists: their corrections are zero (w = 0) and
nothing applies them.
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.func
def scatter(delta: wp.array(dtype=wp.vec3), slots: wp.array(dtype=wp.vec3), slot: int, i: int, dx: wp.vec3):
    """Vertex ``i``'s correction ``dx``: into its own slot when the solver gathers (``slots`` not
    empty), else added to ``delta[i]`` (atomically)."""
    if slots.shape[0] > 0:
        slots[slot] = dx
    else:
        wp.atomic_add(delta, i, dx)


@wp.func
def constraint_at(t: int, start: int, order: wp.array(dtype=int), order_count: wp.array(dtype=int)):
    """Thread ``t``'s constraint: ``start + t``, or with a compacted list (regions.py: the awake
    regions' constraints, ``order_count`` long) ``order[start + t]``, and -1 past its count."""
    if order.shape[0] > 0:
        if t >= order_count[0]:
            return -1
        return order[start + t]
    return start + t


@wp.func
def idle(lam: wp.array(dtype=float), j: int, reset: int, slots: wp.array(dtype=wp.vec3), s: int, nc: int,
         corners: int):
    """Constraint ``j`` moves nothing this iteration (every vertex kinematic, or a degenerate
    gradient): its lambda reset where Algorithm 1 resets it, its ``corners`` slots zeroed on the
    gather path (a slot left as it was would be summed again)."""
    if reset != 0:
        lam[j] = 0.0
    if slots.shape[0] > 0:
        for k in range(corners):
            slots[s + k * nc] = wp.vec3(0.0)


# lanes per vertex of a group's apply on CUDA (integrate.apply_jacobi; JACOBI_GROUPS' order: edges,
# tets, dihedrals): lane l sums entries l, l + L, ... of the vertex's row, then the L partial sums
# are added by shuffles. More loads in flight than a thread walking ~8-14 scattered slots alone
# (H100, 256 worlds, one launch, benchmarks/gather_layouts.py: the edge group 0.28 -> 0.23 ms with 2
# lanes, the tet group 0.77 -> 0.41 ms with 4). The CPU keeps one lane: there a vertex sums in the
# atomics' order (bit for bit); on CUDA the sum's order is fixed too (runs repeat bit for bit).
GATHER_LANES = (2, 4, 1)
assert all(k in (1, 2, 4, 8, 16, 32) for k in GATHER_LANES)  # lanes_sum: a power of two within a warp


@wp.func_native("""
#if defined(__CUDA_ARCH__)
if (lanes > 1) {
    // the L lanes of a vertex: neighbours in one warp, all present (the launch is L x the vertices)
    int first = (threadIdx.x & 31) & ~(lanes - 1);
    unsigned m = ((1u << lanes) - 1u) << first;
    for (int o = lanes / 2; o > 0; o >>= 1) {
        v.c[0] += __shfl_xor_sync(m, v.c[0], o, lanes);
        v.c[1] += __shfl_xor_sync(m, v.c[1], o, lanes);
        v.c[2] += __shfl_xor_sync(m, v.c[2], o, lanes);
    }
}
#endif
return v;
""")
def lanes_sum(v: wp.vec3, lanes: int) -> wp.vec3: ...


# lanes_sum: the sum of ``v`` over the ``lanes`` (a power of two, at most 32) neighbouring lanes of
# a vertex, in every one of them (a shuffle tree); the CPU runs one lane (``lanes`` 1): ``v``.


@wp.func
def gathered_lanes(off: wp.array(dtype=int), slot_ids: wp.array(dtype=int), slots: wp.array(dtype=wp.vec3), i: int,
                   lane: int, lanes: int):
    """:func:`gathered`'s sum by ``lanes`` lanes (lane ``lane`` takes every ``lanes``-th entry of
    vertex ``i``'s row); every lane returns the whole sum. One lane: the row in order."""
    d = wp.vec3(0.0)
    for k in range(off[i] + lane, off[i + 1], lanes):
        d = d + slots[slot_ids[k]]
    return lanes_sum(d, lanes)


@wp.func
def gathered(delta: wp.array(dtype=wp.vec3), off: wp.array(dtype=int), slot_ids: wp.array(dtype=int),
             slots: wp.array(dtype=wp.vec3), i: int):
    """Vertex ``i``'s slots (its CSR row ``off[i]:off[i+1]`` of ``slot_ids``) summed in order from
    zero, or ``delta[i]`` when the lists are empty (the atomic path; the atomics also start from a
    zeroed ``delta``, and nothing writes ``delta`` when the solver gathers)."""
    if off.shape[0] == 0:
        return delta[i]
    d = wp.vec3(0.0)
    for k in range(off[i], off[i + 1]):
        d = d + slots[slot_ids[k]]
    return d


def gather_lists(families: list, movable: np.ndarray, orders: list | None = None) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """CSR lists of one Jacobi group: ``families`` its families' (C, k) vertex id arrays in
    projection order. Returns ``off`` (N + 1,), ``slot_ids`` (the slots of movable vertices, per
    vertex in constraint order: family, row, corner) and each family's slot base. The slot of
    corner l of row j of a family is ``base + l C + j`` (corner-major). ``orders``: per family
    None, or the row's index in the order the sum should follow (a family stored permuted: each
    vertex then sums in that order, e.g. the asset's, whatever the storage order)."""
    n = len(movable)
    bases, verts, slots, ranks, base = [], [], [], [], 0
    for f, ids in enumerate(families):
        ids = np.asarray(ids)
        c, k = ids.shape if ids.ndim == 2 else (0, 0)
        rank = np.arange(c) if orders is None or orders[f] is None else np.asarray(orders[f])
        bases.append(base)
        verts.append(ids.ravel())
        slots.append(base + (np.arange(k)[None, :] * c + np.arange(c)[:, None]).ravel())
        ranks.append((base + rank[:, None] * k + np.arange(k)[None, :]).ravel())  # (family, row, corner)
        base += ids.size
    cat = lambda v: np.concatenate(v) if v else np.zeros(0, np.int64)  # noqa: E731
    vert, slot, rank = cat(verts), cat(slots), cat(ranks)
    use = movable[vert]
    vert, slot, rank = vert[use], slot[use], rank[use]
    order = np.lexsort((rank, vert))  # per vertex, in the sum's order
    off = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(vert, minlength=n), out=off[1:])
    return off.astype(np.int32), slot[order].astype(np.int32), bases
