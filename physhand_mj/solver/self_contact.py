"""Skin self-collision (issue 53; ``Config.self_collision``): one part of the hand's skin kept on the
outward side of another's.

Found once a frame, resolved every substep (docs/self_collision.md):

    frame start   the query slack (solver/self_slack.py): per skin vertex its move since the last
                  frame in its bone's frame, per pair of bones the change of their relative pose,
                  applied per vertex to the other bones' skin that could come within reach of it;
                  a vertex whose slack (how much nearer a kept triangle may come before it is
                  within the margin) they used up is queried, the others keep an empty list. For
                  the queried (CPU: only when
                  there are any): their normals, the skin triangles' boxes, its BVH (grouped by world)
                  refit, per vertex its world's skin triangles within ``self_margin`` + REACH
                  (bvh_query_aabb, then the exact distance), minus the rest filter, those within
                  ``self_margin`` kept in a per-vertex table of SLOTS, the nearest kept one setting
                  the slack; the vertices with any listed in a compact list, and every vertex a
                  listed pair touches in another
    each substep  after the constraint groups (and before the object contact stage): per listed
                  vertex, its nearest listed triangle now; where the vertex lies less than
                  ``self_thickness`` in front of it (or behind it), an XPBD vertex-triangle
                  correction (hard, mass-weighted between the vertex and the triangle's three
                  vertices by the closest point's barycentrics) toward ``self_thickness`` in front,
                  cut short by ``Tuning.self_tet_keep`` where set; corrections summed by atomics and
                  averaged per vertex (Jacobi), ``self_passes`` times; the flesh behind follows
                  through the tets in the next substep

The rest filter (computed from the rest shape, per candidate, no table): a pair is never listed
where the vertex is one of the triangle's or lies within FOLD_GAP of it at rest, nor within
``self_rest_gap`` unless the skin has folded there (the fold rule: the vertex's normal and the
triangle's now more than a right angle apart: a crease closed by flexion). At rest the nearest skin
of another finger lies 9.7 mm away (the middle and ring fingers' middle phalanges), the webs' two
sides 2.1-2.6 mm, and nothing is folded, so the open hand lists nothing.

A frame whose list is empty runs no substep work (CPU: list launches of zero threads are skipped;
``Solver.last_activity``'s ``self_queried``, ``self_pairs`` and ``self_ops_run`` report it).
CUDA: every launch has a fixed shape (list launches bounded by their device-side count, no host
read inside the frame); there the refit, the normals and the query's launch run every frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from physhand_mj.contact.closest import closest_on_triangle
from physhand_mj.contact.tet_room import skin_tet_lists, tet_room
from physhand_mj.solver.self_slack import REACH, QuerySlack

wp.set_module_options({"enable_backward": False})

# The fold rule (docs/self_collision.md): a vertex and a triangle nearer than self_rest_gap at rest
# are still a pair where the skin has folded onto itself (the vertex's normal and the triangle's
# now at more than a right angle: cos < FOLD_COS) and they lay at least FOLD_GAP apart at rest.
# Power grasp: 61 -> 37 vertices inside at 0.2 mm, inverted tets 572 -> 546 (the rest shape is flat
# there: nothing folded, the open hand lists nothing).
FOLD_COS = wp.constant(0.0)
FOLD_SOON = wp.constant(0.5)  # (a fold this close counts for the query slack below)
FOLD_GAP = 1.0e-3  # m: ~ a third of a skin edge; closer at rest is the vertex's own one-ring

SLOTS = 16  # listed triangles per skin vertex at most (the nearest kept: 3 mm around a vertex holds ~6-12)


@wp.kernel
def clear_marks(n: wp.array(dtype=int), involved: wp.array(dtype=int), mark: wp.array(dtype=int)):
    """Forget the last frame's touched vertices (over its involved list, ``n[0]`` long)."""
    i = wp.tid()
    if i < n[0]:
        mark[involved[i]] = 0


@wp.kernel
def zero_corrections(wcounts: wp.array2d(dtype=int)):
    """A frame that reuses the last list (Tuning.self_every): its per-world correction count zeroed (the
    list's own counts kept)."""
    wcounts[wp.tid(), 3] = 0


@wp.func
def touch_vertex(i: int, mark: wp.array(dtype=int), involved: wp.array(dtype=int), counts: wp.array(dtype=int),
           seg: int, w: int, vo: int, winvolved: wp.array(dtype=int), wcounts: wp.array2d(dtype=int)):
    """Vertex i (of world w, its first skin vertex ``vo``) into the involved list once (``seg``: into its
    world's segment of ``winvolved`` too)."""
    if wp.atomic_add(mark, i, 1) == 0:
        s = wp.atomic_add(counts, 1, 1)
        involved[s] = i
        if seg != 0:
            winvolved[vo + wp.atomic_add(wcounts, w, 4, 1)] = i


@wp.func
def _normals_cos(vn: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3):
    """cos of the angle between a vertex's normal ``vn`` and triangle (a, b, c)'s normal now (the
    fold rule: a crease folded onto itself has them opposed)."""
    f = wp.cross(b - a, c - a)
    return wp.dot(vn, f) / wp.max(wp.length(vn) * wp.length(f), 1.0e-30)


