"""The fused substep's block-level helpers (solver/fused.py): adds and stores into a world's shared
tiles without Warp's per-element barrier, the fixed-point sum's add, the block barrier, the Jacobi
average of a group, and one constraint's loads (its ids, inverse masses and rest value) and
multiplier store. Functions of arrays and tiles only; which of their paths a kernel takes is fixed by
the kernel's constant arguments (``vec``, ``pin``, ``row``, ``strided``), folded once inlined."""

from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

# Shared tiles are written through the two native helpers below, which add to one element and leave
# out Warp's barrier: every Warp builtin that writes a tile element (``tile[i] = v``, ``tile[i] += v``,
# ``wp.tile_scatter_add``) ends in ``__syncthreads``, and one barrier per constraint corner kept a
# block's warps in lockstep (measured on an H100, W = 64: a world's substep 0.63 ms on one SM, 10 x
# its arithmetic). A group's adds need no order among themselves (they are atomic where two threads
# may meet), so the block synchronises only where one phase reads what another wrote: after the load,
# after each group's corrections and after each average (``block_sync``). Adding into a zeroed tile,
# or adding a vertex's own correction, rounds as the plain store and update of the family kernels
# do (x + 0 = x; x + d (omega / n) as integrate.apply_jacobi).


@wp.func_native("""if (has) { wp::atomic_add(&t.data.ptr[i], v); }""")
def shared_add(t: Any, i: int, v: wp.vec3, has: bool):
    """``t[i] += v`` where ``has``, atomic (threads may add to one element), no barrier. For this
    module's 1-D shared tiles of vec3 only (``ptr[i]`` is element i there; no bounds check)."""
    ...


@wp.func_native("""if (has) { t.data.ptr[i] = v; }""")
def shared_set(t: Any, i: int, v: wp.vec3, has: bool):
    """``t[i] = v`` where ``has`` (an element only this thread touches in this phase), no barrier."""
    ...


@wp.func_native("""if (has) {
    int* p = (int*)&t.data.ptr[i];
    const float x = wp::clamp(v[0], -bound, bound), y = wp::clamp(v[1], -bound, bound), z = wp::clamp(v[2], -bound, bound);
    wp::atomic_add(p, v[0] == v[0] ? (int)rintf(x * scale) : 0);
    wp::atomic_add(p + 1, v[1] == v[1] ? (int)rintf(y * scale) : 0);
    wp::atomic_add(p + 2, v[2] == v[2] ? (int)rintf(z * scale) : 0);
}
""")
def shared_add_fixed(t: Any, i: int, v: wp.vec3, has: bool, scale: float, bound: float):
    """``t[i] += round(v scale)`` where ``has``, atomic int32 adds into a vec3i tile, no barrier; each
    component first clamped to +-``bound`` m (so no vertex's sum can overflow: FusedSubstep.fx_bounds).
    The clamp is Warp's (fminf/fmaxf on CUDA: two instructions, no branch; a ternary clamp compiled
    to branches, 13 instructions a component). A NaN component adds 0, as a NaN correction must not
    push the constraint's finite corners (the clamp alone would make it -bound); the NaN position it
    came from stays NaN for the guard."""
    ...


@wp.func_native("""if (has) { t.data.ptr[i] = v; }""")
def shared_set_int(t: Any, i: int, v: wp.vec3i, has: bool):
    """``t[i] = v`` for a vec3i tile where ``has``, no barrier."""
    ...


@wp.func
def fixed_to_float(d: wp.vec3i, step: float):
    return wp.vec3(float(d[0]) * step, float(d[1]) * step, float(d[2]) * step)


@wp.func_native("""#if defined(__CUDA_ARCH__)
float r;
asm volatile("{ .reg .u64 g; cvta.to.global.u64 g, %1; ld.global.nc.f32 %0, [g]; }" : "=f"(r)
             : "l"(wp::address(arr, j)));
return r;
#else
return *wp::address(arr, j);
#endif
""")
def load_here(arr: wp.array(dtype=float), j: int) -> float:
    """``arr[j]`` (read-only data), loaded where the call stands. On CUDA the compiler otherwise sinks
    a load that only the non-degenerate branch of a constraint uses (the rest length) into that
    branch, after the positions' loads and the square root, and the warp waits there for L2 (the
    H100's SASS: ~5 % of the fused kernel's stall samples on one instruction); a volatile load stays
    at the top of the iteration, beside the ids' loads, and arrives with them."""
    ...


