"""W worlds in one model (batching as data the model carries): the checks, the layout, and one
world's model tiled into W, on the host (:func:`tile_model_arrays`) or on the device (:func:`tile_model`:
one world's arrays uploaded once, W copies made by kernels).

:func:`tile_model_arrays` tiles one world's host arrays into the W-world layout in
numpy (every index array shifted world by world, per-vertex arrays skins first) and
:func:`~physhand_mj.solver.model.upload_model` copies the result to the device: at W = 1024 that is
several GB written by one host thread and then sent over the bus. :func:`tile_model` uploads one
world's arrays (a few MB) and writes the same W-world arrays with one kernel launch per array, on
the device that will use them. The layout and every value are :func:`tile_model_arrays`' (tested
array by array in tests/test_batch.py); the host fields (body names, colour ranges, slot bases, the
attachment flags, the bones' rest poses) are computed as there.

The layout (``n`` vertices, ``ns`` skin vertices per world, ``W`` worlds): world w's skin vertex i
is ``w ns + i``, its other vertex i (>= ns) is ``W ns + w (n - ns) + i - ns``; constraint families
and skin faces are world by world (row r of world w is ``w C + r``); world w's bodies are ``w nb``
on; a Jacobi group's slot of corner l of row r (one world: ``base + l C + r``) is ``W base + l W C
+ w C + r``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from physhand_mj.solver.gather import GATHER_LANES
from physhand_mj.solver.model import FAMILIES, JACOBI_GROUPS, upload_model, vertex_world
from physhand_mj.types import Model

wp.set_module_options({"enable_backward": False})


@wp.func
def tiled_vertex(j: int, n: int, ns: int, worlds: int):
    """(world, one-world vertex index) of W-world vertex ``j`` (skins first, world by world)."""
    if j < worlds * ns:
        return j // ns, j % ns
    r = j - worlds * ns
    per = wp.max(n - ns, 1)  # (an asset of skin only: j = W n, the CSR end, lands here)
    return r // per, ns + r % per


@wp.func
def shifted_id(v: int, w: int, n: int, ns: int, worlds: int):
    """World w's index of one-world vertex ``v``."""
    if v < ns:
        return v + w * ns
    return v - ns + worlds * ns + w * (n - ns)


@wp.kernel
def tile_per_vertex(src: wp.array(dtype=Any), n: int, ns: int, worlds: int, out: wp.array(dtype=Any)):
    j = wp.tid()
    w, i = tiled_vertex(j, n, ns, worlds)
    out[j] = src[i]


@wp.kernel
def tile_per_vertex_2d(src: wp.array2d(dtype=float), n: int, ns: int, worlds: int, out: wp.array2d(dtype=float)):
    g, j = wp.tid()
    w, i = tiled_vertex(j, n, ns, worlds)
    out[g, j] = src[g, i]


@wp.kernel
def tile_vertex_bodies(src: wp.array(dtype=int), n: int, ns: int, worlds: int, nb: int, out: wp.array(dtype=int)):
    """A per-vertex body index (-1: none), world w's shifted by w ``nb``."""
    j = wp.tid()
    w, i = tiled_vertex(j, n, ns, worlds)
    b = src[i]
    if b >= 0:
        b = b + w * nb
    out[j] = b


@wp.kernel
def tile_vertex_world(n: int, ns: int, worlds: int, out: wp.array(dtype=int)):
    j = wp.tid()
    w, i = tiled_vertex(j, n, ns, worlds)
    out[j] = w


@wp.kernel
def tile_rows(src: wp.array(dtype=Any), rows: int, out: wp.array(dtype=Any)):
    """Plain copies, world by world (``rows`` entries a world)."""
    j = wp.tid()
    out[j] = src[j % rows]


