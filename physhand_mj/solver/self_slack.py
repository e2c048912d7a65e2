"""Which skin vertices the frame's self-contact query asks about (issue 53; solver/self_contact.py
queries them): the query slack, per skin vertex how much nearer a kept skin triangle may come before
it is within ``self_margin``, used up by the moves since it was set (docs/self_collision.md "How
contact is found", step 1).

Once a frame, from the positions at its start: per skin vertex its move since the last frame in its
bone's frame (``local_motion``; per cell of a 6 mm grid the largest move of a vertex whose triangles
reach into it; per bone the largest, its skin's reach, its skin's box in its frame and longest edge:
``bone_bounds``), per pair of bones the change of their relative pose (``body_motion``, which lists
per bone the others near enough to matter), then per vertex the slack those moves could have used
(``pick_queries``): its own, the skin's deformation near it (the grid), plus for every other bone
whose skin's box (grown by its longest edge) lies within reach of the vertex the pose change and
the turn at the vertex's distance. A vertex whose slack is used up goes in the query list
(``QuerySlack.qlist``, ``qcount`` long); the others keep an empty list. The broadphase sets the slack
anew for the vertices it queries (the nearest kept triangle's distance beyond the margin, at most
REACH). A hand whose skin moves rigidly with its bones queries nothing.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.self_measures import skin_edges
from physhand_mj.solver.model import morton_code

wp.set_module_options({"enable_backward": False})

# The frame query's reach beyond self_margin: a vertex whose nearest kept triangle lay beyond the
# margin by s (its slack, at most REACH) is queried again only once the moves since could have used
# it up: its own in its bone's frame plus the largest any skin near that bone may have made seen from
# that bone (pick_queries; a hand at rest: never; docs/self_collision.md "Known limits", the cost).
REACH = 5.0e-4

# The skin's deformation is bounded near each vertex, not over its bone's whole skin: every skin
# vertex writes its move (in its bone's frame) into the cells of a grid of DEFORM_CELL that its
# triangles could reach (its box grown by its longest edge), and a vertex reads the cells within
# ``far`` of it (pick_queries). A held fist whose squeezed skin jitters then queries the skin near
# the jitter, not every vertex of the jittering bones and their neighbours. The grid is a hash table
# of DEFORM_CELLS cells per world: two cells sharing a slot only raise each other's bound.
DEFORM_CELL = 6.0e-3  # m
DEFORM_CELLS = 32768  # per world (a power of two; 128 KB)
DEFORM_NONE = wp.constant(2147483647)  # (a move past 2 m, or NaN: the bone's bound instead)
DEFORM_REACH = wp.constant(1.2e-2)  # m: a vertex reads (or writes) at most this far around it, else its bone's bound
CHUNK = 16  # skin vertices of one bone a bone_bounds thread folds into the bone's figures
# Whether pick_queries takes one world's skin vertices in the rest shape's Morton order on CUDA
# (QuerySlack.order; the CPU takes them ascending either way): H200, W = 4,096 settled, pick_queries
# 3.2 -> 2.6 ms a listing frame, the broadphase unchanged (docs/self_collision.md "How contact is found").
SPATIAL_QUEUE = True


@wp.func
def _cell_slot(ix: int, iy: int, iz: int, w: int) -> int:
    """Grid cell (ix, iy, iz) of world ``w``: its slot in the deformation table (a spatial hash)."""
    h = (wp.uint32(ix) * wp.uint32(73856093)) ^ (wp.uint32(iy) * wp.uint32(19349663)) ^ (wp.uint32(iz) * wp.uint32(83492791))
    return w * DEFORM_CELLS + int(h & wp.uint32(DEFORM_CELLS - 1))


@wp.func
def _cell_of(c: float) -> int:
    return int(wp.floor(c / DEFORM_CELL))


@wp.func
def _pose(body_pose: wp.array2d(dtype=wp.transform), b: int) -> wp.transform:
    if b < 0:
        return wp.transform_identity()
    return body_pose[0, b]


@wp.func
def _slot(b: int, w: int, nb: int) -> int:
    """Bone ``b`` (a model bone index, -1: none) of world ``w`` in the per-world bone tables: world w's
    ``nb`` bones, then its slot for the skin without a bone (the world frame)."""
    if b < 0:
        return w * (nb + 1) + nb
    return b + w  # (b = w nb + its bone in the world: w (nb + 1) + that)


@wp.kernel
def local_motion(x: wp.array(dtype=wp.vec3), skin_body: wp.array(dtype=int), body_pose: wp.array2d(dtype=wp.transform),
                 ns: int, y_last: wp.array(dtype=wp.vec3), mu: wp.array(dtype=float),
                 nbr_off: wp.array(dtype=int), nbr: wp.array(dtype=int), edge: wp.array(dtype=float),
                 deform: wp.array(dtype=int), deform_all: wp.array(dtype=int)):
    """Per skin vertex its move since the last frame's start in its bone's frame (``mu``; the skin's
    deformation, not the bones' motion; ``y_last``: where it lies in that frame now), the longest
    skin edge at it (``edge``; ``nbr``: one world's skin neighbours from ``nbr_off[v]``; ``ns`` skin
    vertices a world) and, per grid cell (``deform``, DEFORM_CELL), the largest move of a vertex whose
    triangles reach into it (the vertex's box grown by its longest edge). :func:`bone_bounds` then
    takes each bone's figures from these."""
    v = wp.tid()
    b = skin_body[v]
    y = wp.transform_point(wp.transform_inverse(_pose(body_pose, b)), x[v])
    m = wp.length(y - y_last[v])
    y_last[v] = y
    mu[v] = m
    p = x[v]
    w = v // ns
    vo = w * ns
    e = float(0.0)
    for n in range(nbr_off[v - vo], nbr_off[v - vo + 1]):
        e = wp.max(e, wp.length(x[nbr[n] + vo] - p))
    edge[v] = e
    # the move into every grid cell that a triangle with a corner here reaches (within e of the vertex)
    # (in whole nm rounded up: native integer atomics, and a cell already holding as much is not written:
    # ~100 vertices write each cell, and a float atomic max on CUDA is a compare-and-swap loop)
    mi = int(wp.ceil(wp.min(m, 2.0) * 1.0e9))
    if m >= 2.0 or m != m:  # (past int32's nm: no bound from the grid)
        mi = DEFORM_NONE
    if e > DEFORM_REACH:  # (a vertex torn from its neighbours: its move bounds every cell of its world)
        wp.atomic_max(deform_all, w, mi)
    elif mi > 0:
        for ix in range(_cell_of(p[0] - e), _cell_of(p[0] + e) + 1):
            for iy in range(_cell_of(p[1] - e), _cell_of(p[1] + e) + 1):
                for iz in range(_cell_of(p[2] - e), _cell_of(p[2] + e) + 1):
                    c = _cell_slot(ix, iy, iz, w)
                    if deform[c] < mi:
                        wp.atomic_max(deform, c, mi)


@wp.kernel
def bone_bounds(ns: int, nb: int, chunk_slot: wp.array(dtype=int),
                chunk_off: wp.array(dtype=int), bone_v: wp.array(dtype=int), y_last: wp.array(dtype=wp.vec3),
                mu: wp.array(dtype=float), edge: wp.array(dtype=float),
                body_move: wp.array(dtype=float), body_reach: wp.array(dtype=float), box: wp.array2d(dtype=int),
                bone_edge: wp.array(dtype=int)):
    """Per bone (slot :func:`_slot`) its skin's largest move (``body_move``), its farthest point from the
    bone's origin (``body_reach``), its bounding box now in the bone's frame (``box``: lower x, y, z, then
    minus the upper; in whole um, rounded outward: native integer atomics; a phalanx's skin lies along
    its bone, so this box is tighter than one in the world's axes where the finger lies at an angle to
    them) and the longest skin edge at a vertex of its skin
    (``bone_edge``, um), so that the box grown by it holds every skin triangle with a corner on the bone.
    A thread per chunk of one bone's skin vertices (one world's ``bone_v``, by bone: chunk c holds
    ``bone_v[chunk_off[c]:chunk_off[c + 1]]`` of bone slot ``chunk_slot[c]``) in each world, its figures
    folded into the bone's by one atomic each (a thread per vertex made ~170 atomics a bone contend for
    one address)."""
    tid = wp.tid()
    nc = chunk_slot.shape[0]
    w = tid // nc
    c = tid - w * nc
    vo = w * ns
    m = float(0.0)
    r = float(0.0)
    e = float(0.0)
    lo = wp.vec3i(2147483647, 2147483647, 2147483647)
    hi = wp.vec3i(2147483647, 2147483647, 2147483647)
    for i in range(chunk_off[c], chunk_off[c + 1]):
        v = bone_v[i] + vo
        m = wp.max(m, mu[v])
        y = y_last[v]  # (the vertex in its bone's frame now: local_motion)
        r = wp.max(r, wp.length(y))
        e = wp.max(e, edge[v])
        for a in range(3):
            lo[a] = wp.min(lo[a], int(wp.floor(y[a] * 1.0e6)))
            hi[a] = wp.min(hi[a], -int(wp.ceil(y[a] * 1.0e6)))
    k = w * (nb + 1) + chunk_slot[c]
    wp.atomic_max(body_move, k, m)
    wp.atomic_max(body_reach, k, r)
    for a in range(3):
        wp.atomic_min(box, k, a, lo[a])
        wp.atomic_min(box, k, a + 3, hi[a])
    wp.atomic_max(bone_edge, k, int(wp.ceil(e * 1.0e6)))


@wp.kernel
def body_motion(body_pose: wp.array2d(dtype=wp.transform), nb: int, rel_last: wp.array2d(dtype=wp.transform),
                body_move: wp.array(dtype=float), body_reach: wp.array(dtype=float), box: wp.array2d(dtype=int),
                far: float, pair_dt: wp.array2d(dtype=float), pair_turn: wp.array2d(dtype=float),
                near_n: wp.array(dtype=int), near: wp.array2d(dtype=int), pose_inv: wp.array(dtype=wp.transform)):
    """Per world w and pair of its bones (slot ``nb``: the world frame) the change of their relative
    pose since the last frame's start, seen from the first: how far the second's origin moved
    (``pair_dt``) and 2 sin(angle / 2) of its turn (``pair_turn``: a point of the second's skin at r
    from its origin moved at most its skin's deformation + pair_dt + pair_turn x r); -1 in
    ``pair_dt`` where the two bones' skins lie too far apart to matter: their bounding balls about the
    bones' origins more than ``far`` (>= slack + margin) plus both skins' largest such moves apart.
    Bones of different worlds are never paired (each world's skin lists only its own triangles).
    The second bones that do matter are listed per first (``near[o + i, :near_n[o + i]]``, in no
    set order: pick_queries takes their largest move); a slot without skin (``box`` empty: e.g. the
    world frame's, where every skin vertex has a bone) is never listed: nothing of it comes near. Per
    slot its pose's inverse (``pose_inv``: pick_queries takes each vertex into the bones' frames)."""
    w, i, j = wp.tid()
    o = w * (nb + 1)  # (world w's slots in the per-world bone tables: _slot)
    bi = w * nb + i
    bj = w * nb + j
    if i == nb:
        bi = -1
    if j == nb:
        bj = -1
    inv = wp.transform_inverse(_pose(body_pose, bi))
    if j == 0:
        pose_inv[o + i] = inv
    rel = wp.transform_multiply(inv, _pose(body_pose, bj))
    last = rel_last[o + i, j]
    rel_last[o + i, j] = rel
    dq = wp.transform_get_rotation(rel) * wp.quat_inverse(wp.transform_get_rotation(last))
    half = wp.min(wp.abs(dq[3]), 1.0)
    dt = wp.length(wp.transform_get_translation(rel) - wp.transform_get_translation(last))
    turn = 2.0 * wp.sqrt(wp.max(1.0 - half * half, 0.0))  # 2 sin(angle / 2)
    pair_turn[o + i, j] = turn
    gap = wp.length(wp.transform_get_translation(rel)) - body_reach[o + i] - body_reach[o + j]
    # (the first's skin moved at most body_move[i] in its frame, the second's at most its deformation +
    # the pair's motion at its reach: apart by more than that plus far, no point of either comes near)
    big = body_move[o + j] + dt + turn * body_reach[o + j]
    if i != j and i != nb and j != nb and gap > far + body_move[o + i] + big:
        dt = -1.0
    pair_dt[o + i, j] = dt
    if i != j and not (dt < 0.0) and box[o + j, 0] != 2147483647:
        near[o + i, wp.atomic_add(near_n, o + i, 1)] = j


@wp.kernel
def pick_queries(x: wp.array(dtype=wp.vec3), skin_body: wp.array(dtype=int),
                 mu: wp.array(dtype=float), body_move: wp.array(dtype=float), body_reach: wp.array(dtype=float),
                 box: wp.array2d(dtype=int), bone_edge: wp.array(dtype=int),
                 pair_dt: wp.array2d(dtype=float), pair_turn: wp.array2d(dtype=float),
                 near_n: wp.array(dtype=int), near_b: wp.array2d(dtype=int), pose_inv: wp.array(dtype=wp.transform),
                 deform: wp.array(dtype=int), deform_all: wp.array(dtype=int), far: float, ns: int, nb: int,
                 order: wp.array(dtype=int), slack: wp.array(dtype=float), cand_n: wp.array(dtype=int),
                 qlist: wp.array(dtype=int), qcount: wp.array(dtype=int)):
    """The vertices the frame queries: those whose slack (how much nearer a kept triangle may have
    come before it is within the margin) the moves since used up: the vertex's own in its bone's frame
    (``mu``), the skin's deformation near it (a fold of its own skin; ``deform``, the grid
    local_motion wrote, at most its bone's ``body_move``) and, per other bone of its world, how far
    that bone's skin near the vertex may have moved seen from the vertex's bone (its deformation near
    the vertex + the pair's motion, body_motion, applied at a radius). Only triangles within ``far``
    (>= slack + margin) of the vertex now matter: one farther keeps the slack whatever it did (the
    slack never grows between queries), and one within it moved at most as counted. Its corners lie
    within far + their longest edge of the vertex, so they wrote their moves into the grid cells
    within ``far`` of it, and every bone it has a corner on holds it in its skin's box grown by that
    bone's longest edge (bone_bounds; the box in the bone's frame, the vertex taken there). So a bone
    whose grown box lies farther than far counts
    nothing, and the others count their pair's turn at |vertex - the bone's origin| + far + that edge
    (or the skin's reach, if less). The others keep an empty list. Thread t of world w takes the
    world's vertex ``order[t - w ns]`` (QuerySlack.order: the queue's order)."""
    t = wp.tid()
    w = t // ns
    v = w * ns + order[t - w * ns]
    o = w * (nb + 1)
    il = _slot(skin_body[v], w, nb) - o  # (the vertex's bone in its world's tables; nb: none)
    p = x[v]
    left = slack[v] - mu[v]
    # the skin's deformation near the vertex: the largest move in the grid cells within far of it
    # (every corner of a triangle within far of it wrote its move there: local_motion; a far beyond
    # DEFORM_REACH: its bone's whole skin's). Once the moves counted use up what is left, the vertex
    # is queried: the rest is not counted (the query sets its slack anew).
    near = float(1.0e30)
    if left > 0.0 and far <= DEFORM_REACH:
        nm = deform_all[w]
        for ix in range(_cell_of(p[0] - far), _cell_of(p[0] + far) + 1):
            for iy in range(_cell_of(p[1] - far), _cell_of(p[1] + far) + 1):
                for iz in range(_cell_of(p[2] - far), _cell_of(p[2] + far) + 1):
                    nm = wp.max(nm, deform[_cell_slot(ix, iy, iz, w)])
        if nm < DEFORM_NONE:
            near = float(nm) * 1.0e-9
    m = wp.min(body_move[o + il], near)
    for k in range(near_n[o + il]):  # (the other bones whose skin could matter: body_motion)
        if left <= m:
            break
        j = near_b[o + il, k]
        dt = pair_dt[o + il, j]
        # (the nearest point of the box of bone j's triangles: its skin's box grown by its longest edge, in
        # the bone's frame (slot nb: the world's), the vertex taken there: a rigid motion keeps the distance)
        ej = float(bone_edge[o + j]) * 1.0e-6
        pl = wp.transform_point(pose_inv[o + j], p)
        q = wp.vec3(0.0)
        for c in range(3):
            q[c] = wp.clamp(pl[c], float(box[o + j, c]) * 1.0e-6 - ej, -float(box[o + j, c + 3]) * 1.0e-6 + ej)
        if wp.length(pl - q) > far:
            continue
        r = wp.min(body_reach[o + j], wp.length(pl) + far + ej)  # (|vertex - the bone's origin|)
        m = wp.max(m, wp.min(body_move[o + j], near) + dt + pair_turn[o + il, j] * r)
    sl = left - m
    slack[v] = sl
    if sl <= 0.0:
        qlist[wp.atomic_add(qcount, 0, 1)] = v
    else:
        cand_n[v] = 0


class QuerySlack:
    """The query slack's buffers and launches for W worlds (solver/self_contact.SelfContact holds
    one): :meth:`zero` (the frame's per-bone tables, with SelfContact's other counters) and
    :meth:`record` (the four launches). ``slack`` (per skin vertex, m), ``qlist`` / ``qcount`` (the
    vertices to query this frame) are what the broadphase reads; it writes ``slack`` for those it
    queries. Per world (ns1 skin vertices, nb1 bones) nb1 + 1 bone slots, the last for skin without
    a bone (the world frame)."""

    def __init__(self, model, worlds: int, ns1: int, nb1: int, faces1: np.ndarray, rest1: np.ndarray, device):
        d = device
        ns = worlds * ns1
        nbw = worlds * (nb1 + 1)
        self.n_skin, self.ns1, self.nb1, self.worlds = ns, ns1, nb1, worlds
        self.skin_body = model.skin_body
        # per vertex its position at the last frame's start in its bone's frame and its move since
        self.y_last = wp.zeros(ns, dtype=wp.vec3, device=d)
        self.mu = wp.zeros(ns, dtype=float, device=d)
        # per bone its skin's largest move, its reach, its box and longest edge at the frame's start
        self.body_move = wp.zeros(nbw, dtype=float, device=d)
        self.body_reach = wp.zeros(nbw, dtype=float, device=d)
        self.box = wp.zeros((nbw, 6), dtype=int, device=d)
        self.bone_edge = wp.zeros(nbw, dtype=int, device=d)
        self.deform = wp.zeros(worlds * DEFORM_CELLS, dtype=int, device=d)  # per grid cell the skin's largest move (nm)
        self.deform_all = wp.zeros(worlds, dtype=int, device=d)  # (per world: a vertex whose edges reach farther)
        e = skin_edges(faces1)
        e = np.concatenate([e, e[:, ::-1]])
        e = e[np.lexsort((e[:, 1], e[:, 0]))]  # (one world's skin edges both ways, by their first vertex)
        self.nbr_off = wp.array(np.concatenate([[0], np.cumsum(np.bincount(e[:, 0], minlength=ns1))]).astype(np.int32),
                                dtype=int, device=d)
        self.nbr = wp.array(e[:, 1].astype(np.int32), dtype=int, device=d)
        self.edge = wp.zeros(ns, dtype=float, device=d)  # per vertex its longest skin edge now
        # one world's skin vertices by bone slot (the last: without a bone), in chunks of at most CHUNK
        sb = model.skin_body.numpy()[:ns1]
        slot = np.where(sb < 0, nb1, sb)
        bone_v = np.argsort(slot, kind="stable")
        starts = np.concatenate([[0], np.cumsum(np.bincount(slot, minlength=nb1 + 1))])
        off, cs = [], []
        for j in range(nb1 + 1):
            for c0 in range(starts[j], starts[j + 1], CHUNK):
                off.append(c0)
                cs.append(j)
        off.append(ns1)
        self.bone_v = wp.array(bone_v.astype(np.int32), dtype=int, device=d)
        self.chunk_off = wp.array(np.asarray(off, dtype=np.int32), dtype=int, device=d)
        self.chunk_slot = wp.array(np.asarray(cs, dtype=np.int32), dtype=int, device=d)
        self.pair_dt = wp.zeros((nbw, nb1 + 1), dtype=float, device=d)  # per bone pair its motion (body_motion)
        self.pair_turn = wp.zeros((nbw, nb1 + 1), dtype=float, device=d)
        self.rel_last = wp.zeros((nbw, nb1 + 1), dtype=wp.transform, device=d)
        self.near_n = wp.zeros(nbw, dtype=int, device=d)  # per bone the other bones near enough to matter
        self.near = wp.zeros((nbw, nb1 + 1), dtype=int, device=d)
        self.pose_inv = wp.zeros(nbw, dtype=wp.transform, device=d)  # per bone slot its pose's inverse now
        self.slack = wp.zeros(ns, dtype=float, device=d)
        # the order pick_queries' threads take one world's skin vertices in: on the CPU ascending (one lane:
        # the queue, and so the lists, in vertex order); on CUDA the rest shape's Morton order, so that a
        # warp's 32 lanes are skin near each other, near the same bones and grid cells (their loops run
        # together). The asset's numbering is spatially random: 32 consecutive skin vertices span the
        # hand. (The queue then comes in the order the warps append it; the lists do not depend on it.)
        spatial = wp.get_device(d).is_cuda and SPATIAL_QUEUE
        order = np.argsort(morton_code(rest1), kind="stable") if spatial else np.arange(ns1)
        self.order = wp.array(order.astype(np.int32), dtype=int, device=d)
        self.qlist = wp.zeros(ns, dtype=int, device=d)
        self.qcount = wp.zeros(1, dtype=int, device=d)

    def zero(self) -> None:
        """The frame's per-bone tables and query count back to their start (run inside the caller's
        frame op, before :meth:`record`'s launches)."""
        self.qcount.zero_()
        self.body_move.zero_()
        self.body_reach.zero_()
        self.box.fill_(2**31 - 1)
        self.bone_edge.zero_()
        self.deform.zero_()
        self.deform_all.zero_()
        self.near_n.zero_()

    def record(self, rec, state, reach: float, cand_n) -> None:
        """The slack's four launches into the solver's frame recorder ``rec`` (each over every world);
        ``reach``: self_margin + REACH (m); ``cand_n``: the per-vertex list lengths, emptied for the
        vertices not queried."""
        ns1, nb1 = self.ns1, self.nb1
        rec.launch(local_motion, self.n_skin, [state.x, self.skin_body, state.body_pose, ns1],
                   [self.y_last, self.mu, self.nbr_off, self.nbr, self.edge, self.deform, self.deform_all])
        rec.launch(bone_bounds, self.worlds * self.chunk_slot.shape[0],
                   [ns1, nb1, self.chunk_slot, self.chunk_off, self.bone_v, self.y_last, self.mu, self.edge],
                   [self.body_move, self.body_reach, self.box, self.bone_edge])
        rec.launch(body_motion, (self.worlds, nb1 + 1, nb1 + 1), [state.body_pose, nb1],
                   [self.rel_last, self.body_move, self.body_reach, self.box, reach, self.pair_dt, self.pair_turn, self.near_n,
                    self.near, self.pose_inv])
        rec.launch(pick_queries, self.n_skin,
                   [state.x, self.skin_body, self.mu, self.body_move, self.body_reach, self.box,
                    self.bone_edge, self.pair_dt, self.pair_turn, self.near_n, self.near, self.pose_inv, self.deform, self.deform_all,
                    reach, ns1, nb1, self.order],
                   [self.slack, cand_n, self.qlist, self.qcount])