class _Renamed:
    """``@_Renamed.func_native(snippet, name)``: ``wp.func_native(snippet)`` for a function a factory
    defines, registered as ``name``. Warp keys a function by its qualified name, the same for every
    function one factory defines, and its code generator takes a function for native (its return
    type from the annotation) by a decorator called ``func_native`` in the source."""

    @staticmethod
    def func_native(snippet: str, name: str):
        def register(f):
            f.__name__ = f.__qualname__ = name
            return wp.func_native(snippet)(f)
        return register


def row_load(width: int, scalar: type, vec: type):
    """The native ``wp.func`` ``row{width}{i|f}(arr, j) -> vec``: row ``j`` of a contiguous (n, ``width``)
    int32 or float32 array, aligned to its row (4 x ``width`` bytes): one 64- or 128-bit load on CUDA
    (Warp's vectors are 4-byte aligned, so ``arr[j, k]`` is ``width`` loads and address computations)."""
    c = "int" if scalar is int else "float"
    name = f"row{width}{c[0]}"
    snippet = f"""#if defined(__CUDA_ARCH__)
const {c}{width} q = __ldg(reinterpret_cast<const {c}{width}*>(wp::address(arr, j, 0)));
return wp::vec_t<{width}, {c}>({", ".join("q." + "xyzw"[k] for k in range(width))});
#else
const {c}* p = wp::address(arr, j, 0);
return wp::vec_t<{width}, {c}>({", ".join(f"p[{k}]" for k in range(width))});
#endif
"""

    @_Renamed.func_native(snippet, name)
    def row(arr: wp.array2d(dtype=scalar), j: int) -> vec:
        ...

    return row


row4i = row_load(4, int, wp.vec4i)
row4f = row_load(4, float, wp.vec4)
row2i = row_load(2, int, wp.vec2i)
row2f = row_load(2, float, wp.vec2)


@wp.func_native("""WP_TILE_SYNC();""")
def block_sync():
    """The block's barrier (every thread of the block calls it)."""
    ...


