"""Penetration measured both ways (paper section 4.2-4.3; DESIGN "Metrics").

1. Skin samples inside objects, as the paper measures: every skin triangle is sampled on the
   order-5 barycentric lattice (21 points: vertices, edge points, interior); a sample with phi < 0
   against any object is a penetration. The kernel adds into one row of ``out``: [penetrating
   samples, sum of their depths |phi| (m), max depth (m)]. Triangles with phi(centroid) >
   circumradius for every geom are skipped: SDFs are 1-Lipschitz, so none of their samples can
   penetrate; in a triangle that is kept, the three corners are asked first, and a sample with
   phi(corner) - |sample - corner| > SKIP_MARGIN for a corner is outside by the same bound and not
   asked (the same rows: only samples that cannot be inside are left out). Checks use a denser
   lattice (``order`` 9 or more: samples no strategy queries).
2. Object surface points inside the closed skin (corners, points along sharp edges, an even
   surface sampling; contact/inside.py), columns 3-5 of the same row: what a tip or an edge pokes
   through a triangle between skin samples.

:func:`summarize` names them ``penetration_*`` (1) and ``object_in_skin_*`` (2).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import triangle_bound, world_geoms
from physhand_mj.contact.query import world_phi
from physhand_mj.contact.sdf import FAR, MESH, GeomSet, geom_sdf

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

ORDER = 5  # 21 samples per triangle
# m: a lattice sample whose bound from a corner's phi (phi(corner) - |sample - corner|, SDFs being
# 1-Lipschitz) exceeds this is outside and not asked (<= 0 turns it off: every sample asked). 1 um
# keeps float rounding out of it: a sample skipped is at least ~1 um outside. On the CPU (2026-11-27,
# two held worlds each) the bowl's kept triangles then ask 36 % of their samples, the apple's 55 %.
SKIP_MARGIN = 1.0e-6


@wp.func
def phi_below(p: wp.vec3, geoms: GeomSet, base: int, n: int, obj_filter: int, cap: float):
    """A lower bound of phi (m) at world point p against a world's n geoms [base, base + n)
    (``obj_filter`` >= 0: that object's only) that is phi itself wherever phi <= ``cap``: a geom whose bounding sphere
    lies farther than ``cap`` from p adds |q| - R (<= its phi) instead of its SDF, so a mesh far
    from p costs no query (and, as in world_phi, a geom farther than the best so far none)."""
    best = float(FAR)
    for j in range(n):
        g = base + j
        if obj_filter >= 0 and geoms.obj[g] != obj_filter:
            continue
        q = wp.transform_point(geoms.inv_pose[g], p)
        far = wp.length(q) - geoms.radius[g]
        if far > cap or far >= best:
            best = wp.min(best, far)
        else:
            best = wp.min(best, geom_sdf(geoms.gtype[g], q, geoms.size[g], geoms.mesh[g]))
    return best


@wp.func
def world_of(t: int, tris_per_world: int, k: int, geom_count: wp.array(dtype=int)):
    """(world, geoms in use) of skin triangle ``t``: world w's geoms are [w k, w k + k)."""
    w = t // tris_per_world
    return w, wp.max(wp.min(k, geom_count[0] - w * k), 0)


def penetration_source(cull: bool):
    """The Python function of a skin-measure kernel, for ``wp.kernel``: :func:`penetration_samples`
    or, ``cull``, :func:`penetration_cull` (its bound alone); both take the same arguments."""
    CULL = bool(cull)

    def kernel(
        faces: wp.array2d(dtype=int),
        x: wp.array(dtype=wp.vec3),
        geoms: GeomSet,
        geoms_per_world: int,
        obj_filter: int,
        row: int,
        order: int,
        tris_per_world: int,
        rows_per_world: int,
        listed: wp.array(dtype=int),
        listed_count: wp.array(dtype=int),
        skip_margin: float,
        out: wp.array2d(dtype=float),
    ):
        t = wp.tid()
        culled = False
        if wp.static(not CULL):
            culled = listed_count.shape[0] > 0
            if culled:
                if t >= listed_count[0]:
                    return
                t = listed[t]
        a = x[faces[t, 0]]
        b = x[faces[t, 1]]
        c = x[faces[t, 2]]
        m, r = triangle_bound(a, b, c)
        w, n = world_of(t, tris_per_world, geoms_per_world, geoms.count)
        base = w * geoms_per_world
        # (exact: the bound is phi itself wherever phi <= r)
        if obj_filter < 0 and not culled and phi_below(m, geoms, base, n, -1, r) > r:
            return
        if wp.static(CULL):
            listed[wp.atomic_add(listed_count, 0, 1)] = t
            return
        # the corners as the lattice makes them (a vertex that is not finite makes every sample NaN, as
        # before)
        pa = a * 1.0 + b * 0.0 + c * 0.0
        pb = a * 0.0 + b * 1.0 + c * 0.0
        pc = a * 0.0 + b * 0.0 + c * 1.0
        da = phi_below(pa, geoms, base, n, obj_filter, 0.0)
        db = phi_below(pb, geoms, base, n, obj_filter, 0.0)
        dc = phi_below(pc, geoms, base, n, obj_filter, 0.0)
        # the corner bound only where phi is 1-Lipschitz: not for a mesh signed by its winding number (an
        # open mesh closed over its holes, where the sign flips away from any face), and a corner with no
        # mesh within its query range (FAR) bounds nothing
        bound = skip_margin > 0.0
        for j in range(n):
            g = base + j
            if geoms.gtype[g] == MESH and geoms.size[g][1] > 0.5 and geoms.size[g][1] < 1.5:  # (sdf_mesh.MESH_SIGN_WINDING)
                bound = False
        ba = wp.where(da < 0.5 * FAR, da, -FAR)
        bb = wp.where(db < 0.5 * FAR, db, -FAR)
        bc = wp.where(dc < 0.5 * FAR, dc, -FAR)
        count = float(0.0)
        total = float(0.0)
        deepest = float(0.0)
        for i in range(order + 1):
            for j in range(order + 1 - i):
                u = float(i) / float(order)
                v = float(j) / float(order)
                p = a * (1.0 - u - v) + b * u + c * v
                d = float(0.0)
                if i == 0 and j == 0:  # (the corners: asked above)
                    d = da
                elif i == order:
                    d = db
                elif j == order:
                    d = dc
                elif bound and wp.max(ba - wp.length(p - pa), wp.max(bb - wp.length(p - pb),
                                                                    bc - wp.length(p - pc))) > skip_margin:
                    d = 1.0  # (outside: not asked)
                else:
                    d = phi_below(p, geoms, base, n, obj_filter, 0.0)
                if d < 0.0:
                    count += 1.0
                    total += -d
                    deepest = wp.max(deepest, -d)
        if count > 0.0:
            o = w * rows_per_world + row
            wp.atomic_add(out, o, 0, count)
            wp.atomic_add(out, o, 1, total)
            wp.atomic_max(out, o, 2, deepest)

    kernel.__name__ = kernel.__qualname__ = "penetration_cull" if CULL else "penetration_samples"  # (the kernel's key)
    return kernel


penetration_samples = wp.kernel(penetration_source(False))
""" Samples on the order-``order`` lattice ((order + 1)(order + 2) / 2 per triangle; the metric's
is 5); obj_filter >= 0 restricts the samples' SDF to the geoms of that object.

Per world (batched worlds, physhand_mj/batch.py): world w's geoms are [w k, w k + k), k =
``geoms_per_world``; triangle t belongs to world w = t // ``tris_per_world``, is measured against
its world's geoms only and adds into row w ``rows_per_world`` + ``row`` of ``out``. One world:
k = the geom capacity, w = 0.

With a ``listed_count`` (length 1), thread i measures triangle ``listed[i]`` of the ones
:func:`penetration_cull` kept (its bound already asked), and threads past the count return: on
a GPU the few triangles near an object then fill whole warps instead of one lane in ~20.

``skip_margin`` > 0 (SKIP_MARGIN): the corners first; a sample at p with phi(corner) - |p - corner| >
skip_margin for any corner is outside (1-Lipschitz) and not asked."""
penetration_cull = wp.kernel(penetration_source(True))
""" :func:`penetration_samples`' bound alone: triangle t goes to ``listed`` unless phi(centroid)
> circumradius clears every sample (launched with no object filter and an empty list). Appended
in any order on a GPU; on the CPU in ascending t, so its atomics add in the order of the one-kernel
measure."""


def reduce_worlds(rows: np.ndarray) -> np.ndarray:
    """Metrics rows of W worlds, (W, ..., 6), as the batch's (..., 6): counts and depth sums
    added, maximum depths the largest (one world: its rows as they are)."""
    rows = np.asarray(rows)
    if len(rows) == 1:
        return rows[0]
    out = rows.sum(axis=0)
    out[..., 2::3] = rows[..., 2::3].max(axis=0)
    return out


def summarize(row: np.ndarray) -> dict:
    """A metrics row -> penetration_count / _max_um / _avg_um (skin samples inside objects: the
    count, the deepest and the mean depth in um) and, for a 6-column row, object_in_skin_count /
    _max_um / _avg_um (object points inside the skin); :func:`summarize_rows` for one row."""
    return summarize_rows(np.asarray(row)[None])[0]


def summarize_rows(rows: np.ndarray) -> list[dict]:
    """:func:`summarize` of every row of ``rows`` (W, 3 or 6) at once: counts rounded to the nearest
    integer (half to even), depths in um, the mean 0.0 without a count (a thousand batched worlds: a
    loop of per-row Python costs ~2 ms of host time a frame)."""
    rows = np.asarray(rows, dtype=np.float64)
    cols, keys = [], []
    for prefix, k in (("penetration", 0), ("object_in_skin", 3)):
        if k + 2 >= rows.shape[1]:
            break
        count = np.rint(rows[:, k]).astype(np.int64)
        avg = np.divide(rows[:, k + 1], count, out=np.zeros(len(count)), where=count > 0) * 1e6
        cols += [count.tolist(), (rows[:, k + 2] * 1e6).tolist(), avg.tolist()]
        keys += [f"{prefix}_count", f"{prefix}_max_um", f"{prefix}_avg_um"]
    return [dict(zip(keys, v)) for v in zip(*cols)] if cols else [{} for _ in range(len(rows))]


@wp.kernel
def lattice_phi(faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), geoms: GeomSet, tris_per_world: int,
                geoms_per_world: int, order: int, points: wp.array2d(dtype=wp.vec3), phi: wp.array2d(dtype=float)):
    """The order-``order`` lattice samples of every triangle ((order + 1)(order + 2) / 2; the
    metric's 21 at order 5) and their phi (m) against the triangle's world's geoms (batched worlds:
    as broadphase.world_geoms; one world: all), for pictures and checks."""
    t = wp.tid()
    g0, g1 = world_geoms(t, tris_per_world, geoms_per_world, geoms.count[0])
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    n = float(order)
    k = int(0)
    for i in range(order + 1):
        for j in range(order + 1 - i):
            p = a * (1.0 - float(i) / n - float(j) / n) + b * (float(i) / n) + c * (float(j) / n)
            points[t, k] = p
            phi[t, k] = world_phi(p, geoms, g0, g1 - g0, -1)
            k += 1
