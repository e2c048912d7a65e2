"""Skin self-collision (issue 53; ``Config.self_collision``): one part of the hand's skin kept on the
outward side of another's.

Found once a frame, resolved every substep (docs/self_collision.md):

    frame start   the skin's BVH (a wp.Mesh over the state's positions) refit; per skin vertex the
                  skin triangles within ``self_margin`` (mesh_query_aabb, then the exact distance),
                  minus the rest filter, kept in a per-vertex table of SLOTS; the vertices with any
                  listed in a compact list, and every vertex a listed pair touches in another
    each substep  after the constraint groups (and before the object contact stage): per listed
                  vertex, its nearest listed triangle now; where the vertex lies less than
                  ``self_thickness`` in front of it (or behind it), an XPBD vertex-triangle
                  correction (hard, mass-weighted between the vertex and the triangle's three
                  vertices by the closest point's barycentrics) toward ``self_thickness`` in front;
                  corrections summed by atomics and averaged per vertex (Jacobi), ``self_passes``
                  times; the flesh behind follows through the tets in the next substep

The rest filter (computed from the rest shape, per candidate, no table): a pair is never listed
where the vertex is one of the triangle's or lies within ``self_rest_gap`` of it at rest: the webs,
the skin around a crease, a vertex and the triangles near it along the surface. At rest the nearest
skin of another finger lies 9.7 mm away (the middle and ring fingers' middle phalanges) and the
webs' two sides 2.1-2.6 mm, so the open hand lists nothing.

A frame whose list is empty runs no substep work (CPU: list launches of zero threads are skipped;
``Solver.last_activity["self_pairs"]`` reports the count).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.closest import closest_on_triangle

wp.set_module_options({"enable_backward": False})

# The fold rule (docs/self_collision.md): a vertex and a triangle nearer than self_rest_gap at rest
# are still a pair where the skin has folded onto itself (the vertex's normal and the triangle's
# now at more than a right angle: cos < FOLD_COS) and they lay at least FOLD_GAP apart at rest.
# Power grasp: 61 -> 37 vertices inside at 0.2 mm, inverted tets 572 -> 546 (the rest shape is flat
# there: nothing folded, the open hand lists nothing).
FOLD_COS = wp.constant(0.0)
FOLD_GAP = 1.0e-3  # m: ~ a third of a skin edge; closer at rest is the vertex's own one-ring

SLOTS = 16  # listed triangles per skin vertex at most (the nearest kept: 3 mm around a vertex holds ~6-12)


@wp.kernel
def clear_marks(n: wp.array(dtype=int), involved: wp.array(dtype=int), mark: wp.array(dtype=int)):
    """Forget the last frame's touched vertices (over its involved list, ``n[0]`` long)."""
    i = wp.tid()
    if i < n[0]:
        mark[involved[i]] = 0


@wp.func
def _touch(i: int, mark: wp.array(dtype=int), involved: wp.array(dtype=int), counts: wp.array(dtype=int)):
    if wp.atomic_add(mark, i, 1) == 0:
        s = wp.atomic_add(counts, 1, 1)
        involved[s] = i


