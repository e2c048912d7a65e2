"""How far the object's feature lists reach, and the frame's check of it (``Config.tuning.feature_slack``).

How far the lists reach (``Config.tuning.feature_slack``, since 2026-11-27). Within a frame the objects stay
where the frame put them and only the skin moves. A feature point d from the skin at the frame's
start (``near_features`` measures d) is listed when d <= s / 2 + contact_margin, s its world's
slack (``config.FEATURE_LIST_SHARE`` s: a half by default since 2026-11-27's fourth session, the whole
slack before), or when the skin's pseudo normals put it inside; its patch holds the skin triangles
within r = d + s of it (both at most contact_frame_margin). If no skin vertex moves more than D with
2 D < s, that is exact: the point's closest triangle at the start is in the patch and stays within
d + D of it, a triangle outside the patch stays farther than r - D, and an unlisted point (farther
than s / 2 + contact_margin) never comes within contact_margin: the same bound on D serves both.
The frame checks this at its end, locally (``skin_motion``, ``certify_features``): a skin vertex
that moved half the slack or more spoils a point only if its move could bring a triangle outside
the patch nearer than the point's closest one, or an unlisted point within contact_margin or
inside, and its path (start to end, straight) passed near enough to the point for one of its
triangles to do so. A world with such a point is reported (``feature_slack_exceeded``). The next
frame's slack is 2.5 x the largest move near the points (their closest triangles', and the fast
vertices' that started near enough to matter: ``next_slack``), at least SLACK_DECAY x this frame's
and Config.tuning.feature_slack, at most contact_frame_margin. Every world lists with
contact_frame_margin until it has listed a point; a world that lists none keeps its slack. The
moves are the frame's end positions against its start, not the paths between.

Kernels that take arrays (``skin_motion``, ``skin_reach``, ``certify_features``, ``next_slack``) and
:class:`SlackCheck`, held by a :class:`~physhand_mj.contact.contact.Contact` (``Contact.slack_check``),
owns their buffers, records them at a frame's end and reports them after the frame's sync.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.data import SlackBuffers
from physhand_mj.contact.inside import object_point

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

UNLISTED = wp.constant(1.0e30)  # pt_dist of a point the frame did not list


@wp.struct
class SkinMoves:
    """The frame's skin moves, per vertex and per world (:func:`skin_motion`, :func:`skin_reach`;
    read by :func:`certify_features` and :func:`next_slack`)."""

    x_start: wp.array(dtype=wp.vec3)  # (S,) m: the skin at the frame's start
    vmotion: wp.array(dtype=float)  # (S,) m: each skin vertex's move over the frame
    motion: wp.array(dtype=float)  # (W,) m: the world's largest skin move in the frame
    fast: wp.array2d(dtype=int)  # (W, S / W): per world its fast vertices (moved half the slack or more)
    fast_count: wp.array(dtype=int)  # (W,): how many (counted past the row's end)
    reach: wp.array(dtype=float)  # (W,) m: the world's longest skin edge at the frame's start or end


def skin_moves(n_skin: int, worlds: int, device) -> SkinMoves:
    """A zeroed :class:`SkinMoves`: room in ``fast`` for every skin vertex of a world (a list that
    overflowed made its world's check fail unasked; the shipped demo's third frame has 325 fast
    vertices); only the fast ones are walked."""
    m = SkinMoves()
    m.x_start = wp.zeros(n_skin, dtype=wp.vec3, device=device)
    m.vmotion = wp.zeros(n_skin, dtype=float, device=device)
    m.motion = wp.zeros(worlds, dtype=float, device=device)
    m.fast = wp.zeros((worlds, max(-(-n_skin // worlds), 1)), dtype=int, device=device)
    m.fast_count = wp.zeros(worlds, dtype=int, device=device)
    m.reach = wp.zeros(worlds, dtype=float, device=device)
    return m


@wp.kernel
def skin_motion(x: wp.array(dtype=wp.vec3), vertex_world: wp.array(dtype=int), slack: wp.array(dtype=float),
                moves: SkinMoves):
    """After a frame: how far (m) each skin vertex moved since the frame's start (``vmotion``), the
    world's largest move (``motion``, atomic max) and its *fast* vertices, those that moved half
    its slack or more (``fast[w]``, ``fast_count[w]`` counts past the row's end). A non-finite
    vertex counts 0 (the guard's)."""
    i = wp.tid()
    d = wp.length(x[i] - moves.x_start[i])
    if not (d == d):
        d = 0.0
    moves.vmotion[i] = d
    w = vertex_world[i]
    if d > moves.motion[w]:  # (a read first: a world's vertices all hit one address, most below its max)
        wp.atomic_max(moves.motion, w, d)
    if d >= 0.5 * slack[w]:
        j = wp.atomic_add(moves.fast_count, w, 1)
        if j < moves.fast.shape[1]:
            moves.fast[w, j] = i


@wp.func
def longest_edge(faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), t: int):
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    return wp.max(wp.length(b - a), wp.max(wp.length(c - b), wp.length(a - c)))


@wp.kernel
def skin_reach(faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), vertex_world: wp.array(dtype=int),
               moves: SkinMoves):
    """Per world the longest skin edge (m) at the frame's start or end (atomic max): how far a
    triangle's points lie from its vertices then, and anywhere on the straight way between, where
    each edge is a blend of its two ends (:func:`certify_features`, which reads it only for a
    world's fast vertices: a world without one is skipped and keeps 0). A non-finite edge counts 0."""
    t = wp.tid()
    if moves.fast_count[vertex_world[faces[t, 0]]] == 0:
        return
    e0 = longest_edge(faces, moves.x_start, t)
    e = longest_edge(faces, x, t)
    if not (e == e):
        e = 0.0
    if e0 == e0:
        e = wp.max(e, e0)
    w = vertex_world[faces[t, 0]]
    if e > moves.reach[w]:  # (as in skin_motion: the atomic only where it can raise the max)
        wp.atomic_max(moves.reach, w, e)