@wp.kernel
def group_roots(bvh: wp.uint64, roots: wp.array(dtype=int)):
    """Per world its subtree's root in the grouped BVH (fixed by the build: a refit keeps it)."""
    w = wp.tid()
    roots[w] = wp.bvh_get_group_root(bvh, w)


@wp.func
def _after(d0: float, t0: int, d1: float, t1: int) -> bool:
    """Whether (distance d0, triangle t0) comes after (d1, t1): by distance, equal ones by triangle."""
    return d0 > d1 or (d0 == d1 and t0 > t1)


@wp.kernel
def broadphase(nq: wp.array(dtype=int), qlist: wp.array(dtype=int), reach: float, slack: wp.array(dtype=float),
               bvh: wp.uint64, roots: wp.array(dtype=int), ns: int, nf: int, x: wp.array(dtype=wp.vec3),
               rest: wp.array(dtype=wp.vec3),
               faces: wp.array2d(dtype=int), rest_centre: wp.array(dtype=wp.vec3), margin: float, rest_gap: float,
               vn_now: wp.array(dtype=wp.vec3), fold_gap: float, seg: int,
               cand: wp.array2d(dtype=int), cand_d: wp.array2d(dtype=float), cand_n: wp.array(dtype=int),
               vlist: wp.array(dtype=int), involved: wp.array(dtype=int), mark: wp.array(dtype=int),
               counts: wp.array(dtype=int), wcounts: wp.array2d(dtype=int), wvlist: wp.array(dtype=int),
               winvolved: wp.array(dtype=int)):
    """Per skin vertex, the skin triangles of its own world within ``margin`` that the rest filter
    keeps (the nearest SLOTS); counts: [listed vertices, involved vertices, pairs, pairs dropped for
    want of a slot]; per world (``wcounts``): [listed vertices, pairs, pairs dropped, corrections,
    involved vertices]; ``seg``: the listed and involved vertices also per world (``wvlist``,
    ``winvolved``: world w's from w ns on; the fused substep's blocks read them).
    World w's skin is vertices [w ns, (w + 1) ns) and triangles [w nf, (w + 1) nf); ``rest`` and
    ``rest_centre`` hold one world's (the rest shape is every world's)."""
    i = wp.tid()
    if i >= nq[0]:
        return
    v = qlist[i]
    w = v // ns
    vo = w * ns  # (world w's first skin vertex and triangle: the offsets to one world's rest arrays)
    to = w * nf
    p = x[v]
    pr = rest[v - vo]
    r = wp.vec3(reach, reach, reach)
    nearest_kept = reach  # for the slack: the nearest triangle kept or about to fold
    # the BVH's group w: world w's triangles only (the worlds overlap in space: every world is solved at the origin)
    q = wp.bvh_query_aabb(bvh, p - r, p + r, roots[w])
    t = int(0)
    n = int(0)
    while wp.bvh_query_next(q, t):
        a = faces[t, 0]
        b = faces[t, 1]
        c = faces[t, 2]
        if a == v or b == v or c == v:
            continue
        # the rest filter's cheap half first: a triangle whose rest centroid lies within fold_gap (rest_gap
        # unless folded) of the vertex at rest (the surface around it: most of what the box holds; the
        # centroid is a point of the triangle, so its distance bounds the rest distance from above)
        rfar = wp.length(pr - rest_centre[t - to])
        if rfar < fold_gap:
            continue
        # the fold rule: the skin folded onto itself (a crease closed by flexion), the vertex's normal
        # now against the triangle's, is a pair from fold_gap apart at rest (flat there: none at rest)
        folded = False
        soon = False  # (for the slack: a fold that a little more motion could close)
        judged = rfar < rest_gap
        if judged:
            cosn = _normals_cos(vn_now[v], x[a], x[b], x[c])
            folded = cosn < FOLD_COS
            soon = cosn < FOLD_SOON
            if not soon:
                continue
        uv = closest_on_triangle(x[a], x[b], x[c], p)
        d = wp.length(p - (uv[0] * x[a] + uv[1] * x[b] + (1.0 - uv[0] - uv[1]) * x[c]))
        if d > reach:
            continue
        # the rest filter: pairs near each other at rest (webs, creases, the surface around the vertex)
        ra = rest[a - vo]
        rb = rest[b - vo]
        rc = rest[c - vo]
        ur = closest_on_triangle(ra, rb, rc, pr)
        qr = ur[0] * ra + ur[1] * rb + (1.0 - ur[0] - ur[1]) * rc
        dr = wp.length(pr - qr)
        if dr < fold_gap:
            continue
        if dr < rest_gap and not judged:  # (the bound let it through: the normals decide now)
            cosn = _normals_cos(vn_now[v], x[a], x[b], x[c])
            folded = cosn < FOLD_COS
            soon = cosn < FOLD_SOON
            if not soon:
                continue
        nearest_kept = wp.min(nearest_kept, d)
        if d > margin or (dr < rest_gap and not folded):
            continue
        if n < SLOTS:
            cand[v, n] = t
            cand_d[v, n] = d
            n += 1
        else:  # full: replace the farthest if this one is nearer
            # (ordered by distance, then triangle: the list does not depend on the BVH's traversal order,
            # which differs between builds, e.g. one world's and W worlds')
            far = int(0)
            for k in range(1, SLOTS):
                if _after(cand_d[v, k], cand[v, k], cand_d[v, far], cand[v, far]):
                    far = k
            if _after(cand_d[v, far], cand[v, far], d, t):
                cand[v, far] = t
                cand_d[v, far] = d
            wp.atomic_add(counts, 3, 1)
            wp.atomic_add(wcounts, w, 2, 1)
    cand_n[v] = n
    slack[v] = nearest_kept - margin
    if n > 0:
        s = wp.atomic_add(counts, 0, 1)
        vlist[s] = v
        wp.atomic_add(counts, 2, n)
        sw = wp.atomic_add(wcounts, w, 0, 1)
        if seg != 0:
            wvlist[vo + sw] = v
        wp.atomic_add(wcounts, w, 1, n)
        touch_vertex(v, mark, involved, counts, seg, w, vo, winvolved, wcounts)
        for k in range(n):
            tk = cand[v, k]
            touch_vertex(faces[tk, 0], mark, involved, counts, seg, w, vo, winvolved, wcounts)
            touch_vertex(faces[tk, 1], mark, involved, counts, seg, w, vo, winvolved, wcounts)
            touch_vertex(faces[tk, 2], mark, involved, counts, seg, w, vo, winvolved, wcounts)