@wp.kernel
def broadphase(mesh: wp.uint64, x: wp.array(dtype=wp.vec3), rest: wp.array(dtype=wp.vec3),
               faces: wp.array2d(dtype=int), rest_ball: wp.array(dtype=wp.vec4), margin: float, rest_gap: float,
               vn_now: wp.array(dtype=wp.vec3), fold_gap: float,
               cand: wp.array2d(dtype=int), cand_d: wp.array2d(dtype=float), cand_n: wp.array(dtype=int),
               vlist: wp.array(dtype=int), involved: wp.array(dtype=int), mark: wp.array(dtype=int),
               counts: wp.array(dtype=int)):
    """Per skin vertex, the skin triangles within ``margin`` that the rest filter keeps (the nearest
    SLOTS); counts: [listed vertices, involved vertices, pairs, pairs dropped for want of a slot]."""
    v = wp.tid()
    p = x[v]
    pr = rest[v]
    r = wp.vec3(margin, margin, margin)
    q = wp.mesh_query_aabb(mesh, p - r, p + r)
    t = int(0)
    n = int(0)
    while wp.mesh_query_aabb_next(q, t):
        a = faces[t, 0]
        b = faces[t, 1]
        c = faces[t, 2]
        if a == v or b == v or c == v:
            continue
        # the fold rule: the skin folded onto itself (a crease closed by flexion), the vertex's normal
        # now against the triangle's, is a pair from fold_gap apart at rest (flat there: none at rest)
        fnow = wp.cross(x[b] - x[a], x[c] - x[a])
        folded = wp.dot(vn_now[v], fnow) < FOLD_COS * wp.length(vn_now[v]) * wp.length(fnow)
        # the rest filter's cheap half first: a triangle whose rest bounding ball lies within
        # rest_gap (folded: fold_gap) of the vertex at rest (the surface around it: most of what the box holds)
        ball = rest_ball[t]
        rfar = wp.length(pr - wp.vec3(ball[0], ball[1], ball[2])) + ball[3]  # an upper bound on the rest distance
        if rfar < rest_gap and (not folded or rfar < fold_gap):
            continue
        uv = closest_on_triangle(x[a], x[b], x[c], p)
        d = wp.length(p - (uv[0] * x[a] + uv[1] * x[b] + (1.0 - uv[0] - uv[1]) * x[c]))
        if d > margin:
            continue
        # the rest filter: pairs near each other at rest (webs, creases, the surface around the vertex)
        ur = closest_on_triangle(rest[a], rest[b], rest[c], pr)
        qr = ur[0] * rest[a] + ur[1] * rest[b] + (1.0 - ur[0] - ur[1]) * rest[c]
        dr = wp.length(pr - qr)
        if dr < rest_gap and (not folded or dr < fold_gap):
            continue
        if n < SLOTS:
            cand[v, n] = t
            cand_d[v, n] = d
            n += 1
        else:  # full: replace the farthest if this one is nearer
            far = int(0)
            for k in range(1, SLOTS):
                if cand_d[v, k] > cand_d[v, far]:
                    far = k
            if d < cand_d[v, far]:
                cand[v, far] = t
                cand_d[v, far] = d
            wp.atomic_add(counts, 3, 1)
    cand_n[v] = n
    if n > 0:
        s = wp.atomic_add(counts, 0, 1)
        vlist[s] = v
        wp.atomic_add(counts, 2, n)
        _touch(v, mark, involved, counts)
        for k in range(n):
            tk = cand[v, k]
            _touch(faces[tk, 0], mark, involved, counts)
            _touch(faces[tk, 1], mark, involved, counts)
            _touch(faces[tk, 2], mark, involved, counts)


@wp.func
def _room(i: int, dp: wp.vec3, x: wp.array(dtype=wp.vec3), vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
          tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float), keep: float) -> float:
    """The share t in [0, 1] of the move dp of vertex i that keeps each of its tets' signed volume at
    least ``keep`` x its rest volume (the volume is linear in one vertex's position)."""
    t = float(1.0)
    for k in range(vt_off[i], vt_off[i + 1]):
        e = vt[k]
        a = tets[e, 0]
        b = tets[e, 1]
        c = tets[e, 2]
        d = tets[e, 3]
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


@wp.kernel
def vertex_normals(x: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=int), vn: wp.array(dtype=wp.vec3)):
    t = wp.tid()
    a = faces[t, 0]
    b = faces[t, 1]
    c = faces[t, 2]
    n = wp.cross(x[b] - x[a], x[c] - x[a])
    wp.atomic_add(vn, a, n)
    wp.atomic_add(vn, b, n)
    wp.atomic_add(vn, c, n)


