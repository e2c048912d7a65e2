"""Edge-edge skin self-contact (issue 53, ``Tuning.self_edges``): two skin edges of the hand that
come within two ``self_thickness`` of each other are kept ``self_thickness`` apart on the side they
lie on at the frame's start.

The vertex-triangle pairs (self_contact.py) see a skin edge pass through another part's triangle
only where one of its ends lies behind the triangle over its interior. In the fist the skin folds
into pleats one triangle wide at the knuckles and pinches between the fingers; there edges dive
through a triangle past its rim with neither end over it (docs/self_collision.md "Known limits").
An edge-edge pair sees that.

Found once a frame, after the vertex-triangle list (whose queried vertices it reuses), resolved in
every substep's self passes:

    frame start   the **tangled** vertices marked: a listed vertex lying behind one of its listed
                  triangles over the triangle's interior, and that triangle's corners (the skin is
                  through itself there); the skin edges' boxes, their BVH (grouped by world) refit;
                  per edge with a queried end, the edges of its world within the margin (twice
                  ``self_thickness``; bvh_query_aabb, then the exact segment distance) that share no
                  vertex, lay at least FOLD_GAP apart at rest, have no tangled end and are not
                  through each other's triangles: listed once, with the closest points' direction
    each pass     per listed pair, its closest points now; where they lie less than
                  ``self_thickness`` apart along the pair's direction, the hard correction moving the
                  four ends by their inverse masses and the closest points' weights, summed with the
                  vertex-triangle corrections and averaged per vertex (Jacobi)

Why the two exclusions: a pair's side at the frame's start is the right one only where the skin is
not already through itself. Listing every pair (no exclusion) held the fist's skin through itself
(``power`` 62 -> 272 crossing edges, CPU, frames 25-36); skipping the pairs through each other's
triangles only, 148; with the tangled ends excluded as well, 17 (glass1 27 -> 4, toothpaste 25 ->
4). What is already tangled is left to the vertex-triangle pairs, which push a vertex behind a
triangle out to its front.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.closest import closest_on_triangle
from physhand_mj.solver.self_contact import FOLD_GAP, group_roots, touch_vertex

wp.set_module_options({"enable_backward": False})

EDGE_SLOTS = 2  # listed pairs per skin edge on average at most (the held power fist: ~4,500 of 15,000 edges)
MARGIN_THICKNESSES = 2.0  # the pairs' list margin in self_thickness (1 mm: as good as 2 mm at 1.7 x less frame)


@wp.func
def segments_closest(p1: wp.vec3, q1: wp.vec3, p2: wp.vec3, q2: wp.vec3):
    """Closest points of segments p1q1 and p2q2 (Ericson, Real-Time Collision Detection 5.1.9): the
    parameters (s, t) along each, in [0, 1]."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = wp.dot(d1, d1)
    e = wp.dot(d2, d2)
    f = wp.dot(d2, r)
    s = float(0.0)
    t = float(0.0)
    if a <= 1.0e-20 and e <= 1.0e-20:
        return wp.vec2(0.0, 0.0)
    if a <= 1.0e-20:
        t = wp.clamp(f / e, 0.0, 1.0)
        return wp.vec2(0.0, t)
    c = wp.dot(d1, r)
    if e <= 1.0e-20:
        s = wp.clamp(-c / a, 0.0, 1.0)
        return wp.vec2(s, 0.0)
    b = wp.dot(d1, d2)
    den = a * e - b * b
    if den > 1.0e-20 * a * e:
        s = wp.clamp((b * f - c * e) / den, 0.0, 1.0)
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = wp.clamp(-c / a, 0.0, 1.0)
    elif t > 1.0:
        t = 1.0
        s = wp.clamp((b - c) / a, 0.0, 1.0)
    return wp.vec2(s, t)