@wp.func
def plane_crossed(p: wp.vec3, faces: wp.array2d(dtype=int), x0: wp.array(dtype=wp.vec3), x1: wp.array(dtype=wp.vec3),
                  f: int):
    """Whether p lies on the other side of triangle ``f``'s plane at the end (``x1``) than at the
    start (``x0``), or on it: the triangle may have passed through p."""
    a0 = x0[faces[f, 0]]
    a1 = x1[faces[f, 0]]
    s0 = wp.dot(p - a0, wp.cross(x0[faces[f, 1]] - a0, x0[faces[f, 2]] - a0))
    s1 = wp.dot(p - a1, wp.cross(x1[faces[f, 1]] - a1, x1[faces[f, 2]] - a1))
    return s0 * s1 <= 0.0


@wp.func
def segment_distance(p: wp.vec3, a: wp.vec3, b: wp.vec3):
    """The distance (m) from p to the segment from a to b."""
    ab = b - a
    t = float(0.0)
    n = wp.dot(ab, ab)
    if n > 0.0:
        t = wp.clamp(wp.dot(p - a, ab) / n, 0.0, 1.0)
    return wp.length(a + t * ab - p)


@wp.kernel
def certify_features(
    feature: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    geom_count: wp.array(dtype=int),
    geoms_per_world: int,
    pt_dist: wp.array(dtype=float),
    pt_face: wp.array(dtype=int),
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    moves: SkinMoves,
    slack: wp.array(dtype=float),
    margin: float,
    keep: float,
    near_motion: wp.array(dtype=float),
    failed: wp.array(dtype=int),
):
    """After a frame, per object feature point p: did its list and patch hold (module docstring)?

    A point's scans matter while it is within ``keep`` of the skin or inside it. Take each vertex
    on the straight way from its start to its end (the check knows no more of its path). A triangle
    T that comes within a distance ``near`` of p, or passes through it, has a vertex v that moved at
    least as far as that point of T did, and v's way passed within near + ``reach[w]`` of p (m, the
    world's longest skin edge at the start or the end: :func:`skin_reach`; an edge on the way is a
    blend of its two ends, no longer than the longer); so v also started within near + |its move| +
    reach. Listed (distance d, closest triangle C at the start, patch radius r = min(margin, d +
    s)), outside at the start, on the same side of C's plane at both ends: a triangle outside the
    patch (farther than r then) that comes within near = keep moved a point at least r - keep.
    Inside at the start (by the pseudo normals), or on C's other side at the end (C may have
    passed through p: :func:`plane_crossed`): it must also not come nearer than C, which moved at
    most D_C (its vertices' largest move), near = max(keep, d + D_C), a move of r - near. Not
    listed, outside: a move of d - keep, d its distance, measured where it lies within keep + s
    (past the list's keep + config.FEATURE_LIST_SHARE s: ``pt_face`` -1; at least s / 2), else
    taken as min(margin, keep + s). The frame's fast vertices (half the slack or more) are asked;
    where a point's needed move is below that threshold, or the world has more fast vertices than
    the list holds, the vertices not asked could spoil it: it fails without asking, unless the
    world's largest move (``motion[w]``, :func:`skin_motion`'s) is shorter than the point's need.
    A failure sets ``failed[w]``; D_C of the listed points, and the move of every fast vertex that started near enough to a point for its
    move to matter there, go into ``near_motion[w]`` (their largest: the next slack's measure)."""
    i = feature[wp.tid()]
    if pts_geom[i] >= geom_count[0]:
        return
    w = pts_geom[i] // geoms_per_world
    s = slack[w]
    n = moves.fast_count[w]
    sd = pt_dist[i]
    p = object_point(i, pts, pts_geom, pose)
    near = keep  # how near the spoiling triangle must come
    need = wp.min(margin, keep + s) - keep  # the move a vertex needs to spoil this point's list
    if sd < UNLISTED and pt_face[i] < 0:  # not listed, measured d from the skin: past keep + share x s,
        need = wp.max(sd - keep, 0.5 * s)  # share >= 1/2 (a point just past it is not failed by rounding)
    elif sd < UNLISTED:
        d = wp.abs(sd)
        f = pt_face[i]
        dc = wp.max(moves.vmotion[faces[f, 0]], wp.max(moves.vmotion[faces[f, 1]], moves.vmotion[faces[f, 2]]))
        wp.atomic_max(near_motion, w, dc)
        if sd < 0.0 or plane_crossed(p, faces, moves.x_start, x, f):  # (inside, or C may have crossed p)
            near = wp.max(keep, d + dc)
        need = wp.min(margin, d + s) - near
    # a vertex not asked (its move below the list's threshold, or past the list's end) spoils the point
    # only if it moved as far as the point needs: none did where the world's largest move is shorter
    fail = (need < 0.5 * s or n > moves.fast.shape[1]) and moves.motion[w] >= need
    for j in range(wp.min(n, moves.fast.shape[1])):
        v = moves.fast[w, j]
        mv = moves.vmotion[v]
        if wp.length(moves.x_start[v] - p) <= near + mv + moves.reach[w]:  # near enough for its move to matter here
            wp.atomic_max(near_motion, w, mv)
            if mv >= need and segment_distance(p, moves.x_start[v], x[v]) <= near + moves.reach[w]:  # (its way passed
                fail = True  # near enough for one of its triangles to come within ``near`` of p)
    if fail:
        failed[w] = 1


