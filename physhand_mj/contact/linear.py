"""The contact held between stages (``Config.contact_linear``): :class:`PlaneHold`, held by a
:class:`~physhand_mj.contact.contact.Contact` (``Contact.hold``).

With ``Config.contact_every`` k > 1 the contact stage (broadphase, multires decision points, Eq. 9,
the feature push) runs every k-th substep only, and between two stages the flesh and the bones can
press the skin back into an object it was lifted off: the next stage must undo it, and on the hard
cases one stage could not (docs/activity.md: 13 of 600 held frames with up to 0.5 mm left at k = 2,
255 with up to 9 mm at k = 5; with this hold 0 at k = 2, on the CPU and the H100).

Here every stage ends by linearising, for each of its active skin triangles whose decision point is
within ``contact_margin`` of an object, that point's constraint (Eq. 8, phi(x*) >= offset) about
where the stage left it: phi(x*) ~ g . x* + c, with x* the same barycentric point of the triangle,
g the unit SDF gradient there and c the offset that makes the plane exact at x*, both kept in the
geom's frame (so an object that moves between frames carries its planes). A substep without a stage
then runs ``HOLD_PASSES`` passes of Eq. 9 against these planes only (:func:`hold_planes`, a
query-free launch plus the averaged apply: no SDF, no BVH, no lattice), after the substep's solve
(before it with ``Placement.BEFORE``). A triangle the stage left out of its first pass as far keeps the weights of its
last decision point (its plane is exact where it is made all the same).

The object's side is held too (with the feature push on): each stage also keeps its listed feature
points (corners, tips, sharp edges) within ``contact_margin`` of the skin, each with its closest skin
point (triangle and barycentric weights, on the skin's BVH refit after the stage), and a substep
without a stage pushes them before the planes and, with ``Config.tuning.feature_last``, after them
(:func:`hold_features`: features.push_feature against that triangle as it is now, a point behind
its plane counting as inside). Batched worlds queried apart (BatchedHands with objects) hold their
planes, not their feature points.

The planes are a first-order model of the object near where the skin touched it: exact for a plane
or a box face, conservative on a convex surface (its tangent plane lies outside it), and the next
stage re-queries the exact SDF. The frame's last substep always runs a full stage (contact_every
counts back from it), so what a frame ends with is checked as before. Planes made by the last stage
of a frame also hold the next frame's first substeps (its objects' new poses applied); a frame whose
contact did not run (nothing near, or the hand asleep) leaves none for the next, and none survive
``Solver.wake`` (``SoftHand.reset`` calls it) or a frame of another state. ``roll_planes`` counts
among a frame's ops, not its contact ops. A plane whose point lies more than
``HOLD_MAX_DEPTH`` behind it (the skin moved far since) is not applied. A triangle whose stage took
the side-aware exit (query.project) makes no plane: its correction is not along the gradient.
"""

from __future__ import annotations

import warp as wp

from physhand_mj.contact.broadphase import TriList, world_geoms
from physhand_mj.contact.closest import closest_on_triangle
from physhand_mj.contact.data import PlaneBuffers
from physhand_mj.contact.features import push_feature
from physhand_mj.contact.inside import object_point
from physhand_mj.contact.query import (SIDE_COS, PushSums, accumulate, apply_contact, depth_weight, side_floor,
                                      world_phi_grad)
from physhand_mj.contact.sdf import GeomSet

wp.set_module_options({"enable_backward": False})

HOLD_MAX_DEPTH = wp.constant(2.0e-3)  # m: a plane's point further behind it than this is left to the next stage
# hold passes a substep without a stage runs, each the kept feature points' push then the planes (and the
# feature points once more after the last with Config.tuning.feature_last): one left 2 of the hard cases' 600
# held frames with up to 9 um at contact_every=2 (a 1 mm plate's edge at the palm), two none
HOLD_PASSES = 2
# slots of Contact.counters a hold takes at most (a touched count per applied push)
HOLD_SLOTS = 2 * HOLD_PASSES + 1


@wp.struct
class Planes:
    """The plane list (data.PlaneBuffers' arrays of the same names) as the kernels take it:
    :func:`make_planes` fills it, :func:`hold_planes` reads it."""

    tri: wp.array(dtype=int)  # the plane's skin triangle
    bary: wp.array(dtype=wp.vec3)  # the decision point's barycentric weights in it
    geom: wp.array(dtype=int)  # the geom the plane is of
    eq: wp.array(dtype=wp.vec4)  # the plane [unit gradient, offset m] in the geom's frame
    state: wp.array(dtype=int)  # [planes, made this frame, made last frame, feature points kept]