@wp.kernel
def skin_bounds(x: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=int),
                lowers: wp.array(dtype=wp.vec3), uppers: wp.array(dtype=wp.vec3)):
    """Per skin triangle its bounding box now (the BVH's leaves, refit next)."""
    t = wp.tid()
    xa = x[faces[t, 0]]
    xb = x[faces[t, 1]]
    xc = x[faces[t, 2]]
    lowers[t] = wp.min(wp.min(xa, xb), xc)
    uppers[t] = wp.max(wp.max(xa, xb), xc)


@wp.kernel
def skin_normals(nq: wp.array(dtype=int), qlist: wp.array(dtype=int), x: wp.array(dtype=wp.vec3),
                 faces: wp.array2d(dtype=int), ns: int, nf: int, vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
                 vn: wp.array(dtype=wp.vec3)):
    """Per queried skin vertex (the first ``nq[0]`` of ``qlist``: the fold rule reads no other's) the
    sum of its triangles' area-weighted normals now, its triangles in ascending order (one world's
    ``vt`` from ``vt_off[v]``; world w's shifted by w ``nf``): the same sum, float for float, as each
    triangle adding its normal to its corners in triangle order, without atomics or the other
    vertices' work."""
    i = wp.tid()
    if i >= nq[0]:
        return
    v = qlist[i]
    w = v // ns
    vl = v - w * ns
    s = wp.vec3(0.0)
    for k in range(vt_off[vl], vt_off[vl + 1]):
        t = vt[k] + w * nf
        xa = x[faces[t, 0]]
        s += wp.cross(x[faces[t, 1]] - xa, x[faces[t, 2]] - xa)
    vn[v] = s


@wp.func
def nearest_listed(v: int, xo: int, x: Any, faces: wp.array2d(dtype=int), cand: wp.array2d(dtype=int),
                   cand_n: wp.array(dtype=int)) -> int:
    """Skin vertex v's nearest listed triangle now (-1: none listed; equal distances, e.g. across a
    shared edge: the lower triangle, so the choice does not depend on the list's order). ``x``: the
    positions of vertex ``g`` at ``g - xo`` (the launches: every world's, xo 0; the fused substep:
    its block's shared tile, xo the world's first skin vertex)."""
    p = x[v - xo]
    best = int(-1)
    bd = float(1.0e30)
    for k in range(cand_n[v]):
        t = cand[v, k]
        xa = x[faces[t, 0] - xo]
        xb = x[faces[t, 1] - xo]
        xc = x[faces[t, 2] - xo]
        uv = closest_on_triangle(xa, xb, xc, p)
        q = uv[0] * xa + uv[1] * xb + (1.0 - uv[0] - uv[1]) * xc
        d = wp.length(p - q)
        if _after(bd, best, d, t):
            bd = d
            best = t
    return best


_PAIRS: dict = {}


