"""The contact stage's buffers, declared: one dataclass per concept, each field's shape, dtype and units.

:class:`~physhand_mj.contact.contact.Contact` holds a :class:`FrameLists` (the frame's, stages' and
passes' triangle lists and their lengths), a :class:`PassBuffers` (what a pass accumulates and
applies) and, with the feature push, a :class:`FeatureLists` (the object feature points listed near
the skin and their patches); its :class:`~physhand_mj.contact.measures.ContactMeasures` holds a
:class:`MetricsBuffers` (the penetration measures' rows), its
:class:`~physhand_mj.contact.slack.SlackCheck` a :class:`SlackBuffers` (the lists' slack and their
check, with each listed point's distance), its :class:`~physhand_mj.contact.linear.PlaneHold` a
:class:`PlaneBuffers`.
Each is made by its ``make_*`` function. Shapes name F = skin triangles (all worlds'), V = vertices,
S = skin vertices, W = batched worlds, P = object surface points, N = object feature points, and
"stages" = contact stages of a frame. A host copy (``*_host``) is in pinned memory on CUDA, where the
frame's one sync waits for its copy (``Contact.copy_metrics``).

The counter slots: ``FrameLists.counters[0]`` is the frame broadphase's list length; each stage
then takes, in recording order (``Contact.take_counter``), its active list's length, its first
pass's list, and per pass Eq. 9's touched vertices, the feature push's touched vertices (with the
feature push) and the next pass's list length; a hold (``Config.contact_linear``) a touched count
per applied push.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import TriList, tri_list
from physhand_mj.contact.query import PushSums, push_sums
from physhand_mj.contact.winding import Patches, patches_of
from physhand_mj.types import Config, Placement


def contact_stages(config: Config) -> int:
    """Contact stages in a frame: one per substep, two with ``Placement.BOTH``."""
    return config.substeps * (2 if config.contact_placement == Placement.BOTH else 1)


@dataclass
class FrameLists:
    """The frame's and its stages' triangle lists (skin triangle indices into ``Model.skin_faces``,
    each list's length in a ``counters`` slot) and the per-pass controls."""

    counters: wp.array  # (1 + stages (2 + 3 passes) + holds,) int: the list lengths of one frame, zeroed per frame
    counters_host: wp.array  # (like counters,) int, host: their copy after the frame
    cand: wp.array  # (max(F, 1),) int: the frame broadphase's list (within contact_frame_margin)
    cand_mask: wp.array  # (max(F, 1),) int: per listed triangle, bits of its world's geoms near it
    active: wp.array  # (max(F, 1),) int: a stage's list (within contact_margin) of the frame's
    active_mask: wp.array  # (max(F, 1),) int: its near-geom bits
    pass_list: wp.array  # (max(F, 1),) int: a later pass's list (triangles with a vertex the last pass moved)
    pass_mask: wp.array  # (max(F, 1),) int: its near-geom bits
    cand_tris: TriList  # cand and cand_mask as the kernels take them (one argument; its length: a counter slot)
    active_tris: TriList  # active and active_mask so
    pass_tris: TriList  # pass_list and pass_mask so
    # (max(stages x passes, 1),) int32: per later pass of a frame, 1 when the pass before it moved a
    # vertex (keep_moved sets it, CUDA's conditional node reads it: activity.py level 2; zeroed per frame)
    pass_flags: wp.array
    # (like counters or 0,) float m: per pass (by its stamp, a counter slot) its largest vertex move,
    # zeroed per frame (Config.tuning.contact_pass_tol; empty when the tolerance is 0)
    pass_move: wp.array
    pass_move_host: wp.array  # (like pass_move,) float m, host (the CPU: pass_move itself)
    # (max(stages, 1) or 0,) float m: per stage the move its passes stop under (Contact.finish_recording)
    stage_tol: wp.array
    stage_tol_host: np.ndarray  # (like stage_tol,) float32: what finish_recording last wrote
    # (W, 2 max(stages, 1)) int or None for one world: per world and stage [active triangles, vertices
    # the first pass corrected]
    world_stage: wp.array | None
    world_stage_host: wp.array | None  # (like world_stage) int, host


@dataclass
class PassBuffers:
    """What a pass computes per triangle and accumulates per vertex, then applies (query.apply_contact)."""

    decision: wp.array  # (max(F, 1),) vec4: the last decision point per triangle, [x* m, phi(x*) m]
    bound: wp.array  # (max(F, 1),) float m: the lowest phi per triangle when last queried (-1e30: none)
    eval_x: wp.array  # (max(F, 1), 3) vec3 m: the triangle's vertices when ``bound`` was set
    bound_mask: wp.array  # (max(F, 1),) int: the geoms ``bound`` was taken over (bits)
    delta: wp.array  # (V,) vec3 m: summed corrections of a push, averaged on apply
    hits: wp.array  # (V,) float: the corrections' weights summed
    touched: wp.array  # (V,) int: the vertices a push corrects (a list; its length a counter slot)
    moved: wp.array  # (V,) int: the counter slot (stamp) of the pass that last moved the vertex, zeroed per frame
    disp: wp.array  # (V,) float m: how far that pass moved it
    push: wp.array  # (V,) float m: the contact's move of the vertex summed over the frame (reports)
    vertex_obj: wp.array  # (V,) int: the object that last pushed the vertex this frame (-1: none)
    sums: PushSums  # delta, hits, touched and vertex_obj as the kernels take them (one argument)


@dataclass
class FeatureLists:
    """The feature push's lists (features.py): the object feature points near the skin, the frame's
    (features.near_features) and each stage's, and with Config.feature_winding the local winding
    number's patches (winding.py, patches_tiled.py). Made at the first recording with listed feature
    points (the objects final then); the patch pool grows after a frame that needed more
    (Contact.features_listed). Indices are into the contact's ``ObjectPoints`` (its ``pts``); the
    patch entries are skin triangle indices."""

    listed: wp.array  # (N,) int: the frame's list of feature points within contact_frame_margin of the skin
    count: wp.array  # (1,) int: its length, zeroed per frame
    count_host: wp.array  # (1,) int, host: its copy after the frame (Contact.features_listed)
    stage: wp.array  # (N,) int: a stage's list: features inside the skin or within contact_margin of it
    stage_counts: wp.array  # (max(stages, 1),) int: per stage of a frame its list's length, zeroed per frame
    no_side: wp.array  # (1,) float: stands in for far_angle and side without Config.feature_winding (never read)
    # Config.feature_winding only (else None):
    # (pool,) int: the listed features' patches, skin triangles each (patch_pool.patch_pool_size; grows)
    patch_pool: wp.array | None = None
    # (3,) int: [entries the patches need in all, taken at the pool's top, patches that did not fit]
    patch_used: wp.array | None = None
    patch_used_host: wp.array | None = None  # (3,) int, host: its copy after the frame
    slot: wp.array | None = None  # (P,) int: per object point (by point index) its listed feature's slot
    patch_start: wp.array | None = None  # (N,) int: per listed feature its patch's first entry in the pool
    patch_len: wp.array | None = None  # (N,) int: its length (-1: no patch, it did not fit)
    patch_fill: wp.array | None = None  # (N,) int: CUDA's appends per feature (patches_tiled.py)
    far_angle: wp.array | None = None  # (N,) float: the solid angle of the skin outside the patch (winding.py)
    side: wp.array | None = None  # (N,) float: the CPU's per-stage sides of the listed features (stage_features)
    # slot, patch_pool, patch_start, patch_len and far_angle as the kernels take them (one argument;
    # without Config.feature_winding ``listed`` and ``no_side`` stand in, never read)
    patches: Patches | None = None


@dataclass
class MetricsBuffers:
    """The penetration measures' rows (DESIGN.md, Metrics) and the skin measure's culled list."""

    # (W (substeps + 1), 6) float: per row [skin samples inside objects: count, sum depth m, max depth
    # m, object points inside the skin: count, sum depth m, max depth m]; world w's rows at
    # [w (substeps + 1), (w + 1) (substeps + 1)), the last of each the frame's end
    metrics: wp.array
    metrics_host: wp.array  # (like metrics) float, host


@dataclass
class SlackBuffers:
    """The feature lists' slack (Config.tuning.feature_slack) and the frame end's check of it (slack.py)."""

    feat_dist: wp.array  # (N,) float m: per listed feature its distance to the skin at the frame's start
    pt_dist: wp.array  # (P,) float m: per object point its signed distance then (slack.UNLISTED: not listed)
    pt_face: wp.array  # (P,) int: its closest skin triangle then (-1: measured, not listed)
    moves: object  # slack.SkinMoves (slack.py imports this module): the skin at the frame's start, its moves
    slack: wp.array  # (W,) float m: the slack each world's lists are made with (the first: contact_frame_margin)
    near_motion: wp.array  # (W,) float m: the largest move near the feature points (the next slack's measure)
    failed: wp.array  # (W,) int: 1 where the check failed a point
    world_listed: wp.array  # (W,) int: points the world listed
    report: wp.array  # (W, 3) float: per world [slack m, largest move m, failed]
    report_host: wp.array  # (W, 3) float, host


@dataclass
class PlaneBuffers:
    """Config.contact_linear's planes (linear.py): a slot per skin triangle where the config asks
    for a hold, else empty arrays; the feature points kept sized at the first recording."""

    tri: wp.array  # (max(F, 1) or 0,) int: the plane's skin triangle
    bary: wp.array  # (like tri,) vec3: the decision point's barycentric weights in it
    geom: wp.array  # (like tri,) int: the geom the plane is of
    eq: wp.array  # (like tri,) vec4: the plane [unit gradient, offset m] in the geom's frame
    state: wp.array  # (4,) int: [planes, made this frame, made last frame, feature points kept]
    # linear.Planes (linear.py imports this module, not the other way): tri, bary, geom, eq and
    # state as the kernels take them (one argument)
    planes: object
    fpt: wp.array | None = None  # (N,) int: a kept feature point
    fface: wp.array | None = None  # (N,) int: its closest skin triangle
    fuv: wp.array | None = None  # (N,) vec2: the barycentric weights of its closest point there
    kept: object = None  # linear.KeptPoints or None: fpt, fface, fuv and state as the kernels take them


def make_frame_lists(model, config: Config, worlds: int, hold_slots: int) -> FrameLists:
    """The frame's lists for ``model``'s skin in ``worlds`` worlds (``hold_slots``: the counter
    slots after the stages' (Config.contact_linear's holds, and the frame's held-skin count:
    Contact.held_slot))."""
    d = model.device
    n_tris = model.skin_faces.shape[0]
    stages = contact_stages(config)
    f = max(n_tris, 1)
    counters = wp.zeros(1 + stages * (2 + 3 * config.contact_passes) + hold_slots, dtype=int, device=d)
    cuda = wp.get_device(d).is_cuda
    world_stage = wp.zeros((worlds, max(stages, 1) * 2), dtype=int, device=d) if worlds > 1 else None
    world_stage_host = (wp.zeros((worlds, max(stages, 1) * 2), dtype=int, device="cpu", pinned=cuda)
                        if worlds > 1 else None)
    tol = config.contact_pass_tol > 0  # (no tolerance: no work, no flag change)
    pass_move = wp.zeros(counters.shape[0] if tol else 0, dtype=float, device=d)
    stage_tol = wp.zeros(max(stages, 1) if tol else 0, dtype=float, device=d)
    cand, active, pass_list = (tri_list(wp.zeros(f, dtype=int, device=d), wp.zeros(f, dtype=int, device=d))
                               for _ in range(3))
    return FrameLists(
        counters=counters,
        counters_host=wp.zeros(counters.shape[0], dtype=int, device="cpu", pinned=cuda),
        cand=cand.tri, cand_mask=cand.mask, active=active.tri, active_mask=active.mask,
        pass_list=pass_list.tri, pass_mask=pass_list.mask, cand_tris=cand, active_tris=active, pass_tris=pass_list,
        pass_flags=wp.zeros(max(stages * config.contact_passes, 1), dtype=wp.int32, device=d),
        pass_move=pass_move,
        pass_move_host=(wp.zeros(pass_move.shape[0], dtype=float, device="cpu", pinned=True) if cuda
                        else pass_move),
        stage_tol=stage_tol, stage_tol_host=np.zeros(stage_tol.shape[0], np.float32),
        world_stage=world_stage, world_stage_host=world_stage_host)


def make_pass_buffers(model) -> PassBuffers:
    """A pass's buffers for ``model``'s skin triangles and vertices."""
    d, n, f = model.device, model.n_vertices, max(model.skin_faces.shape[0], 1)
    sums = push_sums(wp.zeros(n, dtype=wp.vec3, device=d), wp.zeros(n, dtype=float, device=d),
                     wp.zeros(n, dtype=int, device=d), wp.full(n, -1, dtype=int, device=d))
    return PassBuffers(
        moved=wp.zeros(n, dtype=int, device=d), disp=wp.zeros(n, dtype=float, device=d),
        bound=wp.zeros(f, dtype=float, device=d), eval_x=wp.zeros((f, 3), dtype=wp.vec3, device=d),
        bound_mask=wp.zeros(f, dtype=int, device=d), touched=sums.touched, delta=sums.delta, hits=sums.hits,
        decision=wp.zeros(f, dtype=wp.vec4, device=d), push=wp.zeros(n, dtype=float, device=d),
        vertex_obj=sums.vertex_obj, sums=sums)


def make_feature_lists(points, config: Config, pool: int, device) -> FeatureLists:
    """The feature lists for the object points ``points`` (an ObjectPoints: ``n_features`` feature
    points of ``pts.shape[0]`` points); ``pool``: the patch pool's first size (entries,
    patch_pool.patch_pool_size; Config.feature_winding only)."""
    d, n, stages = device, points.n_features, contact_stages(config)
    cuda = wp.get_device(d).is_cuda
    lists = FeatureLists(listed=wp.zeros(n, dtype=int, device=d), count=wp.zeros(1, dtype=int, device=d),
                         count_host=wp.zeros(1, dtype=int, device="cpu", pinned=cuda),
                         stage=wp.zeros(n, dtype=int, device=d),
                         stage_counts=wp.zeros(max(stages, 1), dtype=int, device=d),
                         no_side=wp.zeros(1, dtype=float, device=d))
    if config.feature_winding:
        lists.patch_pool = wp.zeros(pool, dtype=int, device=d)
        lists.patch_used = wp.zeros(3, dtype=int, device=d)
        lists.patch_used_host = wp.zeros(3, dtype=int, device="cpu", pinned=cuda)
        lists.slot = wp.zeros(points.pts.shape[0], dtype=int, device=d)
        lists.patch_start = wp.zeros(n, dtype=int, device=d)
        lists.patch_len = wp.full(n, -1, dtype=int, device=d)
        lists.patch_fill = wp.zeros(n, dtype=int, device=d)
        lists.far_angle = wp.zeros(n, dtype=float, device=d)
        lists.side = wp.zeros(n, dtype=float, device=d)
        lists.patches = patches_of(lists.slot, lists.patch_pool, lists.patch_start, lists.patch_len, lists.far_angle)
    else:
        lists.patches = patches_of(lists.listed, lists.listed, lists.listed, lists.listed, lists.no_side)
    return lists


def make_metrics_buffers(model, config: Config, worlds: int) -> MetricsBuffers:
    """The measures' rows: substeps + 1 per world."""
    rows, cuda = worlds * (config.substeps + 1), wp.get_device(model.device).is_cuda
    return MetricsBuffers(metrics=wp.zeros((rows, 6), dtype=float, device=model.device),
                          metrics_host=wp.zeros((rows, 6), dtype=float, device="cpu", pinned=cuda))