@wp.func
def segment_through(p: wp.vec3, q: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> bool:
    """Whether segment pq passes through the interior of triangle abc (Moller-Trumbore, as the
    independent measure's test)."""
    d = q - p
    e1 = b - a
    e2 = c - a
    pv = wp.cross(d, e2)
    det = wp.dot(e1, pv)
    if wp.abs(det) < 1.0e-30:
        return False
    inv = 1.0 / det
    tv = p - a
    u = wp.dot(tv, pv) * inv
    if u < 0.0 or u > 1.0:
        return False
    qv = wp.cross(tv, e1)
    v = wp.dot(d, qv) * inv
    if v < 0.0 or u + v > 1.0:
        return False
    sv = wp.dot(e2, qv) * inv
    return sv > 0.0 and sv < 1.0


@wp.func
def _edge_through_faces(i0: int, i1: int, e: int, x: wp.array(dtype=wp.vec3), edge_faces: wp.array2d(dtype=int),
                        faces: wp.array2d(dtype=int)) -> bool:
    """Whether segment (x[i0], x[i1]) passes through a triangle of edge e (its two)."""
    for k in range(2):
        t = edge_faces[e, k]
        if t >= 0:
            if segment_through(x[i0], x[i1], x[faces[t, 0]], x[faces[t, 1]], x[faces[t, 2]]):
                return True
    return False


@wp.kernel
def mark_tangled(counts: wp.array(dtype=int), vlist: wp.array(dtype=int), x: wp.array(dtype=wp.vec3),
                 faces: wp.array2d(dtype=int), cand: wp.array2d(dtype=int), cand_n: wp.array(dtype=int),
                 tangled: wp.array(dtype=int)):
    """Per listed vertex: behind any of its listed triangles now (the skin already through itself
    there), the vertex and the triangle's corners marked tangled."""
    i = wp.tid()
    if i >= counts[0]:
        return
    v = vlist[i]
    p = x[v]
    for k in range(cand_n[v]):
        t = cand[v, k]
        xa = x[faces[t, 0]]
        xb = x[faces[t, 1]]
        xc = x[faces[t, 2]]
        bu = closest_on_triangle(xa, xb, xc, p)
        inside_tri = bu[0] > 1.0e-4 and bu[1] > 1.0e-4 and 1.0 - bu[0] - bu[1] > 1.0e-4
        if inside_tri and wp.dot(p - xa, wp.cross(xb - xa, xc - xa)) < 0.0:
            tangled[v] = 1
            tangled[faces[t, 0]] = 1
            tangled[faces[t, 1]] = 1
            tangled[faces[t, 2]] = 1


@wp.kernel
def edge_bounds(x: wp.array(dtype=wp.vec3), edges: wp.array2d(dtype=int), lowers: wp.array(dtype=wp.vec3),
                uppers: wp.array(dtype=wp.vec3)):
    """Per skin edge its bounding box now (the edges' BVH leaves)."""
    e = wp.tid()
    a = x[edges[e, 0]]
    b = x[edges[e, 1]]
    lowers[e] = wp.min(a, b)
    uppers[e] = wp.max(a, b)


@wp.kernel
def mark_queried(qcount: wp.array(dtype=int), qlist: wp.array(dtype=int), queried: wp.array(dtype=int)):
    """The frame's queried skin vertices (the query slack's list) marked."""
    i = wp.tid()
    if i < qcount[0]:
        queried[qlist[i]] = 1


@wp.kernel
def edge_broadphase(bvh: wp.uint64, roots: wp.array(dtype=int), ne1: int, ns: int,
                    x: wp.array(dtype=wp.vec3), rest: wp.array(dtype=wp.vec3), edges: wp.array2d(dtype=int),
                    edge_faces: wp.array2d(dtype=int), faces: wp.array2d(dtype=int), margin: float, rest_gap: float,
                    queried: wp.array(dtype=int), tangled: wp.array(dtype=int),
                    cap: int, pairs: wp.array2d(dtype=int), pdir: wp.array(dtype=wp.vec3), ecount: wp.array(dtype=int),
                    involved: wp.array(dtype=int), mark: wp.array(dtype=int), counts: wp.array(dtype=int),
                    seg: int, wcounts: wp.array2d(dtype=int), winvolved: wp.array(dtype=int)):
    """Per skin edge i with a queried end, the edges j of its world within ``margin`` now that share
    no vertex, lay at least ``rest_gap`` apart at rest, have no tangled end and are not through each
    other's triangles: listed with their closest points' direction (from j to i). Each pair once:
    from its lower edge where both have a queried end. ``ecount``: [pairs found, pairs past ``cap``]."""
    i = wp.tid()
    w = i // ne1
    vo = w * ns
    a = edges[i, 0]
    b = edges[i, 1]
    if queried[a] == 0 and queried[b] == 0:
        return
    if tangled[a] != 0 or tangled[b] != 0:
        return
    xa = x[a]
    xb = x[b]
    r = wp.vec3(margin, margin, margin)
    q = wp.bvh_query_aabb(bvh, wp.min(xa, xb) - r, wp.max(xa, xb) + r, roots[w])
    j = int(0)
    while wp.bvh_query_next(q, j):
        if j == i:
            continue
        c = edges[j, 0]
        d = edges[j, 1]
        if j < i and (queried[c] != 0 or queried[d] != 0):
            continue  # (listed from j)
        if c == a or c == b or d == a or d == b:
            continue
        if tangled[c] != 0 or tangled[d] != 0:
            continue
        # the rest filter: edges nearer than rest_gap at rest (one ring apart on the flat skin)
        ra = rest[a - vo]
        rb = rest[b - vo]
        rc = rest[c - vo]
        rd = rest[d - vo]
        sr = segments_closest(ra, rb, rc, rd)
        if wp.length(ra + sr[0] * (rb - ra) - rc - sr[1] * (rd - rc)) < rest_gap:
            continue
        xc = x[c]
        xd = x[d]
        st = segments_closest(xa, xb, xc, xd)
        p1 = xa + st[0] * (xb - xa)
        p2 = xc + st[1] * (xd - xc)
        dist = wp.length(p1 - p2)
        if dist > margin or dist < 1.0e-9:
            continue
        # already through each other: the side is not known here
        if _edge_through_faces(a, b, j, x, edge_faces, faces) or _edge_through_faces(c, d, i, x, edge_faces, faces):
            continue
        k = wp.atomic_add(ecount, 0, 1)
        if k >= cap:
            wp.atomic_add(ecount, 1, 1)
            continue
        pairs[k, 0] = i
        pairs[k, 1] = j
        pdir[k] = (p1 - p2) / dist
        touch_vertex(a, mark, involved, counts, seg, w, vo, winvolved, wcounts)
        touch_vertex(b, mark, involved, counts, seg, w, vo, winvolved, wcounts)
        touch_vertex(c, mark, involved, counts, seg, w, vo, winvolved, wcounts)
        touch_vertex(d, mark, involved, counts, seg, w, vo, winvolved, wcounts)


@wp.func
def _add(v: int, m: float, dv: wp.vec3, fr: float, delta: wp.array(dtype=wp.vec3), dprev: wp.array(dtype=wp.vec3),
         hits: wp.array(dtype=int)):
    """Vertex v's share of a correction into the pass's sums (none for a vertex held by its bone: m 0)."""
    if m > 0.0:
        wp.atomic_add(delta, v, dv)
        wp.atomic_add(dprev, v, fr * dv)
        wp.atomic_add(hits, v, 1)


@wp.kernel
def resolve_edges(ecount: wp.array(dtype=int), cap: int, x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float),
                  edges: wp.array2d(dtype=int), pairs: wp.array2d(dtype=int), pdir: wp.array(dtype=wp.vec3),
                  thickness: float, x_prev: wp.array(dtype=wp.vec3), ne1: int, delta: wp.array(dtype=wp.vec3),
                  hits: wp.array(dtype=int), dprev: wp.array(dtype=wp.vec3), active: wp.array(dtype=int),
                  wcounts: wp.array2d(dtype=int)):
    """Per listed edge pair: closer than ``thickness`` along its direction, the hard correction,
    mass-weighted over the four ends by the closest points' parameters, into ``delta`` / ``hits``;
    the share that undoes the depth the pair had at the substep's start moves ``x_prev`` too (no
    velocity from it, as the vertex-triangle pairs)."""
    k = wp.tid()
    if k >= wp.min(ecount[0], cap):
        return
    i = pairs[k, 0]
    j = pairs[k, 1]
    a = edges[i, 0]
    b = edges[i, 1]
    c = edges[j, 0]
    d = edges[j, 1]
    n = pdir[k]
    st = segments_closest(x[a], x[b], x[c], x[d])
    s = st[0]
    t = st[1]
    g = wp.dot((1.0 - s) * x[a] + s * x[b] - (1.0 - t) * x[c] - t * x[d], n)
    if g >= thickness:
        return
    ma = inv_mass[a]
    mb = inv_mass[b]
    mc = inv_mass[c]
    md = inv_mass[d]
    wa = 1.0 - s
    wb = s
    wc = 1.0 - t
    wd = t
    wsum = wa * wa * ma + wb * wb * mb + wc * wc * mc + wd * wd * md
    if wsum <= 0.0:
        return
    dl = (thickness - g) / wsum
    g0 = wp.dot((1.0 - s) * x_prev[a] + s * x_prev[b] - (1.0 - t) * x_prev[c] - t * x_prev[d], n)
    fr = wp.clamp((thickness - g0) / (thickness - g), 0.0, 1.0)
    da = wa * ma * dl * n
    db = wb * mb * dl * n
    dc = -wc * mc * dl * n
    dd = -wd * md * dl * n
    _add(a, ma, da, fr, delta, dprev, hits)
    _add(b, mb, db, fr, delta, dprev, hits)
    _add(c, mc, dc, fr, delta, dprev, hits)
    _add(d, md, dd, fr, delta, dprev, hits)
    wp.atomic_add(active, 0, 1)
    wp.atomic_add(wcounts, i // ne1, 3, 1)  # (counted with the world's vertex-triangle corrections)


def edge_tables(faces: np.ndarray):
    """(E, 2) one world's skin edges (each once, the lower vertex first) and (E, 2) each edge's two
    triangles (-1 where the skin has one)."""
    f = np.asarray(faces, np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e.sort(axis=1)
    tri = np.tile(np.arange(len(f)), 3)
    edges, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    ef = np.full((len(edges), 2), -1, np.int64)
    first = np.ones(len(order), bool)
    first[1:] = inv[order][1:] != inv[order][:-1]
    ef[inv[order][first], 0] = tri[order][first]
    second = ~first
    ef[inv[order][second], 1] = tri[order][second]
    return edges.astype(np.int32), ef.astype(np.int32)


class SelfEdges:
    """The edge-edge pairs' buffers and launches beside a
    :class:`~physhand_mj.solver.self_contact.SelfContact` (``sc``), for its W worlds: the skin's edges
    of every world (world w's from ``w`` x one world's on, each world's own BVH group), the pair list
    (EDGE_SLOTS per edge), and the launches that add to ``sc``'s frame list (its involved vertices,
    marks and counts) and to its passes' sums (``delta``, ``hits``, ``dprev``)."""

    def __init__(self, sc, device):
        self.sc, self.device = sc, device
        d = device
        W = sc.worlds
        e1, ef1 = edge_tables(sc.faces[: sc.nf1].numpy())
        self.ne1 = len(e1)
        off_v = (np.arange(W, dtype=np.int32) * sc.ns1)[:, None, None]
        off_f = (np.arange(W, dtype=np.int32) * sc.nf1)[:, None, None]
        self.edges = wp.array((e1[None] + off_v).reshape(-1, 2), dtype=int, device=d)
        self.edge_faces = wp.array(np.where(ef1[None] >= 0, ef1[None] + off_f, -1).reshape(-1, 2), dtype=int, device=d)
        ne = self.ne1 * W
        self.cap = EDGE_SLOTS * ne
        self.pairs = wp.zeros((self.cap, 2), dtype=int, device=d)
        self.pdir = wp.zeros(self.cap, dtype=wp.vec3, device=d)
        self.ecount = wp.zeros(2, dtype=int, device=d)  # [pairs found, pairs past the list's end]
        self.lowers = wp.zeros(ne, dtype=wp.vec3, device=d)
        self.uppers = wp.zeros(ne, dtype=wp.vec3, device=d)
        self.groups = wp.array(np.repeat(np.arange(W, dtype=np.int32), self.ne1), dtype=wp.int32, device=d)
        self.roots = wp.zeros(W, dtype=int, device=d)
        self.bvh = None  # (built at the first frame recorded)
        self.queried = wp.zeros(sc.n_skin, dtype=int, device=d)
        self.tangled = wp.zeros(sc.n_skin, dtype=int, device=d)
        self.ncount = wp.zeros(1, dtype=int, device=d)  # (CPU: the edge launches' length, 0 in a frame querying nothing)

    def record_frame(self, rec, state, when) -> None:
        """After the vertex-triangle list: the tangled and queried vertices marked, the edges' boxes,
        their BVH refit, the pairs listed. ``when(op)``: the op run only when any vertex is queried
        (the CPU's; CUDA's runs every frame, each launch's threads past their list returning)."""
        sc, cfg, d = self.sc, self.sc.config, self.device
        ne = self.ne1 * sc.worlds
        if self.bvh is None:
            wp.launch(edge_bounds, ne, inputs=[state.x, self.edges], outputs=[self.lowers, self.uppers], device=d)
            self.bvh = wp.Bvh(self.lowers, self.uppers, groups=self.groups)
            wp.launch(group_roots, sc.worlds, inputs=[self.bvh.id], outputs=[self.roots], device=d)
        rec.ops.append(lambda: (self.ecount.zero_(), self.tangled.zero_(), self.queried.zero_()))
        qs = sc.query
        rec.launch(mark_queried, sc.n_skin, [qs.qcount, qs.qlist], [self.queried], count=qs.qcount)
        rec.launch(mark_tangled, sc.n_skin, [sc.counts, sc.vlist, state.x, sc.faces, sc.cand, sc.cand_n], [self.tangled],
                   count=sc.counts)
        cuda = wp.get_device(d).is_cuda
        if not cuda:  # (CPU: the edges' boxes and pairs only in a frame that queries any vertex)
            q, n = qs.qcount.numpy(), self.ncount.numpy()
            rec.ops.append(lambda: n.__setitem__(0, ne if q[0] else 0))
        rec.launch(edge_bounds, ne, [state.x, self.edges], [self.lowers, self.uppers], count=None if cuda else self.ncount)
        rec.ops.append(when(self.bvh.refit))
        margin = min(float(cfg.self_margin), MARGIN_THICKNESSES * float(cfg.self_thickness))
        rec.launch(edge_broadphase, ne,
                   [self.bvh.id, self.roots, self.ne1, sc.ns1, state.x, sc.rest, self.edges, self.edge_faces, sc.faces,
                    margin, float(FOLD_GAP), self.queried, self.tangled, self.cap],
                   [self.pairs, self.pdir, self.ecount, sc.involved, sc.mark, sc.counts, int(sc.in_kernel), sc.wcounts,
                    sc.winvolved], count=None if cuda else self.ncount)

    def record_pass(self, rec, state, inv_mass) -> None:
        """One pass's edge-pair corrections, into the vertex-triangle pass's sums (before its apply)."""
        cfg = self.sc.config
        sc = self.sc
        rec.launch(resolve_edges, self.cap,
                   [self.ecount, self.cap, state.x, inv_mass, self.edges, self.pairs, self.pdir,
                    float(cfg.self_thickness), state.x_prev, self.ne1],
                   [sc.delta, sc.hits, sc.dprev, sc.active, sc.wcounts], count=self.ecount)

    def report(self) -> dict:
        """The last frame's edge pairs: listed, and found past the list's end (not listed)."""
        c = self.ecount.numpy()
        return dict(self_edge_pairs=int(min(c[0], self.cap)), self_edge_pairs_over=int(c[1]))