@wp.kernel
def resolve(n: wp.array(dtype=int), x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), faces: wp.array2d(dtype=int),
            vlist: wp.array(dtype=int), cand: wp.array2d(dtype=int), cand_n: wp.array(dtype=int),
            thickness: float, depth: float, pick: int, nearest: wp.array(dtype=int), keep: float, vt_off: wp.array(dtype=int), vt: wp.array(dtype=int),
            tets: wp.array2d(dtype=int), vol0: wp.array(dtype=float),
            delta: wp.array(dtype=wp.vec3), hits: wp.array(dtype=int), active: wp.array(dtype=int)):
    """Per listed vertex: its nearest listed triangle now (``pick``: found and kept in ``nearest``,
    else the one kept by the substep's first pass); closer than ``thickness`` in front (or behind
    it, up to ``depth``): the hard vertex-triangle correction into ``delta`` / ``hits``."""
    i = wp.tid()
    if i >= n[0]:
        return
    v = vlist[i]
    p = x[v]
    best = int(-1)
    if pick != 0:
        bd = float(1.0e30)
        for k in range(cand_n[v]):
            t = cand[v, k]
            uv = closest_on_triangle(x[faces[t, 0]], x[faces[t, 1]], x[faces[t, 2]], p)
            q = uv[0] * x[faces[t, 0]] + uv[1] * x[faces[t, 1]] + (1.0 - uv[0] - uv[1]) * x[faces[t, 2]]
            d = wp.length(p - q)
            if d < bd:
                bd = d
                best = t
        nearest[v] = best
    else:
        best = nearest[v]
    if best < 0:
        return
    a = faces[best, 0]
    b = faces[best, 1]
    c = faces[best, 2]
    xa = x[a]
    xb = x[b]
    xc = x[c]
    bu = closest_on_triangle(xa, xb, xc, p)
    nrm = wp.cross(xb - xa, xc - xa)
    ln = wp.length(nrm)
    if ln < 1.0e-12:
        return
    nrm = nrm / ln
    wa = bu[0]
    wb = bu[1]
    wc = 1.0 - bu[0] - bu[1]
    q = wa * xa + wb * xb + wc * xc
    s = wp.dot(p - q, nrm)
    if s >= thickness or s < -depth:
        return
    w = inv_mass[v] + wa * wa * inv_mass[a] + wb * wb * inv_mass[b] + wc * wc * inv_mass[c]
    if w <= 0.0:
        return
    dl = (thickness - s) / w
    if keep > 0.0:  # Tuning.self_tet_keep: no move that flattens a tet of the vertex or a corner past it
        tk = _room(v, inv_mass[v] * dl * nrm, x, vt_off, vt, tets, vol0, keep)
        tk = wp.min(tk, _room(a, -wa * inv_mass[a] * dl * nrm, x, vt_off, vt, tets, vol0, keep))
        tk = wp.min(tk, _room(b, -wb * inv_mass[b] * dl * nrm, x, vt_off, vt, tets, vol0, keep))
        tk = wp.min(tk, _room(c, -wc * inv_mass[c] * dl * nrm, x, vt_off, vt, tets, vol0, keep))
        dl = dl * tk
    wp.atomic_add(delta, v, inv_mass[v] * dl * nrm)
    wp.atomic_add(hits, v, 1)
    if inv_mass[a] > 0.0:
        wp.atomic_add(delta, a, -wa * inv_mass[a] * dl * nrm)
        wp.atomic_add(hits, a, 1)
    if inv_mass[b] > 0.0:
        wp.atomic_add(delta, b, -wb * inv_mass[b] * dl * nrm)
        wp.atomic_add(hits, b, 1)
    if inv_mass[c] > 0.0:
        wp.atomic_add(delta, c, -wc * inv_mass[c] * dl * nrm)
        wp.atomic_add(hits, c, 1)
    wp.atomic_add(active, 0, 1)


@wp.kernel
def apply(n: wp.array(dtype=int), involved: wp.array(dtype=int), x: wp.array(dtype=wp.vec3), delta: wp.array(dtype=wp.vec3),
          hits: wp.array(dtype=int)):
    """The pass's corrections, averaged per vertex (over the involved list), then zeroed."""
    k = wp.tid()
    if k >= n[0]:
        return
    i = involved[k]
    h = hits[i]
    if h > 0:
        x[i] = x[i] + delta[i] / float(h)
        delta[i] = wp.vec3()
        hits[i] = 0