def pair_correction_fn(keep: bool = True, friction: bool = True):
    """:func:`pair_correction` with Tuning.self_tet_keep's guard (``keep``) and Tuning.self_friction
    (``friction``) compiled in or left out: left out, the ``keep`` / ``mu`` arguments are not read
    (as if 0; the same bits where they are 0). The fused substep kernel takes the variant its Tuning
    needs (solver/fused_self.py): a kernel under a register cap spills what it compiles in, used or not
    (H200, W = 4,096: the fused kernel 89.0 -> 67.9 ms a frame with both left out)."""
    key = (bool(keep), bool(friction))
    if key in _PAIRS:
        return _PAIRS[key]
    KEEP, FRICTION = key

    def pair_correction(v: int, best: int, xo: int, vo: int, to: int, x: Any, inv_mass: wp.array(dtype=float),
                        faces: wp.array2d(dtype=int), thickness: float, depth: float, keep: float, mu: float,
                        vt_off: wp.array(dtype=int), vt: wp.array(dtype=int), tets: wp.array2d(dtype=int),
                        vol0: wp.array(dtype=float), x_prev: wp.array(dtype=wp.vec3)):
        """Skin vertex v against triangle ``best``: closer than ``thickness`` in front (or behind it, up to
        ``depth``), the hard vertex-triangle correction, and with ``mu`` > 0 its Coulomb friction: the
        pair's slip along the triangle over the substep (from ``x_prev``) undone up to ``mu`` x the
        normal correction (the tet guard, ``keep``, checks the normal correction only). Returns (moves,
        a, b, c, the normal moves of v, a, b, c, the share ``fr`` of them that x_prev takes too, the
        friction moves of v, a, b, c, which x_prev does not take: they change the velocity); the caller
        adds them up (the launches:
        :func:`resolve_kernel`; the fused substep: solver/fused_self.py). ``v``, ``faces``, ``x_prev`` and the
        returned corners: every world's indices; ``x`` and ``inv_mass`` hold vertex g at ``g - xo``
        (:func:`nearest_listed`); ``vo``: the world's first skin vertex; ``to``: :func:`~physhand_mj.contact.tet_room.tet_room`'s."""
        z = wp.vec3(0.0)
        a = faces[best, 0]
        b = faces[best, 1]
        c = faces[best, 2]
        p = x[v - xo]
        xa = x[a - xo]
        xb = x[b - xo]
        xc = x[c - xo]
        bu = closest_on_triangle(xa, xb, xc, p)
        nrm = wp.cross(xb - xa, xc - xa)
        ln = wp.length(nrm)
        if ln < 1.0e-12:
            return 0, a, b, c, z, z, z, z, 0.0, z, z, z, z
        nrm = nrm / ln
        wa = bu[0]
        wb = bu[1]
        wc = 1.0 - bu[0] - bu[1]
        q = wa * xa + wb * xb + wc * xc
        s = wp.dot(p - q, nrm)
        if s >= thickness or s < -depth:
            return 0, a, b, c, z, z, z, z, 0.0, z, z, z, z
        mv = inv_mass[v - xo]
        ma = inv_mass[a - xo]
        mb = inv_mass[b - xo]
        mc = inv_mass[c - xo]
        w = mv + wa * wa * ma + wb * wb * mb + wc * wc * mc
        if w <= 0.0:
            return 0, a, b, c, z, z, z, z, 0.0, z, z, z, z
        dl = (thickness - s) / w
        if wp.static(KEEP):  # (compiled in: Tuning.self_tet_keep's guard)
            if keep > 0.0:  # Tuning.self_tet_keep: no move that flattens a tet of the vertex or a corner past it
                tk = tet_room(v - xo, v - vo, mv * dl * nrm, x, vt_off, vt, tets, vol0, keep, to)
                tk = wp.min(tk, tet_room(a - xo, a - vo, -wa * ma * dl * nrm, x, vt_off, vt, tets, vol0, keep, to))
                tk = wp.min(tk, tet_room(b - xo, b - vo, -wb * mb * dl * nrm, x, vt_off, vt, tets, vol0, keep, to))
                tk = wp.min(tk, tet_room(c - xo, c - vo, -wc * mc * dl * nrm, x, vt_off, vt, tets, vol0, keep, to))
                dl = dl * tk
        # The share of the correction that resolves the depth the pair already had at the substep's start
        # (s0 below thickness, from x_prev) moves x_prev too, so it adds no velocity: the pair ends the
        # substep with no relative normal velocity instead of flying apart at depth / h. Without it the
        # held fist's skin jumps up to ~5 mm a frame (docs/self_collision_findings.md "A held fist").
        qp = wa * x_prev[a] + wb * x_prev[b] + wc * x_prev[c]
        s0 = wp.dot(x_prev[v] - qp, nrm)
        fr = wp.clamp((thickness - s0) / (thickness - s), 0.0, 1.0)
        fv = wp.vec3(0.0)
        fa = wp.vec3(0.0)
        fb = wp.vec3(0.0)
        fc = wp.vec3(0.0)
        if wp.static(FRICTION):  # (compiled in: Tuning.self_friction)
            if mu > 0.0:  # Coulomb friction (position-based, as Macklin et al. 2014): the pair's relative slip
                # along the triangle over the substep, undone up to mu x the normal correction's length; it
                # changes the velocity (x_prev not moved), as friction must
                slip = (p - x_prev[v]) - (q - qp)
                slip = slip - nrm * wp.dot(slip, nrm)
                sl = wp.length(slip)
                lim = mu * dl * w  # (dl w: the normal correction's length, thickness - s, as cut by the tet guard)
                if sl > 0.0:
                    f = -slip * (wp.min(sl, lim) / (sl * w))
                    fv = mv * f
                    fa = -wa * ma * f
                    fb = -wb * mb * f
                    fc = -wc * mc * f
        return 1, a, b, c, mv * dl * nrm, -wa * ma * dl * nrm, -wb * mb * dl * nrm, -wc * mc * dl * nrm, fr, fv, fa, fb, fc

    pair_correction.__name__ = pair_correction.__qualname__ = f"pair_correction{'_keep' if KEEP else ''}{'_friction' if FRICTION else ''}"
    _PAIRS[key] = wp.func(pair_correction)
    return _PAIRS[key]