@wp.kernel
def tile_bodies(src: wp.array(dtype=int), rows: int, nb: int, out: wp.array(dtype=int)):
    """A body index per row (-1: none), world w's shifted by w ``nb``."""
    j = wp.tid()
    b = src[j % rows]
    if b >= 0:
        b = b + (j // rows) * nb
    out[j] = b


@wp.kernel
def tile_ids(src: wp.array2d(dtype=int), n: int, ns: int, worlds: int, out: wp.array2d(dtype=int)):
    """(C, k) vertex ids -> (W C, k), world w's rows naming world w's vertices."""
    r, l = wp.tid()
    c = src.shape[0]
    out[r, l] = shifted_id(src[r % c, l], r // c, n, ns, worlds)


@wp.kernel
def tile_gather_off(off: wp.array(dtype=int), n: int, ns: int, worlds: int, out: wp.array(dtype=int)):
    """A group's CSR offsets over the W-world vertices (launch W n + 1): the skins' rows first, world
    by world, then the other vertices' (each world's rows as one world's)."""
    j = wp.tid()
    s = off[ns]  # one world's skin entries
    r = off[n] - s  # and the rest's
    w, i = tiled_vertex(j, n, ns, worlds)
    if j == worlds * n:  # the end (tiled_vertex: past the last world)
        out[j] = worlds * (s + r)
    elif i < ns:
        out[j] = w * s + off[i]
    else:
        out[j] = worlds * s + w * r + off[i] - s


@wp.kernel
def tile_gather_slot(off: wp.array(dtype=int), first: wp.array(dtype=int), step: wp.array(dtype=int), ns: int,
                     n: int, worlds: int, out: wp.array(dtype=int)):
    """A group's slot ids in the W-world order of :func:`tile_gather_off`: one world's entry e of
    world w is ``first[e] + w step[e]`` (``first``: world 0's slot, ``step``: its family's rows)."""
    k = wp.tid()
    s = off[ns]
    r = off[n] - s
    e = int(0)
    w = int(0)
    if k < worlds * s:
        w = k // s
        e = k % s
    else:
        q = k - worlds * s
        w = q // r
        e = s + q % r
    out[k] = first[e] + w * step[e]


def tile_model(a: dict, worlds: int, cfg):
    """The W-world :class:`~physhand_mj.types.Model` of one world's host arrays ``a``
    (:func:`~physhand_mj.solver.model.model_arrays`), tiled on ``cfg.device``: the Model of
    ``upload_model(tile_model_arrays(a, worlds), cfg)``, array for array, without the W-wide host
    arrays. Same checks (the colored scheme, int32 indices)."""
    W = tile_checks(a, worlds)
    one = upload_model(a, cfg)  # one world, on the device
    dev = wp.get_device(cfg.device)
    n, ns, nb = int(a["n_vertices"]), int(a["n_skin"]), len(a["body_names"])

    def launch(kernel, dim, inputs, out):
        if (np.prod(dim) if isinstance(dim, tuple) else dim) > 0:
            wp.launch(kernel, dim, inputs=inputs, outputs=[out], device=dev)
        return out

    def per_vertex(v):
        return launch(tile_per_vertex, W * n, [v, n, ns, W], wp.empty(W * n, dtype=v.dtype, device=dev))

    def bodies_of_vertices(v):
        return launch(tile_vertex_bodies, W * n, [v, n, ns, W, nb], wp.empty(W * n, dtype=int, device=dev))

    def rows(v):
        c = v.shape[0]
        return launch(tile_rows, W * c, [v, max(c, 1)], wp.empty(W * c, dtype=v.dtype, device=dev))

    def ids(v):
        c, k = v.shape
        return launch(tile_ids, (W * c, k), [v, n, ns, W], wp.empty((W * c, k), dtype=int, device=dev))

    counts = launch(tile_per_vertex_2d, (one.vertex_count.shape[0], W * n), [one.vertex_count, n, ns, W],
                    wp.empty((one.vertex_count.shape[0], W * n), dtype=float, device=dev))
    sizes = {name: np.asarray(a[f"{name}_ids"]).size for name in FAMILIES}
    gather_off, gather_slot, slot_base = [], [], {}
    for group, slots_h, off_d in zip(JACOBI_GROUPS, a["gather_slot"], one.gather_off):
        # per one-world entry: world 0's slot and how far one world moves it
        first, step, bases = slot_shifts(a, group, slots_h, W)
        slot_base.update(bases)
        first_d = wp.array(first.astype(np.int32), dtype=int, device=dev)
        step_d = wp.array(step.astype(np.int32), dtype=int, device=dev)
        gather_off.append(launch(tile_gather_off, W * n + 1, [off_d, n, ns, W],
                                 wp.empty(W * n + 1, dtype=int, device=dev)))
        total = W * len(slots_h)
        gather_slot.append(launch(tile_gather_slot, total, [off_d, first_d, step_d, ns, n, W],
                                  wp.empty(total, dtype=int, device=dev)))
    n_slots = max((sum(W * sizes[name] for name in group) for group in JACOBI_GROUPS), default=0) if gather_off else 0
    return Model(
        device=str(dev), n_vertices=W * n, n_skin=W * ns, n_bodies=W * nb,
        body_names=tuple(f"{b}#{k}" for k in range(W) for b in a["body_names"]),
        rest_x=per_vertex(one.rest_x), inv_mass=per_vertex(one.inv_mass),
        vertex_body=bodies_of_vertices(one.vertex_body), body_local=per_vertex(one.body_local),
        skin_body=launch(tile_bodies, W * ns, [one.skin_body, max(ns, 1), nb], wp.empty(W * ns, dtype=int, device=dev)),
        skin_local=rows(one.skin_local), skin_anchor=rows(one.skin_anchor), vertex_carrier=bodies_of_vertices(one.vertex_carrier),
        edge_ids=ids(one.edge_ids), edge_rest=rows(one.edge_rest), edge_alpha=rows(one.edge_alpha),
        tet_ids=ids(one.tet_ids), tet_rest6v=rows(one.tet_rest6v), tet_alpha=rows(one.tet_alpha),
        edge_is_att=np.tile(np.asarray(a["edge_is_att"]), W),
        dih_ids=ids(one.dih_ids), dih_rest=rows(one.dih_rest), dih_alpha=one.dih_alpha,
        skin_faces=ids(one.skin_faces), guard_tets=ids(one.guard_tets),
        vertex_count=counts, colors={name: ([(0, W * len(a[f"{name}_ids"]))] if sizes[name] else []) for name in sizes},
        body_rest_pos=np.tile(np.asarray(a["body_rest_pos"], float), (W, 1)),
        body_rest_quat=np.tile(np.asarray(a["body_rest_quat"], float), (W, 1)),
        vertex_world=launch(tile_vertex_world, W * n, [n, ns, W], wp.empty(W * n, dtype=int, device=dev)),
        worlds=W, gather_off=gather_off, gather_slot=gather_slot, slot_base=slot_base, n_slots=int(n_slots),
    )


def check_worlds(worlds) -> None:
    if not (isinstance(worlds, (int, np.integer)) and worlds >= 1):
        raise ValueError(f"worlds must be an integer >= 1, got {worlds!r}")


def tile_checks(a: dict, worlds) -> int:
    """Whether one world's model arrays ``a`` tile into ``worlds`` worlds (ValueError naming the
    fix); returns W."""
    check_worlds(worlds)
    if any(len(r) > 1 for r in a["colors"].values()):
        raise ValueError("tile_model_arrays tiles Jacobi arrays only: the colored scheme's colours span "
                         "the whole body (build its batch from replicate_asset)")
    W = int(worlds)
    n = int(a["n_vertices"])
    # (the Jacobi apply launches max(GATHER_LANES) threads a vertex)
    per_world = max([max(GATHER_LANES) * (n + 1)] + [np.asarray(a[f"{f}_ids"]).size for f in ("edge", "tet", "dih")])
    if W * per_world >= 2**31:  # vertex, constraint and slot indices are int32 on the device
        raise ValueError(f"{W} worlds exceed the device's int32 indices ({W} x {per_world} >= 2^31): "
                         f"use at most {(2**31 - 1) // per_world} worlds per batch")
    return W


def slot_shifts(a: dict, group, slots, worlds: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """One world's gather slot ids ``slots`` of Jacobi group ``group`` (solver/gather.py) in the
    W-world layout: world 0's slot of each entry and how far one world moves it (one world's slot
    base + l C + j, corner l of row j of C rows, is W base + l W C + w C + j in world w), and the
    families' W-world slot bases."""
    W = int(worlds)
    slots = np.asarray(slots, np.int64)
    first, step, bases = np.zeros(len(slots), np.int64), np.zeros(len(slots), np.int64), {}
    for name in group:
        base, rows, size = a["slot_base"][name], len(a[f"{name}_ids"]), np.asarray(a[f"{name}_ids"]).size
        f = (slots >= base) & (slots < base + size)
        r = slots[f] - base
        first[f] = W * base + (r // max(rows, 1)) * W * rows + r % max(rows, 1)
        step[f] = rows
        bases[name] = W * base
    return first, step, bases


def tile_model_arrays(a: dict, worlds: int) -> dict:
    """One world's host model arrays (``solver.model.model_arrays``) tiled into ``worlds`` worlds laid
    out as :func:`replicate_asset` lays them out (all skins first, world by world, then each world's
    other vertices; bodies ``name#w``), every constraint family world by world. Each world's arrays
    are the single hand's, so a world's model is the serial model exactly (its nearest-vertex
    choices and rest angles included), and the cost is a copy: no per-world rebuild."""
    W = tile_checks(a, worlds)
    n, ns, nb = int(a["n_vertices"]), int(a["n_skin"]), len(a["body_names"])
    w = np.arange(W)

    def per_vertex(v):  # (n, ...) -> (W n, ...): skins first, then the rest, world by world
        v = np.asarray(v)
        return np.concatenate([np.tile(v[:ns], (W,) + (1,) * (v.ndim - 1)),
                               np.tile(v[ns:], (W,) + (1,) * (v.ndim - 1))])

    def bodies(v):  # (ns,) body indices per skin vertex -> world by world, shifted by w nb (-1 stays)
        v = np.asarray(v)
        t = np.tile(v, W)
        return np.where(t >= 0, t + np.repeat(w * nb, len(v)), -1).astype(v.dtype)

    wv = vertex_world(W * n, W * ns, W)

    def vertex_bodies(v):
        v = np.asarray(v)
        t = per_vertex(v)
        return np.where(t >= 0, t + wv * nb, -1).astype(v.dtype)

    def ids(v):  # (C, k) vertex ids -> (W C, k), world by world (int32, as the model stores them)
        v = np.asarray(v, np.int32)
        skin = v < ns
        first = np.where(skin, v, v - ns + W * ns).astype(np.int32)  # world 0's ids
        step = np.where(skin, ns, n - ns).astype(np.int32)  # how far one world moves each
        out = np.empty((W,) + v.shape, np.int32)
        out[0] = first
        for k in range(1, W):  # one add per world, in place (10 x faster than a broadcast product)
            np.add(out[k - 1], step, out=out[k])
        return out.reshape((-1,) + v.shape[1:])

    def tiled(v):
        v = np.asarray(v)
        return np.tile(v, (W,) + (1,) * (v.ndim - 1))

    # the stored dtypes (solver.model.upload_model) before tiling: each element is cast once, not W times
    a = dict(a, **{k: np.asarray(a[k], np.float32) for k in (
        "rest_x", "inv_mass", "body_local", "skin_local", "skin_anchor", "edge_rest", "edge_alpha", "tet_rest6v", "tet_alpha",
        "dih_rest", "vertex_count")})
    sizes = {name: np.asarray(a[f"{name}_ids"]).size for name in ("edge", "tet", "dih")}
    counts = np.asarray(a["vertex_count"])
    out = dict(
        a, n_vertices=W * n, n_skin=W * ns, worlds=W,
        body_names=tuple(f"{b}#{k}" for k in range(W) for b in a["body_names"]),
        rest_x=per_vertex(a["rest_x"]), inv_mass=per_vertex(a["inv_mass"]),
        vertex_body=vertex_bodies(a["vertex_body"]), body_local=per_vertex(a["body_local"]),
        vertex_carrier=vertex_bodies(a["vertex_carrier"]),
        vertex_world=wv.astype(np.int32),
        skin_body=bodies(a["skin_body"]), skin_local=tiled(a["skin_local"]), skin_anchor=tiled(a["skin_anchor"]),
        edge_ids=ids(a["edge_ids"]), edge_rest=tiled(a["edge_rest"]), edge_alpha=tiled(a["edge_alpha"]),
        edge_is_att=tiled(a["edge_is_att"]),
        tet_ids=ids(a["tet_ids"]), tet_rest6v=tiled(a["tet_rest6v"]), tet_alpha=tiled(a["tet_alpha"]),
        dih_ids=ids(a["dih_ids"]), dih_rest=tiled(a["dih_rest"]),
        skin_faces=ids(a["skin_faces"]), guard_tets=ids(a["guard_tets"]),
        vertex_count=np.concatenate([np.tile(counts[:, :ns], (1, W)), np.tile(counts[:, ns:], (1, W))], axis=1),
        colors={name: ([(0, W * len(a[f"{name}_ids"]))] if sizes[name] else []) for name in sizes},
        body_rest_pos=tiled(a["body_rest_pos"]), body_rest_quat=tiled(a["body_rest_quat"]),
        gather_off=[], gather_slot=[], slot_base={},
    )
    for group, off, slots in zip(JACOBI_GROUPS, a["gather_off"], a["gather_slot"]):  # solver/gather.py
        # one world's slot base + l C + j (corner l of row j, C rows) is W base + l W C + w C + j in world w
        off = np.asarray(off, np.int64)
        first, step, bases = slot_shifts(a, group, slots, W)
        out["slot_base"].update(bases)
        parts = [first[off[lo]:off[hi]] + k * step[off[lo]:off[hi]] for lo, hi in ((0, ns), (ns, n)) for k in range(W)]
        out["gather_slot"].append(np.concatenate(parts).astype(np.int32))
        cnt = per_vertex(np.diff(off))
        toff = np.zeros(W * n + 1, np.int64)
        np.cumsum(cnt, out=toff[1:])
        out["gather_off"].append(toff.astype(np.int32))
    return out