class SelfContact:
    """The self-collision's buffers and launches for one body of one world (Solver holds one where
    ``Config.self_collision``): :meth:`record_frame` (the frame's list) and :meth:`record_stage`
    (a substep's correction) record into the solver's frame."""

    def __init__(self, model, config, device):
        if int(getattr(model, "worlds", 1)) != 1:
            raise ValueError("Config.self_collision runs on one hand (a Solver of one world), not batched worlds")
        self.model, self.config, self.device = model, config, device
        d = device
        ns = int(model.n_skin)
        self.n_skin = ns
        faces = np.asarray(model.skin_faces.numpy() if hasattr(model.skin_faces, "numpy") else model.skin_faces)
        self.faces = wp.array(faces.astype(np.int32), dtype=int, device=d)
        self.indices = wp.array(faces.astype(np.int32).ravel(), dtype=int, device=d)
        rest = model.rest_x.numpy()[:ns].astype(np.float64)
        self.rest = wp.array(rest, dtype=wp.vec3, device=d)
        self.vn_now = wp.zeros(ns, dtype=wp.vec3, device=d)  # the skin's area-weighted normals at the frame's start
        centre = rest[faces].mean(axis=1)  # per triangle its rest centroid and the farthest corner from it
        radius = np.linalg.norm(rest[faces] - centre[:, None], axis=2).max(axis=1)
        self.rest_ball = wp.array(np.hstack([centre, radius[:, None]]).astype(np.float32), dtype=wp.vec4, device=d)
        self.cand = wp.zeros((ns, SLOTS), dtype=int, device=d)
        self.cand_d = wp.zeros((ns, SLOTS), dtype=float, device=d)
        self.cand_n = wp.zeros(ns, dtype=int, device=d)
        self.vlist = wp.zeros(ns, dtype=int, device=d)
        self.involved = wp.zeros(ns, dtype=int, device=d)
        self.mark = wp.zeros(ns, dtype=int, device=d)
        self.delta = wp.zeros(ns, dtype=wp.vec3, device=d)
        self.hits = wp.zeros(ns, dtype=int, device=d)
        self.nearest = wp.zeros(ns, dtype=int, device=d)  # per listed vertex its nearest triangle this substep
        # [listed vertices, involved vertices, pairs, pairs over SLOTS]; [corrections this frame]
        self.counts = wp.zeros(4, dtype=int, device=d)
        self.active = wp.zeros(1, dtype=int, device=d)
        self.vcount = wp.zeros(1, dtype=int, device=d)  # (the list launches read their length here)
        self.icount = wp.zeros(1, dtype=int, device=d)
        self._meshes: dict = {}
        # Tuning.self_tet_keep: every tet of every skin vertex (CSR: vt_off, vt) and its rest volume
        tets = np.asarray(model.tet_ids.numpy()).reshape(-1, 4)
        self.tets = wp.array(tets.astype(np.int32), dtype=int, device=d)
        rx = model.rest_x.numpy().astype(np.float64)
        A, B, C, D = (rx[tets[:, k]] for k in range(4))
        self.vol0 = wp.array(np.einsum("ij,ij->i", B - A, np.cross(C - A, D - A)).astype(np.float32), dtype=float, device=d)
        sk = tets < ns
        tv = np.repeat(np.arange(len(tets)), 4)[sk.ravel()]
        vv = tets.ravel()[sk.ravel()]
        order = np.argsort(vv, kind="stable")
        cnt = np.bincount(vv, minlength=ns)
        self.vt_off = wp.array(np.concatenate([[0], np.cumsum(cnt)]).astype(np.int32), dtype=int, device=d)
        self.vt = wp.array(tv[order].astype(np.int32), dtype=int, device=d)

    def mesh(self, state) -> wp.Mesh:
        """The skin's BVH over ``state.x`` (made once per state; refit every frame)."""
        m = self._meshes.get(id(state))
        if m is None:
            m = self._meshes[id(state)] = wp.Mesh(points=state.x, indices=self.indices)
        return m

    def record_frame(self, rec, state) -> None:
        """The frame's list: last frame's marks cleared, the BVH refit, the broadphase."""
        cfg, d = self.config, self.device
        mesh = self.mesh(state)
        rec.launch(clear_marks, self.n_skin, [self.icount, self.involved], [self.mark], count=self.icount)
        rec.ops.append(lambda: self.counts.zero_())
        rec.ops.append(lambda: self.active.zero_())
        rec.ops.append(mesh.refit)
        rec.ops.append(lambda: self.vn_now.zero_())
        rec.launch(vertex_normals, self.faces.shape[0], [state.x, self.faces], [self.vn_now])
        rec.launch(broadphase, self.n_skin,
                   [mesh.id, state.x, self.rest, self.faces, self.rest_ball, float(cfg.self_margin), float(cfg.self_rest_gap),
                    self.vn_now, float(FOLD_GAP)],
                   [self.cand, self.cand_d, self.cand_n, self.vlist, self.involved, self.mark, self.counts])
        # the list lengths the substeps' list launches read (CPU: on the host for free)
        rec.ops.append(lambda: (wp.copy(self.vcount, self.counts, 0, 0, 1), wp.copy(self.icount, self.counts, 0, 1, 1)))

    def record_stage(self, rec, state, inv_mass) -> None:
        """A substep's correction: ``self_passes`` x (resolve, apply) over the frame's lists."""
        cfg = self.config
        for k in range(cfg.self_passes):
            rec.launch(resolve, self.n_skin,
                       [self.vcount, state.x, inv_mass, self.faces, self.vlist, self.cand, self.cand_n,
                        float(cfg.self_thickness), float(cfg.self_depth), int(k == 0), self.nearest,
                        float(cfg.self_tet_keep), self.vt_off, self.vt, self.tets, self.vol0],
                       [self.delta, self.hits, self.active], count=self.vcount)
            rec.launch(apply, self.n_skin, [self.icount, self.involved], [state.x, self.delta, self.hits], count=self.icount)

    def report(self) -> dict:
        """The last frame's figures: listed vertices and pairs, corrections made (summed over passes)."""
        c = self.counts.numpy()
        return dict(self_vertices=int(c[0]), self_pairs=int(c[2]), self_pairs_over=int(c[3]),
                    self_corrections=int(self.active.numpy()[0]))