@wp.struct
class KeptPoints:
    """The kept feature points (data.PlaneBuffers' fpt, fface, fuv and state) as the kernels take
    them: :func:`make_feature_planes` fills them, :func:`hold_features` reads them."""

    pt: wp.array(dtype=int)  # a kept feature point
    face: wp.array(dtype=int)  # its closest skin triangle
    uv: wp.array(dtype=wp.vec2)  # the barycentric weights of its closest point there
    state: wp.array(dtype=int)  # as Planes.state


@wp.kernel
def make_planes(
    faces: wp.array2d(dtype=int),
    active: TriList,
    active_count: wp.array(dtype=int),
    decision: wp.array(dtype=wp.vec4),
    eval_x: wp.array2d(dtype=wp.vec3),
    geoms: GeomSet,
    tris_per_world: int,
    geoms_per_world: int,
    margin: float,
    side_aware: int,
    x: wp.array(dtype=wp.vec3),
    planes: Planes,
):
    """For each of the stage's active triangles (``active.tri[:active_count]``): its decision point
    (``decision``, taken on the vertices ``eval_x``) as barycentric weights, the point at those weights
    on the triangle as it is now, phi and its gradient there; within ``margin``, a plane [g, c] in the
    closest geom's frame (phi ~ g . q + c for a point q in that frame) appended to the plane list.
    Thread 0 marks the list as made in this frame (``planes.state[1]``); the caller zeroes its length
    (``planes.state[0]``) first."""
    k = wp.tid()
    if k == 0:
        planes.state[1] = 1
    if k >= active_count[0]:
        return
    t = active.tri[k]
    i0 = faces[t, 0]
    i1 = faces[t, 1]
    i2 = faces[t, 2]
    dec = decision[t]
    # the decision point's weights: the triangle's point closest to it (it is one of its points)
    bc = closest_on_triangle(eval_x[t, 0], eval_x[t, 1], eval_x[t, 2], wp.vec3(dec[0], dec[1], dec[2]))
    w = wp.vec3(bc[0], bc[1], 1.0 - bc[0] - bc[1])
    a = x[i0]
    b = x[i1]
    c = x[i2]
    p = a * w[0] + b * w[1] + c * w[2]
    base, end = world_geoms(t, tris_per_world, geoms_per_world, geoms.count[0])
    d, g, arg = world_phi_grad(p, geoms, base, end - base, active.mask[k])
    if d >= margin:
        return
    if side_aware != 0 and -d > side_floor(geoms.gtype[arg], geoms.size[arg]):
        nt = wp.normalize(wp.cross(b - a, c - a))
        if wp.dot(g, nt) > SIDE_COS:  # (query.project's side-aware exit: not along the gradient)
            return
    ti = geoms.inv_pose[arg]
    gl = wp.quat_rotate(wp.transform_get_rotation(ti), g)  # the gradient in the geom's frame
    ql = wp.transform_point(ti, p)
    slot = wp.atomic_add(planes.state, 0, 1)
    planes.tri[slot] = t
    planes.bary[slot] = w
    planes.geom[slot] = arg
    planes.eq[slot] = wp.vec4(gl[0], gl[1], gl[2], d - wp.dot(gl, ql))


@wp.kernel
def hold_planes(
    faces: wp.array2d(dtype=int),
    planes: Planes,
    geoms: GeomSet,
    offset: float,
    x: wp.array(dtype=wp.vec3),
    sums: PushSums,
    touched_count: wp.array(dtype=int),
):
    """One pass of Eq. 9 against the planes :func:`make_planes` left (this frame's, or the last
    frame's when that frame made some: ``planes.state`` [length, made this frame, made last frame]):
    the plane's point on the triangle as it is now, phi there by the plane, and below offset / 2 the
    triangle's vertices corrected along the plane's normal (query.project's correction and depth
    weight), into the pass's accumulators (apply_contact averages them)."""
    k = wp.tid()
    if k >= planes.state[0] or (planes.state[1] == 0 and planes.state[2] == 0):
        return
    t = planes.tri[k]
    i0 = faces[t, 0]
    i1 = faces[t, 1]
    i2 = faces[t, 2]
    w = planes.bary[k]
    p = x[i0] * w[0] + x[i1] * w[1] + x[i2] * w[2]
    g = planes.geom[k]
    ti = geoms.inv_pose[g]
    e = planes.eq[k]
    gl = wp.vec3(e[0], e[1], e[2])
    d = wp.dot(gl, wp.transform_point(ti, p)) + e[3]
    if d >= 0.5 * offset or d < -HOLD_MAX_DEPTH:
        return
    corr = wp.quat_rotate_inv(wp.transform_get_rotation(ti), gl) * (offset - d)
    wt = depth_weight(-d)
    accumulate(i0, i1, i2, corr, corr, corr, wt, wt, wt, geoms.obj[g], sums, touched_count)