# the next slack is at least this much of the last (moves under half of it go unseen: next_slack)
SLACK_DECAY = wp.constant(0.8)


@wp.kernel
def next_slack(
    moves: SkinMoves,
    near_motion: wp.array(dtype=float),
    failed: wp.array(dtype=int),
    world_count: wp.array(dtype=int),
    least: float,
    most: float,
    slack: wp.array(dtype=float),
    report: wp.array2d(dtype=float),
):
    """Per world, after a frame: ``report[w]`` = (the slack it was listed with, the skin's largest
    move, 1 where :func:`certify_features` failed a point), and the next frame's slack: 2.5 x the
    largest move near the feature points (``near_motion``; the world's largest move after a failed
    frame or one with more fast vertices than its ``fast`` row holds, whose moves were not all seen), at least
    SLACK_DECAY x this frame's (a move under half the slack was not measured) and ``least``, at most
    ``most`` (m). A world that listed no point and failed none keeps its slack (so a frame whose
    contact block runs with nothing near changes nothing: Config.execution.skip_idle gives the same lists)."""
    w = wp.tid()
    s = slack[w]
    m = near_motion[w]
    if failed[w] != 0 or moves.fast_count[w] > moves.fast.shape[1]:
        m = wp.max(m, moves.motion[w])
    report[w, 0] = s
    report[w, 1] = moves.motion[w]
    report[w, 2] = float(failed[w])
    if world_count[w] > 0 or failed[w] != 0:
        slack[w] = wp.min(wp.max(wp.max(least, 2.5 * m), SLACK_DECAY * s), most)