# (the launches' variant, with both: they branch on the values)
pair_correction = pair_correction_fn(True, True)


_RESOLVE: dict = {}


def resolve_kernel(keep: bool = True, friction: bool = True):
    """The passes' ``resolve`` launch with Tuning.self_tet_keep's guard and Tuning.self_friction
    compiled in or left out (:func:`pair_correction_fn`; SelfContact.record_stage takes what its Tuning
    uses: fewer registers a thread)."""
    key = (bool(keep), bool(friction))
    if key in _RESOLVE:
        return _RESOLVE[key]
    KEEP, FRICTION = key
    pair_correction = pair_correction_fn(KEEP, FRICTION)

    def _correct(v: int, best: int, x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), faces: wp.array2d(dtype=int),
                 thickness: float, depth: float, keep: float, mu: float, vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
                 tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float), x_prev: wp.array(dtype=wp.vec3),
                 delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=int), active: wp.array(dtype=int),
                 dprev: wp.array(dtype=wp.vec3), world: int, vo: int, to: int, wcounts: wp.array2d(dtype=int)):
        """:func:`pair_correction` of vertex v (of world ``world``: its first skin vertex ``vo``, first
        tet ``to``) added into ``delta`` / ``hits`` (and its x_prev share into ``dprev``) by atomics: the
        launches' sum; the correction counted in ``active`` and the world's ``wcounts`` row."""
        moves, a, b, c, dv, da, db, dc, fr, fv, fa, fb, fc = wp.static(pair_correction)(
            v, best, 0, vo, to, x, inv_mass, faces, thickness, depth, keep, mu, vt_off, vt, tets, vol0, x_prev)
        if moves == 0:
            return
        if fr > 0.0:
            wp.atomic_add(dprev, v, fr * dv)
            wp.atomic_add(dprev, a, fr * da)
            wp.atomic_add(dprev, b, fr * db)
            wp.atomic_add(dprev, c, fr * dc)
        if wp.static(FRICTION):
            if mu > 0.0:  # (mu 0: the moves as before friction, bit for bit)
                dv = dv + fv
                da = da + fa
                db = db + fb
                dc = dc + fc
        wp.atomic_add(delta, v, dv)
        wp.atomic_add(hits, v, 1)
        if inv_mass[a] > 0.0:
            wp.atomic_add(delta, a, da)
            wp.atomic_add(hits, a, 1)
        if inv_mass[b] > 0.0:
            wp.atomic_add(delta, b, db)
            wp.atomic_add(hits, b, 1)
        if inv_mass[c] > 0.0:
            wp.atomic_add(delta, c, dc)
            wp.atomic_add(hits, c, 1)
        wp.atomic_add(active, 0, 1)
        wp.atomic_add(wcounts, world, 3, 1)

    _correct.__name__ = _correct.__qualname__ = f"correct{'_keep' if KEEP else ''}{'_friction' if FRICTION else ''}"
    correct = wp.func(_correct)

    @wp.kernel(module="unique", enable_backward=False)
    def resolve(n: wp.array(dtype=int), x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), faces: wp.array2d(dtype=int),
                vlist: wp.array(dtype=int), cand: wp.array2d(dtype=int), cand_n: wp.array(dtype=int),
                thickness: float, depth: float, pick: int, nearest: wp.array(dtype=int), keep: float, mu: float,
                vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
                tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float), x_prev: wp.array(dtype=wp.vec3), ns: int,
                nt: int, delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=int), active: wp.array(dtype=int),
                dprev: wp.array(dtype=wp.vec3), wcounts: wp.array2d(dtype=int)):
        """Per listed vertex (of every world: ``ns`` skin vertices, ``nt`` tets each): its nearest listed
        triangle now (``pick``: found and kept in ``nearest``, else the one kept by the substep's first
        pass), the correction (``_correct``)."""
        i = wp.tid()
        if i >= n[0]:
            return
        v = vlist[i]
        w = v // ns
        best = int(-1)
        if pick != 0:
            best = nearest_listed(v, 0, x, faces, cand, cand_n)
            nearest[v] = best
        else:
            best = nearest[v]
        if best < 0:
            return
        wp.static(correct)(v, best, x, inv_mass, faces, thickness, depth, keep, mu, vt_off, vt, tets, vol0, x_prev,
                           delta, hits, active, dprev, w, w * ns, w * nt, wcounts)

    _RESOLVE[key] = resolve
    return resolve


@wp.kernel
def apply(n: wp.array(dtype=int), involved: wp.array(dtype=int), x: wp.array(dtype=wp.vec3),
          delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=int), x_prev: wp.array(dtype=wp.vec3),
          dprev: wp.array(dtype=wp.vec3)):
    """The pass's corrections, averaged per vertex (over the involved list), then zeroed."""
    k = wp.tid()
    if k >= n[0]:
        return
    i = involved[k]
    h = hits[i]
    if h > 0:
        x[i] = x[i] + delta[i] / float(h)
        x_prev[i] = x_prev[i] + dprev[i] / float(h)
        delta[i] = wp.vec3()
        dprev[i] = wp.vec3()
        hits[i] = 0