@wp.kernel
def make_feature_planes(
    skin: wp.uint64,
    feat: wp.array(dtype=int),
    feat_count: wp.array(dtype=int),
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pose: wp.array(dtype=wp.transform),
    margin: float,
    kept: KeptPoints,
):
    """For each of the stage's listed object feature points (``feat[:feat_count]``) within ``margin``
    of the skin as the stage left it: the skin's closest point (face, u, v) on the skin's BVH, kept
    with the point (its geom carries it) for :func:`hold_features`; the caller zeroes
    ``kept.state[3]`` (the list's length) first."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    i = feat[k]
    q = wp.mesh_query_point_no_sign(skin, object_point(i, pts, pts_geom, pose), margin)
    if not q.result:
        return
    slot = wp.atomic_add(kept.state, 3, 1)
    kept.pt[slot] = i
    kept.face[slot] = q.face
    kept.uv[slot] = wp.vec2(q.u, q.v)


@wp.kernel
def hold_features(
    faces: wp.array2d(dtype=int),
    kept: KeptPoints,
    pts: wp.array(dtype=wp.vec3),
    pts_geom: wp.array(dtype=int),
    pts_normal: wp.array(dtype=wp.vec3),
    pose: wp.array(dtype=wp.transform),
    geom_obj: wp.array(dtype=int),
    offset: float,
    max_step: float,
    reach: float,
    x: wp.array(dtype=wp.vec3),
    sums: PushSums,
    touched_count: wp.array(dtype=int),
):
    """The feature push (features.push_feature) of every kept feature point against the skin point
    it was closest to when kept, where that point is still within ``reach`` (m) of it: a point
    behind the triangle's plane as it is now counts as inside, else outside (then pushed only when
    closer than offset / 2, as a stage would); the triangle pushed along its inward normal until the
    point is ``offset`` outside its plane (at most ``max_step``), into the pass's accumulators
    (``kept.state`` as in :func:`hold_planes`)."""
    k = wp.tid()
    if k >= kept.state[3] or (kept.state[1] == 0 and kept.state[2] == 0):
        return
    i = kept.pt[k]
    uv = kept.uv[k]
    f = kept.face[k]
    p = object_point(i, pts, pts_geom, pose)
    w2 = 1.0 - uv[0] - uv[1]
    c = x[faces[f, 0]] * uv[0] + x[faces[f, 1]] * uv[1] + x[faces[f, 2]] * w2
    if wp.length(p - c) > reach:  # (the skin or the object moved on since: the next stage's)
        return
    # inside: behind the kept triangle's plane as it is now (the stage's rule where its winding agrees)
    n = wp.cross(x[faces[f, 1]] - x[faces[f, 0]], x[faces[f, 2]] - x[faces[f, 0]])
    sign = float(1.0)
    if wp.dot(p - c, n) < 0.0:
        sign = -1.0
    nw = wp.quat_rotate(wp.transform_get_rotation(pose[pts_geom[i]]), pts_normal[i])
    push_feature(p, f, uv[0], uv[1], sign, geom_obj[pts_geom[i]], faces, offset, max_step, x, sums, touched_count,
                 nw)


@wp.kernel
def roll_planes(plane_state: wp.array(dtype=int)):
    """At a frame's start: the planes made last frame may hold this frame's first substeps; none made yet."""
    plane_state[2] = plane_state[1]
    plane_state[1] = 0


class PlaneHold:
    """``Config.contact_linear``'s planes of a :class:`~physhand_mj.contact.contact.Contact`
    (``Contact.hold``): its buffers (:class:`~physhand_mj.contact.data.PlaneBuffers`, ``data``),
    made by a stage's end (:meth:`record_make`) and held by the substeps without a stage
    (:meth:`record_hold`), which take the stage's lists and pass buffers from the contact."""

    def __init__(self, model, objects, config, n_tris: int, tris_per_world: int, geoms_per_world: int,
                 side_aware: int):
        self.model, self.objects, self.config = model, objects, config
        self.tris_per_world, self.geoms_per_world, self.side_aware = tris_per_world, geoms_per_world, side_aware
        self.n_tris = n_tris
        # whether substeps without a contact stage hold the skin on the last stage's planes
        self.holds = bool(config.contact_linear and config.contact_every > 1 and n_tris)
        self.data = make_plane_buffers(max(n_tris, 1) if self.holds else 0, model.device)
        self.plane_len, self.fplane_len = self.data.state[0:1], self.data.state[3:4]  # (the lists' lengths)
        self.planes_of = None  # the state the planes were made for (forget)

    def forget(self, state=None) -> None:
        """Drop the planes (a hand woken or reset, or another state stepped with this contact); with
        ``state``, only when the planes were made for another one."""
        if not self.holds or (state is not None and self.planes_of is state):
            return
        self.data.state.zero_()
        self.planes_of = state

    def record_frame(self, rec) -> None:
        """Every frame, contact or not: last frame's planes become the previous ones (roll_planes)."""
        if self.holds:
            rec.launch(roll_planes, 1, [self.data.state], [])

    def keeps_features(self, points) -> bool:
        """Sizes the kept feature points' slots for ``points`` (ObjectPoints; made at the frame's
        first recording: the objects are final); False for no points (no feature push, or the worlds
        queried apart: batches with objects hold their planes, not their feature points)."""
        if points is None:
            return False
        b = self.data
        if b.fpt is None:
            nf, d = points.n_features, self.model.device
            b.fpt = wp.zeros(nf, dtype=int, device=d)
            b.fface = wp.zeros(nf, dtype=int, device=d)
            b.fuv = wp.zeros(nf, dtype=wp.vec2, device=d)
            b.kept = KeptPoints()
            b.kept.pt, b.kept.face, b.kept.uv, b.kept.state = b.fpt, b.fface, b.fuv, b.state
        return True

    def record_make(self, rec, state, lists, acc, active_count, features=None) -> None:
        """After a stage's last pass: its planes (make_planes) over the stage's ``lists`` (FrameLists,
        ``active_count`` its length) and decision points (``acc``: PassBuffers) and, with
        ``features`` = (points, the stage's features, their count, the refitted skin volume, its
        refit op), its feature points near the skin (make_feature_planes), replacing the lists."""
        if not self.holds:
            return
        m, o, cfg, b = self.model, self.objects, self.config, self.data
        if features is not None and self.keeps_features(features[0]):
            points, feat_stage, feat_count, vol, refit = features
            rec.ops += [self.fplane_len.zero_, refit]  # (the CPU: only with features listed)
            rec.launch(make_feature_planes, points.n_features,
                       [vol.mesh.id, feat_stage, feat_count, points.pts, points.geom, o.pose,
                        cfg.contact_margin], [b.kept],
                       count=feat_count)
        rec.ops.append(self.plane_len.zero_)
        rec.launch(make_planes, self.n_tris,
                   [m.skin_faces, lists.active_tris, active_count, acc.decision, acc.eval_x,
                    o.geoms_exact, self.tris_per_world, self.geoms_per_world, cfg.contact_margin, self.side_aware,
                    state.x],
                   [b.planes],
                   count=active_count, min_dim=1)

    def record_hold(self, rec, state, lists, acc, take_counter, shift: tuple, bone_hold, exchange, points=None) -> None:
        """A substep without a stage: HOLD_PASSES passes of [the kept feature points' push (``points``:
        ObjectPoints, None: none kept), Eq. 9 against the planes], each applied into ``acc``
        (PassBuffers; ``shift``: apply_contact's shift arrays; ``bone_hold``, ``exchange``: its bones.BoneHold and
        exchange.Exchange) with a touched count from
        ``take_counter()`` (its counter slot, the vertices' stamp), then (Config.tuning.feature_last)
        the feature points once more."""
        if not self.holds:
            return
        m, o, cfg, b = self.model, self.objects, self.config, self.data
        pushes = [(hold_planes, self.n_tris, self.plane_len,
                   [m.skin_faces, b.planes, o.geoms, cfg.contact_offset, state.x])]
        if self.keeps_features(points):  # the kept feature points, before the planes (as a stage's push is)
            pushes.insert(0, (hold_features, points.n_features, self.fplane_len,
                              [m.skin_faces, b.kept, points.pts, points.geom, points.normal, o.pose, o.obj, cfg.feature_offset,
                               cfg.contact_margin, cfg.contact_margin, state.x]))
        order = pushes * HOLD_PASSES + (pushes[:1] if len(pushes) == 2 and cfg.feature_last else [])
        for kernel, dim, length, inputs in order:  # each push applied (averaged) before the next
            stamp, count = take_counter()
            rec.launch(kernel, dim, inputs, [acc.sums, count], count=length)
            rec.launch(apply_contact, m.n_vertices, [acc.sums, count, stamp, shift[0], bone_hold, exchange],
                       [state.x, acc.push, acc.moved, acc.disp, lists.pass_move, shift[1]], count=count)


def make_plane_buffers(n: int, device) -> PlaneBuffers:
    """The plane list, ``n`` slots (a slot per skin triangle where the config asks for a hold, else 0)."""
    p = Planes()
    p.tri, p.bary = wp.zeros(n, dtype=int, device=device), wp.zeros(n, dtype=wp.vec3, device=device)
    p.geom, p.eq = wp.zeros(n, dtype=int, device=device), wp.zeros(n, dtype=wp.vec4, device=device)
    p.state = wp.zeros(4, dtype=int, device=device)
    return PlaneBuffers(tri=p.tri, bary=p.bary, geom=p.geom, eq=p.eq, state=p.state, planes=p)
