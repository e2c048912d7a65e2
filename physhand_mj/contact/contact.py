"""The contact stage of a substep (Algorithm 1, line 6): broadphase, decision points, Eq. 9.

:class:`Contact` owns the preallocated contact buffers of one solver and records its launches into
the solver's frame (so a CUDA graph captures them); the penetration metrics are its
:class:`~physhand_mj.contact.measures.ContactMeasures` (contact/measures.py), the frame's host-side
reports its :class:`~physhand_mj.contact.reports.ContactReports` (contact/reports.py), the feature lists'
slack and its check :class:`~physhand_mj.contact.slack.FeatureSlack` (contact/slack.py), where the
object side's queries run :class:`~physhand_mj.contact.query_space.QuerySpace` (contact/query_space.py).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import find_active, keep_moved, stage_lists, tally_worlds
from physhand_mj.contact.features import (FEATURE_LANES, near_features, stage_features, stage_features_scan,
                                          stage_features_tiled)
from physhand_mj.contact.patches_tiled import PATCH_LANES, feature_patches_tiled
from physhand_mj.contact.winding import feature_patches
from physhand_mj.contact.feature_push import FeaturePush
from physhand_mj.contact.inside import ObjectPoints
from physhand_mj.contact.linear import HOLD_SLOTS, LinearHold
from physhand_mj.contact.measures import ContactMeasures
from physhand_mj.contact.objects import Objects
from physhand_mj.contact.query import apply_contact, decide_and_project, decide_inputs, multires_kernel
from physhand_mj.contact.query_space import QuerySpace
from physhand_mj.contact.reports import ContactReports
from physhand_mj.contact.slack import FeatureSlack
from physhand_mj.contact.query_tiled import TILE_LANES, tiled_kernel_for
from physhand_mj.config import FEATURE_LIST_SHARE
from physhand_mj.types import Config, Model, Placement, Settings, Strategy
from physhand_mj.launch import Recorder, tiled_blocks

# the local winding number's patch pool (features.py): entries per feature point of the objects,
# within [PATCH_POOL_MIN, PATCH_POOL_MAX] in all (the demo's listed features hold ~170 triangles each
# within 1 cm, at most ~270, and ~184 of its ~1,760 (features every 0.25 mm) are listed per frame); a
# patch that does not fit keeps the pseudo-normal sign (one hand) or is not pushed (CUDA batches) in
# that frame, after which the pool grows (ContactReports.features_listed).
# 2^30 int32 entries (4 GiB) at most: the HOI box grasp at W = 4096 needs 442 M (an H100, 2026-11-26;
# with the 2^28 it had then, points of some worlds went unpushed, up to 0.49 mm inside)
# The BVH path (winding.feature_patches) gives the k-th of a frame's n listed features the slot
# pool[k c: (k + 1) c], c = min(PATCH_SLOT, pool // 2 n), and the larger patches room at the top (the
# other half at least): a pool of 2 x 128 entries per feature point holds in its top half every list
# the packed pool of 128 held, however many patches pass their slots (slots over the whole pool left
# the hard cases' deep starts no room: 47-267 points without a patch, tests/test_winding.py); at
# PATCH_POOL_MAX every patch is sure to fit while the list needs at most half of it packed
PATCH_SLOT = 128
PATCH_POOL_PER_FEATURE = 2 * PATCH_SLOT
PATCH_POOL_MIN = 1 << 15
PATCH_POOL_MAX = 1 << 30
# the frame margin PATCH_POOL_PER_FEATURE was measured at (the default): a patch's radius is at most
# Config.contact_frame_margin and the skin triangles within it grow with its square (the rest skin's,
# within a ball about a skin vertex: 147 on average at 10 mm, 500 at 20 mm, 1,074 at 30 mm), so a
# larger margin gets proportionally more entries per feature point, up to PATCH_POOL_SCALED (16 MiB;
# a large object's many feature points, most of them never listed, keep the unscaled pool); past
# that the pool grows when a frame needs more (ContactReports.features_listed). MyoSuite's 20 mm
# margin: the myoHandReorient envs list ~1,400 of 1,960 points, needing 449 k entries packed, past the
# 502 k of 256 per point (211 patches did not fit); 2.0 M with the margin's square
PATCH_POOL_MARGIN = 0.01
PATCH_POOL_SCALED = 1 << 22


def patch_pool_size(n_features: int, frame_margin: float) -> int:
    """The patch pool's first size (entries) for ``n_features`` object feature points (every
    world's) whose patches reach at most ``frame_margin`` (m): PATCH_POOL_PER_FEATURE each, times
    (frame_margin / PATCH_POOL_MARGIN)^2 above PATCH_POOL_MARGIN up to PATCH_POOL_SCALED in all,
    within [PATCH_POOL_MIN, PATCH_POOL_MAX]."""
    base = n_features * PATCH_POOL_PER_FEATURE
    scaled = math.ceil(base * max(1.0, (float(frame_margin) / PATCH_POOL_MARGIN) ** 2))
    return int(min(max(min(scaled, max(base, PATCH_POOL_SCALED)), PATCH_POOL_MIN), PATCH_POOL_MAX))


# batched worlds from which CUDA runs the feature queries a thread per listed feature (Config.execution.tiled_features
# None): the HOI box grasp on an H100 (benchmarks/batch_hoi.py), hand-frames/s with a block per feature
# against a thread: W = 16 1,349 / 627, W = 64 1,830 / 1,827, W = 256 1,907 / 3,302, W = 1024 1,859 / 3,745
FEATURE_SCAN_WORLDS = 64



AUTO_MULTIRES_REGISTERS = 128  # Config.execution.multires_registers = None: the cap for a CUDA batch with a mesh object


def multires_registers_for(config: Settings, cuda: bool, worlds: int, has_mesh: bool) -> int:
    """The register cap of the per-thread multires kernel (0: the generic kernel) for a run on a
    CUDA device or not, of ``worlds`` worlds, with a mesh object or not: Config.execution.multires_registers
    where set; None picks AUTO_MULTIRES_REGISTERS for a CUDA batch with a mesh object (the bowl:
    1.11-1.13 x the batch's throughput on an H100) and 0 otherwise (the analytic grasps ran 4-24 %
    slower capped; one hand runs the tiled kernel, where the cap does not apply)."""
    if config.contact != Strategy.MULTIRES:
        return 0
    if config.multires_registers is not None:
        return int(config.multires_registers)
    return AUTO_MULTIRES_REGISTERS if cuda and worlds > 1 and has_mesh else 0


def _same_device(a, b) -> bool:
    """Whether two device names name one device ("cuda" and "cuda:0" do); unknown names differ."""
    if str(a) == str(b):
        return True
    try:
        return wp.get_device(a) == wp.get_device(b)
    except (RuntimeError, ValueError):
        return False


class Contact(ContactMeasures, ContactReports, FeatureSlack, QuerySpace, LinearHold, FeaturePush):
    """Skin-object contact for a solver ``Model`` against ``objects`` (see Config.contact*)."""

    capturable = True

    def __init__(self, model: Model, objects: Objects, config: Config):
        if not _same_device(objects.device, model.device):
            raise ValueError(f"objects live on {objects.device}, the model on {model.device}")
        d = model.device
        self.model, self.objects, self.config = model, objects, config
        n_tris = model.skin_faces.shape[0]
        self.n_tris = n_tris
        stages = config.substeps * (2 if config.contact_placement == Placement.BOTH else 1)
        # batched worlds (physhand_mj/batch.py): world w holds triangles [w F_w, (w + 1) F_w) and
        # geoms [w k, (w + 1) k); every list and metric is indexed by world (one world: w = 0)
        self.worlds = w = int(getattr(model, "worlds", 1))
        if w > 1 and (n_tris % w or objects.capacity % w):
            raise ValueError(f"batched worlds: {n_tris} skin triangles and {objects.capacity} geoms do not split "
                             f"into {w} equal worlds")
        self.tris_per_world = max(n_tris // w, 1)
        self.geoms_per_world = max(objects.capacity // w, 1)
        self._views = None  # the objects' arrays as (W, k) views (the metrics' per-world geoms)
        # batched worlds solved at one origin but queried apart (set_query_offsets): the object side's
        # skin meshes hold x + the world's offset and its queries use the geoms' poses so moved
        self.query_shift = self._qoff = self._qpose = None
        self._no_shift = wp.zeros(0, dtype=wp.vec3, device=model.device)  # (apply_contact's, unshifted)
        # per world and contact stage: [active triangles, vertices the first pass corrected] (W > 1)
        self.world_stage = wp.zeros((w, max(stages, 1) * 2), dtype=int, device=d) if w > 1 else None
        self._world_stage_host = wp.zeros((w, max(stages, 1) * 2), dtype=int, device="cpu",
                                          pinned=wp.get_device(d).is_cuda) if w > 1 else None
        # list lengths of one frame, zeroed once per frame: [frame list, per stage: its list, per pass:
        # the pass's triangle list, Eq. 9's touched vertices, the features' touched vertices, and after
        # the last pass the final feature push's touched vertices (Config.tuning.feature_last)]
        # (Config.contact_linear: and what the holds of the substeps without a stage take, linear.py)
        holds = config.substeps * HOLD_SLOTS if config.contact_linear and config.contact_every > 1 else 0
        self.counters = wp.zeros(1 + stages * (2 + 3 * config.contact_passes) + holds, dtype=int, device=d)
        self.cand = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # the frame's broadphase list
        self.cand_mask = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # near-geom bits per slot
        self.cand_count = self.counters[0:1]
        self.active = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # the stage's list
        self.active_mask = wp.zeros(max(n_tris, 1), dtype=int, device=d)
        self.active_count = self.cand_count  # replaced per stage by its counter
        self.pass_list = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # a later pass's list
        self.pass_mask = wp.zeros(max(n_tris, 1), dtype=int, device=d)
        self.moved = wp.zeros(model.n_vertices, dtype=int, device=d)  # number of the pass that last moved i
        self.disp = wp.zeros(model.n_vertices, dtype=float, device=d)  # m, how far that pass moved i
        self.bound = wp.zeros(max(n_tris, 1), dtype=float, device=d)  # m, lowest phi per triangle (see query)
        self.eval_x = wp.zeros((max(n_tris, 1), 3), dtype=wp.vec3, device=d)  # its vertices when bound was set
        self.bound_mask = wp.zeros(max(n_tris, 1), dtype=int, device=d)  # the geoms bound was taken over
        self.touched = wp.zeros(model.n_vertices, dtype=int, device=d)  # vertices a pass corrects
        self.touched_count = self.cand_count
        self._slot = 1
        # CUDA multires runs the tiled kernel when a block holds the lattice (and the centroid), by
        # default for one hand only: its launch has a block per skin triangle, which batched worlds
        # fill with idle blocks (Config.execution.tiled_contact)
        tiled = config.tiled_contact if config.tiled_contact is not None else model.worlds == 1
        self.tiled = bool(wp.get_device(d).is_cuda and config.contact == Strategy.MULTIRES
                          and config.multires_samples < TILE_LANES and tiled)
        self.delta = wp.zeros(model.n_vertices, dtype=wp.vec3, device=d)
        self.hits = wp.zeros(model.n_vertices, dtype=float, device=d)
        self.decision = wp.zeros(max(n_tris, 1), dtype=wp.vec4, device=d)
        self.push = wp.zeros(model.n_vertices, dtype=float, device=d)  # m, summed over the frame
        self.vertex_obj = wp.full(model.n_vertices, -1, dtype=int, device=d)
        # per row: [skin samples inside objects: count, sum depth, max depth (m),
        #          object points inside the skin: count, sum depth, max depth (m)]
        # (batched worlds: W blocks of these rows, world w's at [w (substeps + 1), (w + 1) (substeps + 1)))
        self.metrics = wp.zeros((w * (config.substeps + 1), 6), dtype=float, device=d)
        self._metrics_host = wp.zeros((w * (config.substeps + 1), 6), dtype=float, device="cpu",
                                      pinned=wp.get_device(d).is_cuda)
        self._points = None  # ObjectPoints, built at the first recording (objects are final then)
        self._check_points = None  # the denser check set (check_points), built on first use
        self._reuse_memory = {}  # Config.execution.reuse_outside's per (points, skin volume) memory (measures.py)
        self._volumes = {}  # SkinVolume per (state, winding) (its mesh's points are the state's skin positions)
        # the object's side (features.py, the second measure) needs an inside: a closed skin
        # (batched worlds: world 0's faces, which name world 0's skin vertices; every world is a copy,
        # and the tolerance below is then the serial hand's to the bit)
        f = model.skin_faces[: self.tris_per_world].numpy() if n_tris else np.zeros((0, 3), np.int32)
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1).astype(np.int64)
        key = e[:, 0] * (int(e.max(initial=0)) + 1) + e[:, 1]  # one integer per edge: a 1-D unique (fast for W worlds)
        self.closed_skin = bool(len(f)) and bool(np.all(np.unique(key, return_counts=True)[1] == 2))
        self.feat = None  # the frame's list of object feature points near the skin (features.py)
        self.feat_count = wp.zeros(1, dtype=int, device=d)
        self.feat_stage_float = wp.zeros(1, dtype=float, device=d)  # stands in for far_angle (feature_winding off)
        self._slot_ids = {}  # counter slots as device arrays, per tuple of slots (Contact._slot_array)
        self._first_push = None  # the stage's first-pass feature counter (CUDA: filled by stage_features_tiled)
        # m, the radius a feature's skin query tries first (features.closest_signed): a pass's
        # features lie within ~contact_margin of the skin; the frame margin is the fallback
        self.near_query = float(min(config.contact_frame_margin, max(4.0 * config.contact_margin, 1.0e-3)))
        self.feat_stage = None  # the stage's features: inside the skin or within contact_margin of it
        self.feat_stage_counts = wp.zeros(max(stages, 1), dtype=int, device=d)  # one per stage of a frame
        # CUDA: the stage's and passes' feature queries by a block per feature over the frame's
        # triangle list (features.py, stage_features_tiled / feature_contact_tiled; no skin BVH refit
        # per stage and pass); lanes per block: FEATURE_LANES on CUDA, 1 on the CPU (a block is one
        # thread there: the CPU runs these kernels only when a test sets tiled_features)
        # (no BVH refit per stage and pass on CUDA unless tiled_features is False). Batches of
        # FEATURE_SCAN_WORLDS or more on CUDA (tiled_features None) run a thread per listed feature over its patch
        # (features.py stage_features_scan / feature_contact_scan: the batch's features fill the GPU)
        cuda = wp.get_device(d).is_cuda
        tf = config.tiled_features
        self.tiled_features = bool(cuda and (tf is None or tf))
        self.feature_scan = bool(cuda and tf is None and w >= FEATURE_SCAN_WORLDS and config.feature_winding)
        self.feature_lanes = FEATURE_LANES if cuda else 1
        self.patch_lanes = PATCH_LANES if cuda else 1  # (feature_patches_tiled's block)
        self._patch_used_host = wp.zeros(3, dtype=int, device="cpu", pinned=cuda)
        self._patch_warned = False
        # buffers replaced since the contact was made (a grown patch pool): the recorded frames read the
        # old ones, so the solver records its frames again when this changes (Solver._queue_frame)
        self.reallocations = 0
        # m, Warp's tie tolerance of the pseudo-normal sign (1e-3 x the skin's average edge length,
        # mesh_query_point_sign_normal), here of the rest skin's
        rest = model.rest_x[: int(f.max()) + 1].numpy()[f] if len(f) else np.zeros((0, 3, 3))
        edges = np.linalg.norm(rest - np.roll(rest, -1, axis=1), axis=2)
        self.feature_eps = float(1.0e-3 * edges.mean()) if len(f) else 0.0
        self._counters_host = wp.zeros(self.counters.shape[0], dtype=int, device="cpu",
                                       pinned=wp.get_device(d).is_cuda)
        self._stage_slots = []  # per recorded stage: (active-list slot, first-pass touched slots)
        self.pass_slots = []  # per recorded pass: the slot of its triangle list's length
        # per later pass of a frame: 1 when the pass before it moved a vertex (set by keep_moved, read by
        # the pass's conditional graph node on CUDA, activity.py level 2; zeroed per frame)
        self.pass_flags = wp.zeros(max(stages * config.contact_passes, 1), dtype=wp.int32, device=d)
        # Config.tuning.contact_pass_tol: per pass (by its stamp, a counter slot) its largest vertex move, m
        # (zeroed per frame), and per stage the tolerance its passes stop at (0 in the frame's last
        # stage: set by finish_recording); both empty when the tolerance is 0 (no work, no flag change)
        tol = config.contact_pass_tol > 0
        self.pass_move = wp.zeros(self.counters.shape[0] if tol else 0, dtype=float, device=d)
        self.stage_tol = wp.zeros(max(stages, 1) if tol else 0, dtype=float, device=d)
        self._stage_tol_host = np.zeros(self.stage_tol.shape[0], np.float32)
        self._passes_gated = False  # (finish_recording: as the solver's frame last said)
        cuda = wp.get_device(d).is_cuda
        self._pass_move_host = (wp.zeros(self.pass_move.shape[0], dtype=float, device="cpu", pinned=True) if cuda
                                else self.pass_move)
        self._feat_host = wp.zeros(1, dtype=int, device="cpu", pinned=wp.get_device(d).is_cuda)
        self._make_planes_buffers()  # (Config.contact_linear: linear.py)

    # -- recording into the solver's frame --------------------------------------------------------
    def wants(self, stage: str) -> bool:
        p = self.config.contact_placement
        return (stage == "before" and p in (Placement.BEFORE, Placement.BOTH)) or (
            stage == "after" and p in (Placement.AFTER, Placement.BOTH))

    def zero_counters(self, rec) -> None:
        """Zero the frame's list lengths (``counters``), where the frame's broadphase is recorded
        (``rec.ahead_ops()``): before :meth:`record_frame`, outside its gate (the gates read them)."""
        rec.ahead_ops().append(self.counters.zero_)

    def record_frame(self, rec, state) -> None:
        """Once per frame, before the substeps: the frame's broadphase over all skin triangles with
        ``contact_frame_margin``; each stage then tests only this list. What follows the broadphase
        is recorded into ``rec.gated(..., 1)``, a block the solver runs only when the list is not
        empty (physhand_mj/solver/activity.py); :meth:`zero_counters` first. The broadphase goes
        to ``rec.launch_ahead`` (CUDA: ahead of the frame's graph, Solver.step)."""
        m, o, cfg = self.model, self.objects, self.config
        if not self.n_tris:
            return
        self._slot = 1
        self._stage_slots = []
        self.pass_slots = []
        rec.launch_ahead(find_active, self.n_tris,
                         [m.skin_faces, state.x, o.gtype, o.size, o.inv_pose, o.radius, o.mesh, o.count,
                          self.tris_per_world, self.geoms_per_world, cfg.contact_frame_margin],
                         [self.cand, self.cand_mask, self.cand_count])
        rec.gated(lambda sub: self._record_frame_lists(rec, state), 1)

    def _record_frame_lists(self, rec, state) -> None:
        """The per-frame resets and the frame's feature list (after the broadphase)."""
        m, o, cfg = self.model, self.objects, self.config
        rec.ops += [self.moved.zero_, lambda: self.bound.fill_(-1.0e30), self.pass_flags.zero_]  # objects moved
        pts = self.points
        if cfg.feature_contact and self.closed_skin and pts.n_features:
            if self.feat is None:
                self.feat = wp.zeros(pts.n_features, dtype=int, device=m.device)
                self.feat_stage = wp.zeros(pts.n_features, dtype=int, device=m.device)
                if cfg.feature_winding:
                    n = pts.n_features
                    self.patch_pool = wp.zeros(patch_pool_size(n, cfg.contact_frame_margin), dtype=int,
                                               device=m.device)
                    # [entries the patches need in all, taken at the pool's top, patches that did not fit]
                    self.patch_used = wp.zeros(3, dtype=int, device=m.device)
                    self.feat_slot = wp.zeros(pts.pts.shape[0], dtype=int, device=m.device)  # by point index
                    self.patch_start = wp.zeros(n, dtype=int, device=m.device)
                    self.patch_len = wp.full(n, -1, dtype=int, device=m.device)
                    self.patch_fill = wp.zeros(n, dtype=int, device=m.device)  # CUDA's appends per feature
                    self.far_angle = wp.zeros(n, dtype=float, device=m.device)
                    self.feat_side = wp.zeros(n, dtype=float, device=m.device)  # CPU: the stage's sides
                self._make_slack(pts.pts.shape[0])  # Config.tuning.feature_slack's buffers (slack.py)
            vol = self.volume(state, winding=False)
            qpose = self._query_pose(rec)
            rec.ops += [self.feat_count.zero_, self.feat_stage_counts.zero_, *self._slack_start_ops(state),
                    *vol.refit_ops()]
            rec.launch(near_features, pts.n_features, [vol.mesh.id, pts.feature, pts.pts, pts.geom, qpose, o.count,
                                                   cfg.contact_frame_margin, cfg.contact_margin, self.slack,
                                                   FEATURE_LIST_SHARE, self.geoms_per_world],
                   [self.feat, self.feat_count, self.feat_dist, self.pt_dist, self.pt_face, self.world_listed])
            if cfg.feature_winding and self.tiled_features and not self.feature_scan:  # CUDA, one hand:
                # a block per feature over its world's skin
                rec.ops += [self.patch_used.zero_, self.patch_fill.zero_]
                lanes = self.patch_lanes
                nb = tiled_blocks(m.device, pts.n_features, lanes)
                rec.launch(feature_patches_tiled, (nb, lanes),
                       [m.skin_faces, self._query_x(state), self.feat, self.feat_count, nb, pts.pts, pts.geom, qpose,
                        cfg.contact_frame_margin, self.feat_dist, self.slack, self.tris_per_world,
                        self.geoms_per_world],
                       [self.patch_used, self.patch_pool, self.feat_slot, self.patch_start, self.patch_len,
                        self.patch_fill, self.far_angle], block_dim=lanes)
            elif cfg.feature_winding:  # the local winding number's patches and far angles (features.py)
                volw = self.volume(state, winding=True)
                rec.ops += [self._refit_op(volw), self.patch_used.zero_]
                rec.launch(feature_patches, pts.n_features,
                       [vol.mesh.id, volw.mesh.id, m.skin_faces, self._query_x(state), self.feat, self.feat_count,
                        pts.pts, pts.geom, qpose, cfg.contact_frame_margin, cfg.contact_frame_margin, self.feat_dist,
                        self.slack, self.geoms_per_world, PATCH_SLOT],
                       [self.patch_used, self.patch_pool, self.feat_slot, self.patch_start, self.patch_len,
                        self.far_angle], count=self.feat_count)

    def _counter(self):
        if self._slot >= self.counters.shape[0]:
            raise RuntimeError(f"contact: the frame's {self.counters.shape[0]} counter slots are all taken "
                               "(a recording that takes more than Contact.__init__ sized them for)")
        c = self.counters[self._slot: self._slot + 1]
        self._slot += 1
        return c

    def record(self, rec, state) -> None:
        """One contact stage: broadphase over the frame's list, then ``contact_passes`` x (decision
        points + Eq. 9, averaged apply); a later pass queries only the stage's triangles with a
        vertex the previous pass moved (the others cannot have changed). Through the solver's gates
        (``rec.gated``) a pass after one that moved no vertex is skipped (CPU; it would repeat that pass on the same
        skin: activity.py level 2)."""
        m, o, cfg = self.model, self.objects, self.config
        if not self.n_tris:
            return
        # (active-list slot, first pass's Eq. 9 touched slot, its feature touched slot or -1)
        self._stage_slots.append((self._slot, self._slot + 2, self._slot + 3 if self.feat is not None else -1))
        self.active_count = self._counter()
        lst = (self.pass_list, self.pass_mask, self._counter())
        self.pass_slots.append(self._slot - 1)
        # the stage's active triangles (within contact_margin) of the frame's list, and of those its
        # first pass's list, in one launch
        rec.launch(stage_lists, self.n_tris, [m.skin_faces, state.x, o.gtype, o.size, o.inv_pose, o.radius, o.mesh, o.count,
                                          self.tris_per_world, self.geoms_per_world, cfg.contact_margin, self.cand,
                                          self.cand_mask, self.cand_count, self.bound, self.bound_mask, self.eval_x],
               [self.active, self.active_mask, self.active_count, *lst], count=self.cand_count)
        stage = len(self._stage_slots) - 1
        if self.world_stage is not None:  # the stage's active triangles per world
            rec.launch(tally_worlds, self.n_tris, [self.active, self.active_count, self.tris_per_world, m.vertex_world,
                                               2 * stage], [self.world_stage], count=self.active_count)
        if self.feat is not None and self.feature_scan:  # the stage's features, a thread each (CUDA batches)
            feat_count = self.feat_stage_counts[stage: stage + 1]
            skin = None
            rec.ops += self.volume(state, winding=False).sync_ops()
            self._first_push = self.counters[self._slot + 1: self._slot + 2]  # (as the tiled path's, below)
            rec.launch(stage_features_scan, self.points.n_features,
                   self._feature_inputs(state, self.feat, self.feat_count, cfg.feature_offset, self._first_push,
                                        out=self.feat_stage, out_count=feat_count), [])
        elif self.feat is not None and self.tiled_features:  # the stage's features, a block each (CUDA),
            # with its first pass's feature push (into that pass's counter slot, taken by _record_features)
            feat_count = self.feat_stage_counts[stage: stage + 1]
            skin = None
            rec.ops += self.volume(state, winding=False).sync_ops()
            self._first_push = self.counters[self._slot + 1: self._slot + 2]  # after the pass's Eq. 9 slot
            nb = tiled_blocks(m.device, self.points.n_features, self.feature_lanes)
            rec.launch(stage_features_tiled, (nb, self.feature_lanes),
                   self._feature_inputs(state, self.feat, self.feat_count, cfg.feature_offset, self._first_push,
                                        stride=nb, out=self.feat_stage, out_count=feat_count), [],
                   block_dim=self.feature_lanes)
        elif self.feat is not None:  # the stage's features (features.py)
            feat_count = self.feat_stage_counts[stage: stage + 1]
            vol = self.volume(state, winding=False)
            skin = vol.mesh
            rec.ops.append(self._refit_op(vol))
            rec.launch(stage_features, self.points.n_features,
                   self._feature_inputs(state, self.feat, self.feat_count, cfg.feature_offset, None, skin=skin,
                                        out=self.feat_stage, out_count=feat_count), [],
                   count=self.feat_count)
        else:
            skin = feat_count = None
        prev: tuple = ()  # counter slots of the vertices the previous pass moved
        flag = None  # the device flag the previous pass's keep_moved set from them (activity.py level 2)
        for p in range(cfg.contact_passes):
            if p:
                box: dict = {}
                gate = rec.gated(lambda sub, p=p: box.update(r=self._record_pass(rec, state, p, lst, skin,
                                                                                 feat_count)), 2, prev, flag)
                if gate is not None and len(self.pass_move):  # (Config.tuning.contact_pass_tol: the CPU's host test)
                    gate.moved_enough = self._moved_enough(prev[0], stage)
                lst, prev, flag = box["r"]
            else:
                lst, prev, flag = self._record_pass(rec, state, p, lst, skin, feat_count)
        self.record_make_planes(rec, state, feat_count)  # (Config.contact_linear: linear.py)

    def _record_pass(self, rec, state, p, lst, skin, feat_count):
        """One pass of a stage; returns the next pass's list, this pass's touched counter slots and
        the device flag (1 when one of them is not zero) the next pass's conditional node reads."""
        m, o, cfg = self.model, self.objects, self.config
        stamp = self._slot  # unique within the frame (moved is zeroed per frame)
        moved_slots = [self._slot]
        self.touched_count = self._counter()
        outs = [self.delta, self.hits, self.decision, self.vertex_obj, self.bound, self.bound_mask, self.eval_x,
                self.touched, self.touched_count]
        if self.feat is not None:  # features.py: the stage's list against the skin as it is now, applied
            # before Eq. 9 (one after the other: averaged together, the two undid each other at rims)
            slot, feat_touched = self._record_features(rec, state, p, skin, feat_count, stamp)
            moved_slots.append(slot)
            self._tally_touched(rec, p, feat_touched)
        def decide(stride):  # the decision points' inputs (query.decide_inputs)
            return decide_inputs(m.skin_faces, o, self.tris_per_world, self.geoms_per_world, lst, stride,
                                 int(cfg.contact), cfg.multires_samples, cfg.multires_rounds, cfg.opt_queries,
                                 cfg.contact_offset, int(self.closed_skin and cfg.side_aware), state.x)

        if self.tiled:  # CUDA multires: a block per triangle, a lane per lattice sample
            nb = tiled_blocks(m.device, self.n_tris, TILE_LANES)
            rec.launch(tiled_kernel_for(o.has_mesh), (nb, TILE_LANES), decide(nb), outs, block_dim=TILE_LANES)
        else:
            kernel = decide_and_project  # (Config.execution.multires_registers: a copy specialised to multires)
            regs = multires_registers_for(cfg, wp.get_device(m.device).is_cuda, m.worlds, o.has_mesh)
            block = None
            if regs:  # (its block size passed to the launch: Warp launches 256 on CUDA whatever the module says)
                block = int(cfg.multires_block_dim)
                kernel = multires_kernel(regs, block)
            rec.launch(kernel, self.n_tris, decide(0), outs, count=lst[2], block_dim=block)
        shift, shifted = self._apply_shift(state)
        rec.launch(apply_contact, m.n_vertices, [self.touched, self.touched_count, stamp, self.delta, self.hits, shift],
               [state.x, self.push, self.moved, self.disp, self.pass_move, shifted], count=self.touched_count)
        self._tally_touched(rec, p, self.touched_count)
        if p + 1 == cfg.contact_passes and self.feat is not None and cfg.feature_last:
            moved_slots.append(self._record_features(rec, state, p + 1, skin, feat_count, stamp)[0])
        flag = None
        if p + 1 < cfg.contact_passes:
            lst = (self.pass_list, self.pass_mask, self._counter())
            self.pass_slots.append(self._slot - 1)
            j = len(self.pass_slots) - 1  # (one flag per later pass of the frame, zeroed with the frame)
            flag = self.pass_flags[j: j + 1]
            rec.launch(keep_moved, self.n_tris, [m.skin_faces, self.active, self.active_mask, self.active_count,
                                             self.moved, self.disp, stamp, self.bound, self.counters,
                                             self._slot_array(moved_slots), self.pass_move, self.stage_tol,
                                             len(self._stage_slots) - 1],
                   [*lst, flag],
                   count=self.active_count, min_dim=1)
        return lst, tuple(moved_slots), flag

    def _moved_enough(self, stamp: int, stage: int):
        """Config.tuning.contact_pass_tol's host test of a pass (the CPU's level-2 gate; CUDA's keep_moved
        sets the device flag the same way): did the pass ``stamp`` move some vertex by more than its
        stage's tolerance?"""
        move = self._pass_move_host.numpy()  # (the CPU: a view; CUDA: the frame's copy, for reports)
        return lambda: self._stage_tol_host[stage] <= 0.0 or move[stamp] > self._stage_tol_host[stage]

    def finish_recording(self, passes_gated: bool | None = None) -> None:
        """After a frame (or a stage) is recorded: Config.tuning.contact_pass_tol for every stage but the
        last recorded one, which runs its passes to the end; none where a pass cannot be skipped whole
        (``passes_gated`` False: Activity.passes_gated; a pass's feature push runs outside its list,
        so an emptied list alone would apply half a pass; None: as the solver's frame last said)."""
        if passes_gated is None:
            passes_gated = self._passes_gated
        else:
            self._passes_gated = bool(passes_gated)
        n = len(self._stage_slots)
        if len(self.stage_tol) and n:  # (a host write: recorded frames and graphs read the array)
            tol = np.full(self.stage_tol.shape[0], self.config.contact_pass_tol if passes_gated else 0.0,
                          np.float32)
            tol[n - 1:] = 0.0
            self.stage_tol.assign(tol)
            self._stage_tol_host = tol

    def _slot_array(self, slots) -> wp.array:
        """``slots`` (counter indices) as a device array, made once and held (recorded launches read it)."""
        key = tuple(int(s) for s in slots)
        a = self._slot_ids.get(key)
        if a is None:
            a = self._slot_ids[key] = wp.array(np.asarray(key, np.int32), dtype=int, device=self.model.device)
        return a

    def _tally_touched(self, rec, p: int, count) -> None:
        """Batched worlds: the vertices a stage's first pass corrected (``self.touched``, ``count``
        long), per world (the log's ``contacts``)."""
        if self.world_stage is not None and p == 0:
            m = self.model
            rec.launch(tally_worlds, m.n_vertices, [self.touched, count, 0, m.vertex_world,
                                                2 * (len(self._stage_slots) - 1) + 1], [self.world_stage], count=count)

    def _fit_patch_pool(self) -> None:
        used, _, failed = (int(v) for v in self._patch_used_host.numpy())
        # (the BVH path counts the patches that did not fit; CUDA's tiled one packs them, full past the
        # pool's size; < 0: an int32 counter wrapped past 2^31)
        size = self.patch_pool.shape[0]
        over = bool(failed or used > size or used < 0)
        if size < PATCH_POOL_MAX and (over or 2 * used > size):
            # (a power of two at least twice the need and the pool: a list that keeps growing re-records rarely)
            grown = PATCH_POOL_MAX if used < 0 else min(1 << (max(2 * used, 2 * size) - 1).bit_length(), PATCH_POOL_MAX)
            self.patch_pool = wp.zeros(grown, dtype=int, device=self.model.device)
            self.reallocations += 1
        elif over and not self._patch_warned:
            from physhand_mj.warn import warn_user

            self._patch_warned = True
            need = f"{used:,}" if used >= 0 else "over 2^31"
            what = f"{failed} object feature points' patches did not fit: " if failed else ""
            per = f" ({self.worlds} worlds)" if self.worlds > 1 else ""
            warn_user(f"contact: {what}the feature points' patches (the skin triangles near each, for its inside "
                      f"test) needed {need} entries packed, more than the pool's most{per}, {size:,} (4 GiB): "
                      f"points past it kept the pseudo-normal sign (one hand) or were not pushed (CUDA batches). "
                      f"Run fewer worlds per BatchedHands, or a smaller Config.contact_frame_margin (the "
                      f"patches' radius)", RuntimeWarning)

    def begin_frame(self, ops: list) -> None:
        """Reset the per-frame report buffers (metrics, push, touched object)."""
        ops += [self.metrics.zero_, self.push.zero_, lambda: self.vertex_obj.fill_(-1)]
        if len(self.pass_move):  # (Config.tuning.contact_pass_tol)
            ops.append(self.pass_move.zero_)
        if self.world_stage is not None:
            ops.append(self.world_stage.zero_)

    @property
    def points(self) -> ObjectPoints:
        """The objects' surface points (built on first use)."""
        if self._points is None:
            self._points = ObjectPoints(self.objects, edge_spacing=self.config.feature_spacing)
        return self._points

    # -- host side ---------------------------------------------------------------------------------
    def run_stage(self, state) -> np.ndarray:
        """Run one contact stage now (broadphase + passes) on ``state.x``; returns (F, 4) decision
        points of the last pass (x*, phi(x*)) with phi = FAR for triangles the broadphase skipped.
        For tests and diagnostics: inside a frame the solver records the same launches."""
        rec = Recorder(self.model.device)
        rec.ops.append(lambda: self.decision.fill_(wp.vec4(0.0, 0.0, 0.0, 1.0e6)))
        kept = (self._slot, self._stage_slots, self.active_count, self.touched_count, self.pass_slots)
        self.zero_counters(rec)
        self.record_frame(rec, state)
        self.record(rec, state)
        gated = self._passes_gated
        self.finish_recording(False)  # (one stage, ungated: the last, run to the end)
        self._passes_gated = gated
        stage_active = self.active_count
        (self._slot, self._stage_slots, self.active_count, self.touched_count,
         self.pass_slots) = kept  # the solver frame's
        for op in rec.ops:
            op()
        wp.synchronize_device(self.model.device)
        self.finish_recording(None)  # (the solver frame's stages again)
        self.stage_active_count = int(stage_active.numpy()[0])
        return self.decision.numpy()[: self.n_tris].copy()