class SlackCheck:
    """The feature lists' slack of a :class:`~physhand_mj.contact.contact.Contact` and the frame
    end's check of it: its buffers (:class:`~physhand_mj.contact.data.SlackBuffers`, ``data``), the
    frame start's resets, the frame end's check and its reports. ``points``: the contact's object
    points (ObjectPoints); made with the contact's feature lists (its first recorded frame)."""

    def __init__(self, model, objects, config, points, worlds: int, geoms_per_world: int):
        self.model, self.objects, self.config, self.points = model, objects, config, points
        self.worlds, self.geoms_per_world = worlds, geoms_per_world
        self.data = make_slack_buffers(model, config, points, worlds)
        self.warned = False  # (feature_motion warns once)

    def restart(self) -> None:
        """A new episode: every world lists with contact_frame_margin again (its first frame's slack),
        as after construction (so an episode does not depend on how fast the last one moved)."""
        self.data.slack.fill_(float(self.config.contact_frame_margin))

    def start_ops(self, state) -> list:
        """The frame start's ops, before the feature list: the per-frame resets and the skin's copy."""
        b = self.data
        x_start, x, n_skin, pt_dist = b.moves.x_start, state.x, self.model.n_skin, b.pt_dist
        mv = b.moves
        return [mv.motion.zero_, mv.fast_count.zero_, b.near_motion.zero_, b.failed.zero_,
                mv.reach.zero_, b.world_listed.zero_, lambda: pt_dist.fill_(UNLISTED),
                lambda: wp.copy(x_start, x, count=n_skin)]

    def record_frame_end(self, rec, state) -> None:
        """At the end of a frame with listed feature points: how far the skin moved in it, per
        world, against the slack its feature lists were made with, and the next frame's slack."""
        m, cfg, pts, b = self.model, self.config, self.points, self.data
        rec.launch(skin_motion, m.n_skin, [state.x, m.vertex_world, b.slack], [b.moves])
        rec.launch(skin_reach, m.skin_faces.shape[0], [m.skin_faces, state.x, m.vertex_world], [b.moves])
        rec.launch(certify_features, pts.n_features,
                   [pts.feature, pts.pts, pts.geom, self.objects.pose, self.objects.count, self.geoms_per_world,
                    b.pt_dist, b.pt_face, m.skin_faces, state.x, b.moves, b.slack, float(cfg.contact_frame_margin),
                    float(cfg.contact_margin)],
                   [b.near_motion, b.failed])
        rec.launch(next_slack, self.worlds, [b.moves, b.near_motion, b.failed, b.world_listed, float(cfg.feature_slack),
                                             float(cfg.contact_frame_margin)],
                   [b.slack, b.report])

    def copy_report(self) -> None:
        """Start the report's device-to-host copy (the frame's sync waits for it)."""
        wp.copy(self.data.report_host, self.data.report)

    def feature_motion(self, ran: bool = True, warn: bool = True) -> dict:
        """The last frame, worst world (after the frame's sync; Config.tuning.feature_slack, this module):
        ``feature_slack_mm``, the slack its feature lists were made with (m -> mm), ``skin_motion_mm``,
        the skin's largest move in it, and ``feature_slack_exceeded``, the worlds in which a skin
        vertex moved far enough, near enough to a feature point, that the point's list or patch could
        have missed a skin triangle (warned about once where the lists had been cut short of
        contact_frame_margin, unless ``warn`` is False: Solver.warn_feature_slack, off while SoftHand
        settles, which moves the bones on purpose; the count is reported either way). A frame that
        did not run its contact block (``ran`` False: nothing near) made no lists: its move and count
        are 0, its slack the last lists'."""
        r = self.data.report_host.numpy()
        if not ran:
            return dict(feature_slack_mm=round(float(r[:, 0].max()) * 1e3, 4), skin_motion_mm=0.0,
                        feature_slack_exceeded=0)
        over = int(np.count_nonzero(r[:, 2]))
        # (warned where the lists were cut short of contact_frame_margin: at it they are the frame
        # broadphase's own, as before the slack; the count says it either way)
        if over and warn and not self.warned and np.any(r[r[:, 2] > 0, 0] < self.config.contact_frame_margin):
            from physhand_mj.warn import warn_user

            self.warned = True
            w = int(np.flatnonzero(r[:, 2])[0])
            want = min(2.5 * float(r[w, 1]), self.config.contact_frame_margin)
            warn_user(f"contact: the skin moved up to {r[w, 1] * 1e3:.2f} mm in one frame, near enough to an "
                      f"object's feature points to spoil their lists, made for moves under {r[w, 0] * 5e2:.2f}-"
                      f"{r[w, 0] * 1e3:.2f} mm (half to all of the lists' slack, which grows after such a frame from "
                      f"its least, Config.tuning.feature_slack): in that frame those points' contact may have missed a "
                      f"closer skin triangle. For a hand that moves this fast set Config.tuning.feature_slack={want:.3g} "
                      f"(m, 2.5 x the move) or shorten Config.frame_dt")
        return dict(feature_slack_mm=round(float(r[:, 0].max()) * 1e3, 4),
                    skin_motion_mm=round(float(r[:, 1].max()) * 1e3, 4), feature_slack_exceeded=over)

    def feature_motion_worlds(self, ran: bool = True) -> list:
        """Per world, 1 where the last frame's feature-list check failed (:meth:`feature_motion`),
        else 0 (also in a frame whose contact block did not run)."""
        if not ran:
            return [0] * self.worlds
        return [int(v) for v in self.data.report_host.numpy()[:, 2]]