@wp.func
def apply_group(xs: Any, ds: Any, ns: int, vertex_count: wp.array2d(dtype=float), group: int, relaxation: float,
                lane: int, bd: int):
    """A group's Jacobi average in shared memory (integrate.apply_jacobi: x_i += omega / n_i sum),
    its accumulator zeroed for the next group; every thread of the block calls it (a barrier before,
    for the group's corrections, and after, for the positions)."""
    block_sync()
    for k in range((ns + bd - 1) // bd):
        l = k * bd + lane
        if l < ns:
            c = vertex_count[group, l]
            if c > 0.0:
                shared_set(xs, l, xs[l] + ds[l] * (relaxation / c), True)
            shared_set(ds, l, wp.vec3(0.0), True)
    block_sync()


@wp.func
def apply_group_fixed(xs: Any, ds: Any, ns: int, vertex_count: wp.array2d(dtype=float), group: int,
                      relaxation: float, lane: int, bd: int, step: float):
    """apply_group for ACCUM "fixed" (a vec3i accumulator in steps of ``step`` m)."""
    block_sync()
    for k in range((ns + bd - 1) // bd):
        l = k * bd + lane
        if l < ns:
            c = vertex_count[group, l]
            if c > 0.0:
                shared_set(xs, l, xs[l] + fixed_to_float(ds[l], step) * (relaxation / c), True)
            shared_set_int(ds, l, wp.vec3i(0), True)
    block_sync()


@wp.func
def add2(ds: Any, ns: int, i1: int, i2: int, d1: wp.vec3, d2: wp.vec3, moves: int):
    """A 2-vertex constraint's corrections into the shared accumulator (movable vertices only)."""
    shared_add(ds, i1, d1, moves != 0 and i1 < ns)
    shared_add(ds, i2, d2, moves != 0 and i2 < ns)


@wp.func
def add_corners(ds: Any, ns: int, i1: int, i2: int, i3: int, i4: int, d1: wp.vec3, d2: wp.vec3, d3: wp.vec3,
                d4: wp.vec3, moves: int):
    """A 4-vertex constraint's corrections into the shared accumulator (movable vertices only)."""
    add2(ds, ns, i1, i2, d1, d2, moves)
    add2(ds, ns, i3, i4, d3, d4, moves)


@wp.func
def add2_fixed(ds: Any, ns: int, i1: int, i2: int, d1: wp.vec3, d2: wp.vec3, moves: int, scale: float,
               bound: float):
    """add2 into ACCUM "fixed"'s vec3i accumulator."""
    shared_add_fixed(ds, i1, d1, moves != 0 and i1 < ns, scale, bound)
    shared_add_fixed(ds, i2, d2, moves != 0 and i2 < ns, scale, bound)


@wp.func
def add_corners_fixed(ds: Any, ns: int, i1: int, i2: int, i3: int, i4: int, d1: wp.vec3, d2: wp.vec3,
                      d3: wp.vec3, d4: wp.vec3, moves: int, scale: float, bound: float):
    """add_corners into ACCUM "fixed"'s vec3i accumulator."""
    add2_fixed(ds, ns, i1, i2, d1, d2, moves, scale, bound)
    add2_fixed(ds, ns, i3, i4, d3, d4, moves, scale, bound)


def corner_loads(corners: int):
    """The ``wp.func`` ``corners{2|4}(ids, rows, inv_mass, rest, j, vec, pin, row)``: constraint ``j``
    of a ``corners``-vertex family (2: edges; 4: tets, dihedrals), (i1.., w1.., rest). ``vec``: ids and
    masses in one vector load each (``row`` too; :func:`row_load`); ``pin``: the rest value loaded
    here (:func:`load_here`); ``row``: the masses from the family's per-constraint rows, else per
    vertex (``inv_mass``)."""
    FOUR = corners == 4
    ROW_IDS = row4i if FOUR else row2i
    ROW_MASSES = row4f if FOUR else row2f

    def loads(ids: wp.array2d(dtype=int), rows: wp.array2d(dtype=float), inv_mass: wp.array(dtype=float),
              rest: wp.array(dtype=float), j: int, vec: int, pin: int, row: int):
        i1 = int(0)
        i2 = int(0)
        if wp.static(FOUR):
            i3 = int(0)
            i4 = int(0)
        if vec != 0:
            e = wp.static(ROW_IDS)(ids, j)
            i1 = e[0]
            i2 = e[1]
            if wp.static(FOUR):
                i3 = e[2]
                i4 = e[3]
        else:
            i1 = ids[j, 0]
            i2 = ids[j, 1]
            if wp.static(FOUR):
                i3 = ids[j, 2]
                i4 = ids[j, 3]
        r = float(0.0)
        if pin != 0:
            r = load_here(rest, j)
        else:
            r = rest[j]
        w1 = float(0.0)
        w2 = float(0.0)
        if wp.static(FOUR):
            w3 = float(0.0)
            w4 = float(0.0)
        if vec != 0:
            q = wp.static(ROW_MASSES)(rows, j)
            w1 = q[0]
            w2 = q[1]
            if wp.static(FOUR):
                w3 = q[2]
                w4 = q[3]
        elif row != 0:
            w1 = rows[j, 0]
            w2 = rows[j, 1]
            if wp.static(FOUR):
                w3 = rows[j, 2]
                w4 = rows[j, 3]
        else:
            w1 = inv_mass[i1]
            w2 = inv_mass[i2]
            if wp.static(FOUR):
                w3 = inv_mass[i3]
                w4 = inv_mass[i4]
        if wp.static(FOUR):
            return i1, i2, i3, i4, w1, w2, w3, w4, r
        else:
            return i1, i2, w1, w2, r

    loads.__name__ = loads.__qualname__ = f"corners{corners}"
    return wp.func(loads)


corners2 = corner_loads(2)
corners4 = corner_loads(4)


@wp.func
def keep_multiplier(lam: wp.array(dtype=float), rows: wp.array(dtype=int), base: int, j: int, dlam: float, keep: int,
                    strided: int):
    """``lam[base + row] = dlam`` where ``keep``: the multiplier of constraint ``j``, in its asset row
    (``rows[j]`` where the family is stored permuted, ORDER "strided")."""
    if keep != 0:
        r = j
        if strided != 0:
            r = rows[j]
        lam[base + r] = dlam