class SelfContact:
    """The self-collision's buffers and launches for one body of W worlds (Solver holds one where
    ``Config.self_collision``; one hand: W = 1): :meth:`record_frame` (the frame's list) and
    :meth:`record_stage` (a substep's correction) record into the solver's frame, each stage one
    launch over every world's skin (the batched layout, solver/worlds.py: world w's skin vertices
    ``w ns`` on, its skin triangles ``w nf`` on, its bones ``w nb`` on, its tets ``w nt`` on).

    A vertex pairs only with its own world's triangles: one BVH over every world's skin triangles,
    grouped by world (``wp.Bvh(groups=...)``), queried from the vertex's world's subtree
    (``bvh_get_group_root``). Batched worlds all lie at the origin (BatchedHands), so a filter on
    the query's results would walk all W worlds' triangles near the vertex; per-world meshes would
    refit W times a frame. The query slack's bone tables are per world ((nb + 1) slots each, bone
    pairs only within a world). The rest filter's arrays are one world's (the rest shape is every
    world's), indexed by the world's offsets."""

    def __init__(self, model, config, device):
        self.model, self.config, self.device = model, config, device
        d = device
        W = int(getattr(model, "worlds", 1))
        self.worlds = W
        ns = int(model.n_skin)
        self.n_skin = ns
        self.ns1 = ns // W  # (one world's skin vertices, bones, skin triangles, tets)
        self.nb1 = int(model.n_bodies) // W
        faces = model.skin_faces
        if not (isinstance(faces, wp.array) and faces.dtype == wp.int32 and faces.ndim == 2 and faces.device == wp.get_device(d)
                and faces.is_contiguous):
            faces = wp.array(np.asarray(faces.numpy() if hasattr(faces, "numpy") else faces).astype(np.int32), dtype=int, device=d)
        self.faces = faces  # (every world's, as the model holds them: no W-wide copy)
        nf = int(faces.shape[0])
        self.nf1 = nf // W
        faces1 = faces[: self.nf1].numpy()  # world 0's: one world's vertex indices (skins lead)
        rest = model.rest_x.numpy()[: self.ns1].astype(np.float64)
        self.rest = wp.array(rest, dtype=wp.vec3, device=d)  # one world's rest skin
        self.vn_now = wp.zeros(ns, dtype=wp.vec3, device=d)  # the queried skin vertices' area-weighted normals at the frame's start
        # the skin triangles' bounding boxes (the BVH's leaves, refit every frame) and their worlds (its groups)
        self.lowers = wp.zeros(nf, dtype=wp.vec3, device=d)
        self.uppers = wp.zeros(nf, dtype=wp.vec3, device=d)
        self.groups = wp.array(np.repeat(np.arange(W, dtype=np.int32), self.nf1), dtype=wp.int32, device=d)
        self.bvh = None  # (built at the first frame recorded, from its state's skin)
        self.roots = wp.zeros(W, dtype=int, device=d)  # per world its subtree's root in the BVH
        # which skin vertices the frame queries (solver/self_slack.py: their slack, the list of them)
        self.query = QuerySlack(model, W, self.ns1, self.nb1, faces1, rest, d)
        self.fcount = wp.zeros(1, dtype=int, device=d)
        # per triangle its rest centroid (the rest filter's bound)
        self.rest_centre = wp.array(rest[faces1].mean(axis=1).astype(np.float32), dtype=wp.vec3, device=d)
        # one world's skin triangles by corner vertex, ascending (skin_normals)
        vt = np.stack([faces1.ravel(), np.repeat(np.arange(len(faces1)), 3)], 1)
        vt = vt[np.lexsort((vt[:, 1], vt[:, 0]))]
        self.vt_off_skin = wp.array(np.concatenate([[0], np.cumsum(np.bincount(vt[:, 0], minlength=self.ns1))]).astype(np.int32),
                                    dtype=int, device=d)
        self.vt_skin = wp.array(vt[:, 1].astype(np.int32), dtype=int, device=d)
        self.cand = wp.zeros((ns, SLOTS), dtype=int, device=d)
        self.cand_d = wp.zeros((ns, SLOTS), dtype=float, device=d)
        self.cand_n = wp.zeros(ns, dtype=int, device=d)
        self.dprev = wp.zeros(ns, dtype=wp.vec3, device=d)
        self.vlist = wp.zeros(ns, dtype=int, device=d)
        self.involved = wp.zeros(ns, dtype=int, device=d)
        self.mark = wp.zeros(ns, dtype=int, device=d)
        self.delta = wp.zeros(ns, dtype=wp.vec3, device=d)
        self.hits = wp.zeros(ns, dtype=int, device=d)
        self.nearest = wp.zeros(ns, dtype=int, device=d)  # per listed vertex its nearest triangle this substep
        # [listed vertices, involved vertices, pairs, pairs over SLOTS]; [corrections this frame]
        self.counts = wp.zeros(4, dtype=int, device=d)
        self.active = wp.zeros(1, dtype=int, device=d)
        # per world: [listed vertices, pairs, pairs over SLOTS, corrections this frame, involved vertices]
        self.wcounts = wp.zeros((W, 5), dtype=int, device=d)
        self.vcount = wp.zeros(1, dtype=int, device=d)  # (the list launches read their length here)
        self.icount = wp.zeros(1, dtype=int, device=d)
        # (the substep passes run inside the fused kernel, solver/fused_self.py: set before the first frame
        # is recorded, the broadphase then also lists per world, a block reading its world's segment)
        self.in_kernel = False
        # per world its listed and involved vertices from w ns1 on (wcounts' columns 0 and 4 long)
        self.wvlist = wp.zeros(ns, dtype=int, device=d)
        self.winvolved = wp.zeros(ns, dtype=int, device=d)
        # Tuning.self_tet_keep: every tet of every skin vertex of one world (CSR: vt_off, vt) and its rest
        # volume; world w's are the same shifted by its offsets (the model's tets: world by world)
        self.tets, self.nt1, self.vol0, self.vt_off, self.vt = skin_tet_lists(model, self.ns1)
        self.edge_pairs = None  # Tuning.self_edges: the edge-edge pairs (solver/self_edges.py; the Solver sets them)
        self.every = int(config.self_every)  # Tuning.self_every: frames one list serves
        self.query_now = True  # (begin_frame: whether this frame lists anew, and for which state's id)
        self._listed_for = None
        # the frame's figures report() reads (counts, corrections, vertices queried, per world wcounts):
        # on CUDA copied into pinned host rows after the frame's launches (copy_report), so the frame's one
        # sync brings them instead of a device read (a host round trip) each; on the CPU the arrays themselves
        self._figures = [self.counts, self.active, self.query.qcount, self.wcounts]
        self._figures_host = ([wp.empty(a.shape, dtype=a.dtype, device="cpu", pinned=True) for a in self._figures]
                              if wp.get_device(d).is_cuda else self._figures)
        self._figures_np = [a.numpy() for a in self._figures_host]  # (views, made once)

    def build(self, state) -> wp.Bvh:
        """The BVH over the skin triangles of ``state`` (built once, at the first frame recorded; every
        frame refits it to its state's skin: a second state's frames refit the same tree)."""
        if self.bvh is None:
            wp.launch(skin_bounds, self.faces.shape[0], inputs=[state.x, self.faces],
                      outputs=[self.lowers, self.uppers], device=self.device)
            self.bvh = wp.Bvh(self.lowers, self.uppers, groups=self.groups)
            wp.launch(group_roots, self.worlds, inputs=[self.bvh.id], outputs=[self.roots], device=self.device)
        return self.bvh

    def begin_frame(self, state) -> bool:
        """Whether the frame about to run on ``state`` lists anew (Tuning.self_every: every
        ``self_every``-th frame of the state, its first included, and any frame of a state other than
        the one the list was made for; the frames between reuse the list). Part of the frame's graph
        key on CUDA (a graph for each)."""
        # (a list is one state's: a solver stepping two states in turn lists anew for each)
        self.query_now = state.frames % self.every == 0 or id(state) != self._listed_for
        if self.query_now:
            self._listed_for = id(state)
        return self.query_now

    def record_frame(self, rec, state) -> None:
        """The frame's list (:meth:`_record_list`); with Tuning.self_every above 1 in a block run
        only where :meth:`begin_frame` said so, the frames between zeroing only the frame's
        correction counts (the list, its lengths and the slack kept as the last query left them)."""
        if self.every == 1:
            self._record_list(rec, state)
            return
        outer = rec.ops
        try:
            rec.ops = listing = []
            self._record_list(rec, state)
            rec.ops = keeping = []
            keeping.append(self.active.zero_)
            rec.launch(zero_corrections, self.worlds, [], [self.wcounts])
        finally:
            rec.ops = outer

        def either():
            for op in listing if self.query_now else keeping:
                op()
        outer.append(either)

    def _record_list(self, rec, state) -> None:
        """The frame's list: last frame's marks cleared; the vertices whose slack is used up picked;
        for them (CPU: only when there are any) their normals and the triangles' boxes, the BVH refit,
        the broadphase. Each a launch over every world."""
        cfg, d = self.config, self.device
        bvh = self.build(state)
        cuda = wp.get_device(d).is_cuda
        rec.launch(clear_marks, self.n_skin, [self.icount, self.involved], [self.mark], count=self.icount)
        qs = self.query
        rec.ops.append(lambda: (self.counts.zero_(), self.active.zero_(), self.wcounts.zero_(), qs.zero()))
        ns1 = self.ns1
        reach = float(cfg.self_margin) + REACH
        qs.record(rec, state, reach, self.cand_n)
        q = qs.qcount.numpy() if not cuda else None  # (CPU: a view, read when the frame runs)

        def when_queried(op):
            return op if cuda else (lambda: op() if q[0] else None)

        nf = int(self.faces.shape[0])
        if not cuda:  # (CPU: the boxes' launch sized 0 when nothing is queried)
            fc = self.fcount.numpy()
            rec.ops.append(lambda: fc.__setitem__(0, nf if q[0] else 0))
        rec.launch(skin_normals, self.n_skin,
                   [qs.qcount, qs.qlist, state.x, self.faces, ns1, self.nf1, self.vt_off_skin, self.vt_skin],
                   [self.vn_now], count=qs.qcount)
        rec.launch(skin_bounds, nf, [state.x, self.faces], [self.lowers, self.uppers],
                   count=None if cuda else self.fcount)
        rec.ops.append(when_queried(bvh.refit))
        rec.launch(broadphase, self.n_skin,
                   [qs.qcount, qs.qlist, reach, qs.slack, bvh.id, self.roots, ns1, self.nf1, state.x, self.rest, self.faces,
                    self.rest_centre, float(cfg.self_margin), float(cfg.self_rest_gap), self.vn_now, float(FOLD_GAP),
                    int(self.in_kernel)],
                   [self.cand, self.cand_d, self.cand_n, self.vlist, self.involved, self.mark, self.counts, self.wcounts,
                    self.wvlist, self.winvolved],
                   count=qs.qcount)
        if self.edge_pairs is not None:  # (after the vertices' list: it marks the vertices already through)
            self.edge_pairs.record_frame(rec, state, when_queried)
        # the list lengths the substeps' list launches read (CPU: on the host for free)
        rec.ops.append(lambda: (wp.copy(self.vcount, self.counts, 0, 0, 1), wp.copy(self.icount, self.counts, 0, 1, 1)))

    def features(self) -> tuple[bool, bool]:
        """(Tuning.self_tet_keep's guard, Tuning.self_friction) in use: what the passes' kernels
        compile in (:func:`pair_correction_fn`: the fused kernel runs at a register cap, so code it
        carries unused spills for the whole kernel)."""
        cfg = self.config
        return float(cfg.self_tet_keep) > 0.0, float(cfg.self_friction) > 0.0

    def record_stage(self, rec, state, inv_mass) -> None:
        """A substep's correction: ``self_passes`` x (resolve, apply) over the frame's lists (every world's)."""
        cfg = self.config
        for k in range(cfg.self_passes):
            rec.launch(resolve_kernel(*self.features()), self.n_skin,
                       [self.vcount, state.x, inv_mass, self.faces, self.vlist, self.cand, self.cand_n,
                        float(cfg.self_thickness), float(cfg.self_depth), int(k == 0), self.nearest,
                        float(cfg.self_tet_keep), float(cfg.self_friction), self.vt_off, self.vt, self.tets, self.vol0,
                        state.x_prev,
                        self.ns1, self.nt1],
                       [self.delta, self.hits, self.active, self.dprev, self.wcounts], count=self.vcount)
            if self.edge_pairs is not None:
                self.edge_pairs.record_pass(rec, state, inv_mass)
            rec.launch(apply, self.n_skin, [self.icount, self.involved],
                       [state.x, self.delta, self.hits, state.x_prev, self.dprev], count=self.icount)

    def copy_report(self) -> None:
        """CUDA: queue the copies of the frame's figures to the host rows :meth:`report` and
        :meth:`report_worlds` read (Solver._queue_frame, after the frame's launches: the frame's sync
        waits for them). The CPU reads the arrays themselves."""
        if self._figures_host is not self._figures:
            for host, dev in zip(self._figures_host, self._figures):
                wp.copy(host, dev)

    def report(self) -> dict:
        """The last frame's figures (every world's together): vertices queried, listed vertices and
        pairs, corrections made (summed over passes); per world: :meth:`report_worlds`."""
        c, active, qcount, _ = self._figures_np
        q = int(qcount[0]) if self.query_now else 0
        cfg = self.config
        # the frame's self-collision launches that ran on the CPU (CUDA runs the fixed set, each
        # thread past its list returning): the motion bound's five, the query's four with any
        # vertex queried, the substeps' 2 x passes with any pair listed (however many worlds; inside the
        # fused kernel the substep passes launch nothing of their own; Tuning.self_edges: with a query its
        # marks', boxes' and pairs' 4, and with an edge pair listed 1 a pass, 2 where no vertex is listed); a
        # frame reusing the last list (Tuning.self_every) runs only its counts' zeroing before the passes
        ops = 5 + (4 if q else 0) if self.query_now else 1
        ops += 2 * cfg.self_passes * cfg.substeps if c[0] and not self.in_kernel else 0
        edges = {}
        if self.edge_pairs is not None:
            edges = self.edge_pairs.report()
            ops += 4 if q else 0
            if edges["self_edge_pairs"]:
                ops += cfg.self_passes * cfg.substeps * (1 if c[0] else 2)
        return dict(**edges, self_queried=q, self_ops_run=ops, self_vertices=int(c[0]), self_pairs=int(c[2]), self_pairs_over=int(c[3]),
                    self_corrections=int(active[0]))

    def report_worlds(self) -> np.ndarray:
        """(W, 4) the last frame's per-world figures: listed vertices, pairs, pairs over SLOTS,
        corrections (:meth:`report`'s ``self_vertices``, ``self_pairs``, ``self_pairs_over``,
        ``self_corrections`` of each world)."""
        return self._figures_np[3][:, :4].copy()