def make_slack_buffers(model, config, points, worlds: int) -> SlackBuffers:
    """Per listed feature its distance to the skin at the frame's start; per object point its signed
    distance and closest triangle then (UNLISTED where not listed); per skin vertex the skin at the
    start and its move; per world the slack its lists are made with (the first:
    contact_frame_margin), its largest move, its fast vertices, the largest move near the points, a
    failed point, its longest skin edge, the points listed, the frame's report (slack, move,
    failed) and its host copy (:class:`~physhand_mj.contact.data.SlackBuffers`)."""
    W, dev, n_skin = worlds, model.device, model.n_skin
    n_points = points.pts.shape[0]
    return SlackBuffers(
        feat_dist=wp.zeros(points.n_features, dtype=float, device=dev),
        pt_dist=wp.full(n_points, UNLISTED, dtype=float, device=dev),
        pt_face=wp.zeros(n_points, dtype=int, device=dev),
        moves=skin_moves(n_skin, W, dev),
        slack=wp.full(W, config.contact_frame_margin, dtype=float, device=dev),
        near_motion=wp.zeros(W, dtype=float, device=dev),
        failed=wp.zeros(W, dtype=int, device=dev),
        world_listed=wp.zeros(W, dtype=int, device=dev),
        report=wp.zeros((W, 3), dtype=float, device=dev),
        report_host=wp.zeros((W, 3), dtype=float, device="cpu", pinned=wp.get_device(dev).is_cuda))
