"""The contact stage of a substep (Algorithm 1, line 6): broadphase, decision points, Eq. 9.

:class:`Contact` owns the preallocated contact buffers of one solver, declared in contact/data.py
(:class:`~physhand_mj.contact.data.FrameLists`: the frame's, stages' and passes' lists;
:class:`~physhand_mj.contact.data.PassBuffers`: what a pass computes and applies), and records its launches into
the solver's frame through a :class:`~physhand_mj.launch.Recorder` (so a CUDA graph captures them):
the frame's lists, the stages and their passes (Eq. 9, then the feature push), and the frame's
host-side reports. It holds, each owning its own data: where the object side's queries run
(:class:`~physhand_mj.contact.query_space.QuerySpace`, ``space``), the feature lists' slack and its
check (:class:`~physhand_mj.contact.slack.SlackCheck`, ``slack_check``), and Config.contact_linear's
planes (:class:`~physhand_mj.contact.linear.PlaneHold`, ``hold``), and the penetration measures with
their rows (:class:`~physhand_mj.contact.measures.ContactMeasures`, ``measures``).
"""

from __future__ import annotations

import contextlib

import numpy as np
import warp as wp

from physhand_mj.contact.data import (FeatureLists, make_feature_lists, make_frame_lists,
                                      make_metrics_buffers, make_pass_buffers)
from physhand_mj.contact.bones import (RESTORE_ROUNDS, RESTORE_ROUNDS_LAST, bone_report, hold_depth, hold_skin,
                                      make_bone_hold, record_restore)
from physhand_mj.contact.exchange import TwoWay
from physhand_mj.contact.broadphase import NO_LIST, find_active, keep_moved, stage_lists, tally_worlds
from physhand_mj.contact.features import (FEATURE_LANES, near_features, stage_features, stage_features_scan,
                                          stage_features_tiled)
from physhand_mj.contact import patch_pool  # (its constants read at recording: tests shrink them)
from physhand_mj.contact.patches_tiled import PATCH_LANES, feature_patches_tiled
from physhand_mj.contact.winding import feature_patches
from physhand_mj.contact.inside import ObjectPoints
from physhand_mj.contact.linear import HOLD_SLOTS, PlaneHold
from physhand_mj.contact.measures import ContactMeasures
from physhand_mj.contact.objects import Objects
from physhand_mj.contact.features import feature_contact, feature_contact_scan, feature_contact_tiled, feature_inputs
from physhand_mj.contact.query import apply_contact, decide_and_project, decide_inputs, multires_kernel
from physhand_mj.contact.query_space import QuerySpace
from physhand_mj.contact.query_tiled import TILE_LANES, tiled_kernel_for
from physhand_mj.contact.slack import SlackCheck
from physhand_mj.contact.touch import TouchDamping
from physhand_mj.config import FEATURE_LIST_SHARE
from physhand_mj.types import Config, Model, Placement, Settings, Strategy
from physhand_mj.launch import Recorder, tiled_blocks

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


class Contact:
    """Skin-object contact for a solver ``Model`` against ``objects`` (see Config.contact*)."""

    capturable = True

    def __init__(self, model: Model, objects: Objects, config: Config):
        if not _same_device(objects.device, model.device):
            raise ValueError(f"objects live on {objects.device}, the model on {model.device}")
        d = model.device
        self.model, self.objects, self.config = model, objects, config
        n_tris = model.skin_faces.shape[0]
        self.n_tris = n_tris
        # batched worlds (physhand_mj/batch.py): world w holds triangles [w F_w, (w + 1) F_w) and
        # geoms [w k, (w + 1) k); every list and metric is indexed by world (one world: w = 0)
        self.worlds = w = int(getattr(model, "worlds", 1))
        if w > 1 and (n_tris % w or objects.capacity % w):
            raise ValueError(f"batched worlds: {n_tris} skin triangles and {objects.capacity} geoms do not split "
                             f"into {w} equal worlds")
        self.tris_per_world = max(n_tris // w, 1)
        self.geoms_per_world = max(objects.capacity // w, 1)
        # where the object side's queries run: the skin meshes, and batched worlds solved at one
        # origin but queried apart (set_query_offsets)
        self.space = QuerySpace(model, objects, w, self.geoms_per_world)
        # the frame's, stages' and passes' lists and their lengths (contact/data.py)
        holds = config.substeps * HOLD_SLOTS if config.contact_linear and config.contact_every > 1 else 0
        # (+ 1: the last counter slot, the skin vertices held by bones inside objects this frame: bones.py)
        self.lists = make_frame_lists(model, config, w, holds + 1)
        self.acc = make_pass_buffers(model)  # what a pass computes and applies
        self.touch = TouchDamping(config)  # Config.tuning.touch_damping, after each stage (touch.py)
        # recording cursors: the length slots (counters) of the frame's list, the stage's and the pass's touched
        self.cand_count = self.lists.counters[0:1]
        self.active_count = self.cand_count  # replaced per stage by its counter
        self.touched_count = self.cand_count
        self._slot = 1
        # CUDA multires runs the tiled kernel when a block holds the lattice (and the centroid), by
        # default for one hand only: its launch has a block per skin triangle, which batched worlds
        # fill with idle blocks (Config.execution.tiled_contact)
        tiled = config.tiled_contact if config.tiled_contact is not None else model.worlds == 1
        self.tiled = bool(wp.get_device(d).is_cuda and config.contact == Strategy.MULTIRES
                          and config.multires_samples < TILE_LANES and tiled)
        self._points = None  # ObjectPoints, built on first use from the geoms of Objects.version:
        self._objects_version = objects.version  # (made again when that changes: sync_objects)
        # the object's side (features.py, the second measure) needs an inside: a closed skin
        # (batched worlds: world 0's faces, which name world 0's skin vertices; every world is a copy,
        # and the tolerance below is then the serial hand's to the bit)
        f = model.skin_faces[: self.tris_per_world].numpy() if n_tris else np.zeros((0, 3), np.int32)
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1).astype(np.int64)
        key = e[:, 0] * (int(e.max(initial=0)) + 1) + e[:, 1]  # one integer per edge: a 1-D unique (fast for W worlds)
        self.closed_skin = bool(len(f)) and bool(np.all(np.unique(key, return_counts=True)[1] == 2))
        # both penetration measures and their rows (measures.py)
        self.measures = ContactMeasures(model, objects, config, make_metrics_buffers(model, config, w), self.space,
                                        n_tris=n_tris, worlds=w, tris_per_world=self.tris_per_world,
                                        geoms_per_world=self.geoms_per_world, closed_skin=self.closed_skin)
        # the feature push's lists of object feature points near the skin and their patches (data.py),
        # made at the first recording with feature points (None: no feature push)
        self.features: FeatureLists | None = None
        self.slack_check = None  # the lists' slack and its check (slack.py), made with the lists
        self._slot_ids = {}  # counter slots as device arrays, per tuple of slots (Contact._slot_array)
        self._first_push = None  # the stage's first-pass feature counter (CUDA: filled by stage_features_tiled)
        # m, the radius a feature's skin query tries first (features.closest_signed): a pass's
        # features lie within ~contact_margin of the skin; the frame margin is the fallback
        self.near_query = float(min(config.contact_frame_margin, max(4.0 * config.contact_margin, 1.0e-3)))
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
        self._patch_warned = False
        # buffers replaced since the contact was made (a grown patch pool): the recorded frames read the
        # old ones, so the solver records its frames again when this changes (Solver._queue_frame)
        self.reallocations = 0
        # m, Warp's tie tolerance of the pseudo-normal sign (1e-3 x the skin's average edge length,
        # mesh_query_point_sign_normal), here of the rest skin's
        rest = model.rest_x[: int(f.max()) + 1].numpy()[f] if len(f) else np.zeros((0, 3, 3))
        edges = np.linalg.norm(rest - np.roll(rest, -1, axis=1), axis=2)
        self.feature_eps = float(1.0e-3 * edges.mean()) if len(f) else 0.0
        self._stage_slots = []  # per recorded stage: (active-list slot, first-pass touched slots)
        self.pass_slots = []  # per recorded pass: the slot of its triangle list's length
        self._passes_gated = False  # (finish_recording: as the solver's frame last said)
        # what a push may do to each skin vertex, from its bones (Config.tuning.bone_hold, bones.py)
        n = self.lists.counters.shape[0]
        self.held_slot = n - 1
        self.hold_depth = hold_depth(config)  # m (0.5 mm where MuJoCo keeps the bones out, else 2)
        self.bone_hold = make_bone_hold(model, config.bone_hold, self.lists.counters[n - 1: n], self.hold_depth)
        # Config.two_way: the skin's impulses and friction on the objects and bones (exchange.py)
        self.two_way = TwoWay(model, objects, config, self.space, self.geoms_per_world)
        # Config.contact_linear: the planes a stage leaves for the substeps without one (linear.py)
        self.hold = PlaneHold(model, objects, config, n_tris, self.tris_per_world, self.geoms_per_world,
                              int(self.closed_skin and config.side_aware))

    @property
    def counters(self) -> wp.array:
        """The frame's list lengths (:attr:`FrameLists.counters`; the solver's gates read them)."""
        return self.lists.counters

    @property
    def exchange(self):
        """The :class:`~physhand_mj.contact.exchange.Exchange` every contact push records into (two-way coupling)."""
        return self.two_way.data

    @property
    def push(self) -> wp.array:
        """(V,) float m: each vertex's contact move summed over the last frame (:attr:`PassBuffers.push`)."""
        return self.acc.push

    @property
    def vertex_obj(self) -> wp.array:
        """(V,) int: the object that last pushed each vertex in the last frame, -1 none
        (:attr:`PassBuffers.vertex_obj`)."""
        return self.acc.vertex_obj

    def volume(self, state, winding: bool = True):
        """The closed skin of ``state`` as a mesh (:meth:`QuerySpace.volume`)."""
        return self.space.volume(state, winding)

    def new_episode(self) -> None:
        """What a new episode starts over (SoftHand.reset, BatchedHands.restart): the feature lists'
        slack and, with two-way coupling, the exchange's object and bone state and the skin's friction
        anchors: an episode does not depend on the one before it."""
        if self.slack_check is not None:
            self.slack_check.restart()
        if self.two_way is not None:
            self.two_way.clear()

    def set_query_offsets(self, offsets) -> None:
        """Batched worlds solved at one origin, queried apart (:meth:`QuerySpace.set_offsets`)."""
        self.space.set_offsets(offsets)

    @property
    def query_shift(self):
        """Each skin vertex's world offset for the object side's queries (None: not queried apart)."""
        return self.space.shift

    # -- recording into the solver's frame --------------------------------------------------------
    def wants(self, stage: str) -> bool:
        p = self.config.contact_placement
        return (stage == "before" and p in (Placement.BEFORE, Placement.BOTH)) or (
            stage == "after" and p in (Placement.AFTER, Placement.BOTH))

    def zero_counters(self, rec) -> None:
        """Zero the frame's list lengths (``counters``), where the frame's broadphase is recorded
        (``rec.ahead_ops()``): before :meth:`record_frame`, outside its gate (the gates read them)."""
        rec.ahead_ops().append(self.lists.counters.zero_)

    def record_frame(self, rec, state) -> None:
        """Once per frame, before the substeps: the frame's broadphase over all skin triangles with
        ``contact_frame_margin``; each stage then tests only this list. What follows the broadphase
        is recorded into ``rec.gated(..., 1)``, a block the solver runs only when the list is not
        empty (physhand_mj/solver/activity.py); :meth:`zero_counters` first. The broadphase goes
        to ``rec.launch_ahead`` (CUDA: ahead of the frame's graph, Solver.step)."""
        m, o, cfg = self.model, self.objects, self.config
        self.touch.begin_frame()
        if not self.n_tris:
            return
        self._slot = 1
        self._stage_slots = []
        self.pass_slots = []
        rec.launch_ahead(find_active, self.n_tris,
                         [m.skin_faces, state.x, o.geoms, self.tris_per_world, self.geoms_per_world,
                          cfg.contact_frame_margin, NO_LIST, *[None] * 4],
                         [self.lists.cand_tris, self.cand_count, NO_LIST, None])
        rec.gated(lambda sub: self._record_frame_lists(rec, state), 1)

    def _record_frame_lists(self, rec, state) -> None:
        """The per-frame resets, the skin held by bones inside objects and the frame's feature list
        (after the broadphase)."""
        m, o, cfg = self.model, self.objects, self.config
        if cfg.bone_hold and m.n_skin:  # (bones.py: at the frame's last bone pose)
            rec.ops.append(self.bone_hold.gripped.zero_)
            rec.launch(hold_skin, m.n_skin, [m.skin_body, m.skin_local, m.skin_anchor, m.vertex_world, state.body_sub,
                                             cfg.substeps - 1, o.geoms, self.geoms_per_world, o.count],
                       [self.bone_hold])
        # (the objects moved: every triangle's bound is stale)
        rec.ops += [self.acc.moved.zero_, lambda: self.acc.bound.fill_(-1.0e30), self.lists.pass_flags.zero_]
        pts = self.points
        if cfg.feature_contact and self.closed_skin and pts.n_features:
            if self.features is None:
                pool = patch_pool.patch_pool_size(pts.n_features, cfg.contact_frame_margin)
                self.features = make_feature_lists(pts, cfg, pool, m.device)
                # Config.tuning.feature_slack's buffers and check (slack.py)
                self.slack_check = SlackCheck(m, o, cfg, pts, self.worlds, self.geoms_per_world)
            fl, sd = self.features, self.slack_check.data
            vol = self.space.volume(state, winding=False)
            qpose = self.space.record_pose(rec)
            rec.ops += [fl.count.zero_, fl.stage_counts.zero_, *self.slack_check.start_ops(state), *vol.refit_ops()]
            rec.launch(near_features, pts.n_features, [vol.mesh.id, pts.feature, pts.pts, pts.geom, qpose, o.count,
                                                       cfg.contact_frame_margin, cfg.contact_margin, sd.slack,
                                                       FEATURE_LIST_SHARE, self.geoms_per_world],
                       [fl.listed, fl.count, sd.feat_dist, sd.pt_dist, sd.pt_face, sd.world_listed])
            if cfg.feature_winding and self.tiled_features and not self.feature_scan:  # CUDA, one hand:
                # a block per feature over its world's skin
                rec.ops += [fl.patch_used.zero_, fl.patch_fill.zero_]
                lanes = self.patch_lanes
                nb = tiled_blocks(m.device, pts.n_features, lanes)
                rec.launch(feature_patches_tiled, (nb, lanes),
                           [m.skin_faces, self.space.skin_x(state), fl.listed, fl.count, nb, pts.pts, pts.geom, qpose,
                            cfg.contact_frame_margin, sd.feat_dist, sd.slack, self.tris_per_world,
                            self.geoms_per_world],
                           [fl.patch_used, fl.patches, fl.patch_fill], block_dim=lanes)
            elif cfg.feature_winding:  # the local winding number's patches and far angles (features.py)
                volw = self.space.volume(state, winding=True)
                rec.ops += [self.space.refit_op(volw, fl.count), fl.patch_used.zero_]
                rec.launch(feature_patches, pts.n_features,
                           [vol.mesh.id, volw.mesh.id, m.skin_faces, self.space.skin_x(state), fl.listed, fl.count,
                            pts.pts, pts.geom, qpose, cfg.contact_frame_margin, cfg.contact_frame_margin, sd.feat_dist,
                            sd.slack, self.geoms_per_world, patch_pool.PATCH_SLOT],
                           [fl.patch_used, fl.patches], count=fl.count)

    def record_frame_end(self, rec, state) -> None:
        """At the end of a frame with contact: the skin's move against the feature lists' slack
        (:meth:`SlackCheck.record_frame_end`); nothing without listed feature points."""
        if self.features is not None:
            self.slack_check.record_frame_end(rec, state)

    def feature_motion(self, ran: bool = True, warn: bool = True) -> dict:
        """The last frame's feature-list check, worst world (:meth:`SlackCheck.feature_motion`);
        empty without feature points."""
        return {} if self.features is None else self.slack_check.feature_motion(ran, warn)

    def feature_motion_worlds(self, ran: bool = True) -> list:
        """Per world, 1 where the last frame's feature-list check failed
        (:meth:`SlackCheck.feature_motion_worlds`); empty without feature points."""
        return [] if self.features is None else self.slack_check.feature_motion_worlds(ran)

    # -- Config.contact_linear's hold (linear.py) --------------------------------------------------
    @property
    def holds(self) -> bool:
        """Whether substeps without a contact stage hold the skin on the last stage's planes."""
        return self.hold.holds

    def forget_planes(self, state=None) -> None:
        """Drop the planes (:meth:`PlaneHold.forget`)."""
        self.hold.forget(state)

    def record_frame_planes(self, rec) -> None:
        """Every frame, contact or not: last frame's planes become the previous ones."""
        self.hold.record_frame(rec)

    def _held_points(self):
        """The object points whose feature points the hold keeps: with the feature push (the
        frame's lists made before any stage or hold) and the worlds not queried apart; else None."""
        return self.points if self.features is not None and self.space.shift is None else None

    def _record_make_planes(self, rec, state, feat_count) -> None:
        """After a stage's last pass: its planes and kept feature points (:meth:`PlaneHold.record_make`)."""
        if not self.hold.holds:
            return
        features = None
        pts = self._held_points() if feat_count is not None else None
        if pts is not None:
            vol = self.space.volume(state, winding=False)
            features = (pts, self.features.stage, feat_count, vol, self.space.refit_op(vol, feat_count))
        self.hold.record_make(rec, state, self.lists, self.acc, self.active_count, features)

    def record_hold(self, rec, state) -> None:
        """A substep without a stage: the skin held on the last stage's planes (:meth:`PlaneHold.record_hold`)."""
        if not self.hold.holds:
            return
        self.two_way.record_move(rec)
        self.hold.record_hold(rec, state, self.lists, self.acc, self.take_counter, self.space.apply_shift(state),
                              self.bone_hold, self.exchange, self._held_points())
        self.two_way.record_take(rec, state, self.bone_hold)

    def take_counter(self) -> tuple:
        """The next counter slot of the frame and its (1,) counter (:meth:`_counter`)."""
        slot = self._slot
        return slot, self._counter()

    def _counter(self):
        if self._slot >= self.lists.counters.shape[0]:
            raise RuntimeError(f"contact: the frame's {self.lists.counters.shape[0]} counter slots are all taken "
                               "(a recording that takes more than Contact.__init__ sized them for)")
        c = self.lists.counters[self._slot: self._slot + 1]
        self._slot += 1
        return c

    def record(self, rec, state, last: bool = False, substep: int = 0) -> None:
        """One contact stage: broadphase over the frame's list, then ``contact_passes`` x (decision
        points + Eq. 9, averaged apply); a later pass queries only the stage's triangles with a
        vertex the previous pass moved (the others cannot have changed). ``last``: the frame's last
        stage (the solver's schedule), whose positions the frame ends with; ``substep``: the substep it
        runs in (the touch damping's bone motion, touch.py). Through the solver's gates
        (``rec.gated``) a pass after one that moved no vertex is skipped (CPU; it would repeat that pass on the same
        skin: activity.py level 2)."""
        m, o, cfg = self.model, self.objects, self.config
        if not self.n_tris:
            return
        self.two_way.record_move(rec)
        # (active-list slot, first pass's Eq. 9 touched slot, its feature touched slot or -1)
        self._stage_slots.append((self._slot, self._slot + 2, self._slot + 3 if self.features is not None else -1))
        self.active_count = self._counter()
        lst = (self.lists.pass_tris, self._counter())
        self.pass_slots.append(self._slot - 1)
        # the stage's active triangles (within contact_margin) of the frame's list, and of those its
        # first pass's list, in one launch
        rec.launch(stage_lists, self.n_tris,
                   [m.skin_faces, state.x, o.geoms, self.tris_per_world, self.geoms_per_world, cfg.contact_margin,
                    self.lists.cand_tris, self.cand_count, self.acc.bound, self.acc.bound_mask, self.acc.eval_x],
                   [self.lists.active_tris, self.active_count, *lst], count=self.cand_count)
        stage = len(self._stage_slots) - 1
        if self.lists.world_stage is not None:  # the stage's active triangles per world
            rec.launch(tally_worlds, self.n_tris,
                       [self.lists.active, self.active_count, self.tris_per_world, m.vertex_world, 2 * stage],
                       [self.lists.world_stage], count=self.active_count)
        fl = self.features
        if fl is not None and self.feature_scan:  # the stage's features, a thread each (CUDA batches)
            feat_count = fl.stage_counts[stage: stage + 1]
            skin = None
            rec.ops += self.space.volume(state, winding=False).sync_ops()
            self._first_push = self.lists.counters[self._slot + 1: self._slot + 2]  # (as the tiled path's, below)
            rec.launch(stage_features_scan, self.points.n_features,
                       self._feature_inputs(state, fl.listed, fl.count, cfg.feature_offset, self._first_push,
                                            out=fl.stage, out_count=feat_count), [])
        elif fl is not None and self.tiled_features:  # the stage's features, a block each (CUDA),
            # with its first pass's feature push (into that pass's counter slot, taken by _record_features)
            feat_count = fl.stage_counts[stage: stage + 1]
            skin = None
            rec.ops += self.space.volume(state, winding=False).sync_ops()
            self._first_push = self.lists.counters[self._slot + 1: self._slot + 2]  # after the pass's Eq. 9 slot
            nb = tiled_blocks(m.device, self.points.n_features, self.feature_lanes)
            rec.launch(stage_features_tiled, (nb, self.feature_lanes),
                       self._feature_inputs(state, fl.listed, fl.count, cfg.feature_offset, self._first_push,
                                            stride=nb, out=fl.stage, out_count=feat_count), [],
                       block_dim=self.feature_lanes)
        elif fl is not None:  # the stage's features (features.py)
            feat_count = fl.stage_counts[stage: stage + 1]
            vol = self.space.volume(state, winding=False)
            skin = vol.mesh
            rec.ops.append(self.space.refit_op(vol, fl.count))
            rec.launch(stage_features, self.points.n_features,
                       self._feature_inputs(state, fl.listed, fl.count, cfg.feature_offset, None, skin=skin,
                                            out=fl.stage, out_count=feat_count), [],
                       count=fl.count)
        else:
            skin = feat_count = None
        lst, prev, flag = self._record_pass(rec, state, 0, lst, skin, feat_count)
        self._record_later_passes(rec, state, 1, lst, prev, flag, skin, feat_count, stage)
        self._record_make_planes(rec, state, feat_count)  # (Config.contact_linear: linear.py)
        self.two_way.record_take(rec, state, self.bone_hold)
        if cfg.bone_hold:  # a gripped world's flattened skin tets grown back (bones.py; after the two-way
            # take: not a push on the object); more rounds after the frame's last stage, which it ends with
            rounds = RESTORE_ROUNDS_LAST if last else RESTORE_ROUNDS
            record_restore(rec, self.bone_hold, self.held_slot, m.inv_mass, state.x, rounds)
        self.touch.record(rec, m, state, self.acc.vertex_obj, substep, cfg.frame_dt / cfg.substeps)

    def _record_later_passes(self, rec, state, p, lst, prev, flag, skin, feat_count, stage) -> None:
        """Passes ``p``.. of a stage, each recorded inside the gate of the one before (activity.py level
        2: ``prev``, the counter slots of the vertices pass p - 1 moved; ``flag``, the device flag its
        keep_moved set from them). Nested, a skipped pass skips every later one with it: one test
        (CUDA: one conditional graph node) however many passes ``contact_passes`` allows. (A pass
        after a skipped one could not run anyway: its counters and flag are set only by the skipped
        pass, and zeroed with the frame.)"""
        if p >= self.config.contact_passes:
            return

        def body(sub):
            nxt = self._record_pass(rec, state, p, lst, skin, feat_count)
            self._record_later_passes(rec, state, p + 1, *nxt, skin, feat_count, stage)

        gate = rec.gated(body, 2, prev, flag)
        # (Config.tuning.contact_pass_tol: the CPU's host test)
        if gate is not None and len(self.lists.pass_move):
            gate.moved_enough = self._moved_enough(prev[0], stage)

    def _record_pass(self, rec, state, p, lst, skin, feat_count):
        """One pass of a stage; returns the next pass's list, this pass's touched counter slots and
        the device flag (1 when one of them is not zero) the next pass's conditional node reads."""
        m, o, cfg = self.model, self.objects, self.config
        stamp = self._slot  # unique within the frame (moved is zeroed per frame)
        moved_slots = [self._slot]
        self.touched_count = self._counter()
        a = self.acc
        outs = [a.decision, a.bound, a.bound_mask, a.eval_x, a.sums, self.touched_count]
        if self.features is not None:  # features.py: the stage's list against the skin as it is now, applied
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
            rec.launch(kernel, self.n_tris, decide(0), outs, count=lst[1], block_dim=block)
        shift, shifted = self.space.apply_shift(state)
        rec.launch(apply_contact, m.n_vertices, [a.sums, self.touched_count, stamp, shift, self.bone_hold, self.exchange],
                   [state.x, a.push, a.moved, a.disp, self.lists.pass_move, shifted], count=self.touched_count)
        self._tally_touched(rec, p, self.touched_count)
        if p + 1 == cfg.contact_passes and self.features is not None and cfg.feature_last:
            moved_slots.append(self._record_features(rec, state, p + 1, skin, feat_count, stamp)[0])
        flag = None
        if p + 1 < cfg.contact_passes:
            lst = (self.lists.pass_tris, self._counter())
            self.pass_slots.append(self._slot - 1)
            j = len(self.pass_slots) - 1  # (one flag per later pass of the frame, zeroed with the frame)
            flag = self.lists.pass_flags[j: j + 1]
            rec.launch(keep_moved, self.n_tris,
                       [m.skin_faces, self.lists.active_tris, self.active_count, a.moved, a.disp,
                        stamp, a.bound, self.lists.counters, self._slot_array(moved_slots), self.lists.pass_move,
                        self.lists.stage_tol, len(self._stage_slots) - 1],
                       [*lst, flag], count=self.active_count, min_dim=1)
        return lst, tuple(moved_slots), flag

    def _moved_enough(self, stamp: int, stage: int):
        """Config.tuning.contact_pass_tol's host test of a pass (the CPU's level-2 gate; CUDA's keep_moved
        sets the device flag the same way): did the pass ``stamp`` move some vertex by more than its
        stage's tolerance?"""
        move = self.lists.pass_move_host.numpy()  # (the CPU: a view; CUDA: the frame's copy, for reports)
        return lambda: self.lists.stage_tol_host[stage] <= 0.0 or move[stamp] > self.lists.stage_tol_host[stage]

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
        if len(self.lists.stage_tol) and n:  # (a host write: recorded frames and graphs read the array)
            tol = np.full(self.lists.stage_tol.shape[0], self.config.contact_pass_tol if passes_gated else 0.0,
                          np.float32)
            tol[n - 1:] = 0.0
            self.lists.stage_tol.assign(tol)
            self.lists.stage_tol_host = tol

    def _slot_array(self, slots) -> wp.array:
        """``slots`` (counter indices) as a device array, made once and held (recorded launches read it)."""
        key = tuple(int(s) for s in slots)
        a = self._slot_ids.get(key)
        if a is None:
            a = self._slot_ids[key] = wp.array(np.asarray(key, np.int32), dtype=int, device=self.model.device)
        return a

    def _tally_touched(self, rec, p: int, count) -> None:
        """Batched worlds: the vertices a stage's first pass corrected (``self.acc.touched``, ``count``
        long), per world (the log's ``contacts``)."""
        if self.lists.world_stage is not None and p == 0:
            m = self.model
            rec.launch(tally_worlds, m.n_vertices,
                       [self.acc.touched, count, 0, m.vertex_world, 2 * (len(self._stage_slots) - 1) + 1],
                       [self.lists.world_stage], count=count)

    def begin_frame(self, ops: list) -> None:
        """Reset the per-frame report buffers (metrics, push, touched object)."""
        ops += [self.measures.rows.metrics.zero_, self.acc.push.zero_, lambda: self.acc.vertex_obj.fill_(-1)]
        ops += self.two_way.zero_ops()
        if len(self.lists.pass_move):  # (Config.tuning.contact_pass_tol)
            ops.append(self.lists.pass_move.zero_)
        if self.lists.world_stage is not None:
            ops.append(self.lists.world_stage.zero_)

    def sync_objects(self) -> bool:
        """Whether the geoms changed since the object points were built (``Objects.version``: a geom
        added, or a type or size changed by SoftHand.refresh_objects); if so the points, the feature
        lists and the measures' check points are dropped, to be made again from the geoms as they
        are now (the solver then records its frames again: Solver._queue_frame)."""
        v = self.objects.version
        if v == self._objects_version:
            return False
        self._objects_version = v
        self._points = None
        self.features = None
        self.slack_check = None
        self.measures.forget()
        return True

    @property
    def points(self) -> ObjectPoints:
        """The objects' surface points (built on first use, and again after the geoms change:
        :meth:`sync_objects`)."""
        self.sync_objects()
        if self._points is None:
            self._points = ObjectPoints(self.objects, edge_spacing=self.config.feature_spacing)
        return self._points

    # -- the penetration measures (measures.py: ContactMeasures) -----------------------------------

    @property
    def check_points(self) -> ObjectPoints:
        """The denser object points the contact never uses (:attr:`ContactMeasures.check_points`)."""
        self.sync_objects()
        return self.measures.check_points

    @property
    def cull_measure(self) -> bool:
        """Whether the skin measure culls its triangles first (:attr:`ContactMeasures.cull_measure`)."""
        return self.measures.cull_measure

    @cull_measure.setter
    def cull_measure(self, on: bool) -> None:
        self.measures.cull_measure = on

    def record_metrics(self, rec, state, row: int, obj: int = -1, out=None, objects_side: bool = True,
                       order: int = 5, points: ObjectPoints | None = None, skin_side: bool = True,
                       reuse: bool | None = None) -> None:
        """Both measures of ``state`` recorded into row ``row`` (:meth:`ContactMeasures.record_metrics`;
        ``points`` default :attr:`points`)."""
        if self.n_tris:
            self.measures.record_metrics(rec, state, row, self.points if points is None else points, obj=obj,
                                         out=out, objects_side=objects_side, order=order, skin_side=skin_side,
                                         reuse=reuse)

    def measure(self, state, obj: int = -1, order: int = 5, objects_side: bool = True,
                check: bool = False) -> np.ndarray:
        """Both measures of ``state`` now, a (6,) row (:meth:`ContactMeasures.measure`; ``check``: the
        :attr:`check_points` instead of :attr:`points`)."""
        return self.measures.measure(state, self._measured_points(check), obj, order, objects_side, check)

    def measure_worlds(self, state, obj: int = -1, order: int = 5, objects_side: bool = True,
                       check: bool = False) -> np.ndarray:
        """:meth:`measure` per world, (W, 6) rows (:meth:`ContactMeasures.measure_worlds`)."""
        return self.measures.measure_worlds(state, self._measured_points(check), obj, order, objects_side, check)

    def _measured_points(self, check: bool) -> ObjectPoints | None:
        """The points a measure at once asks: :attr:`points` (built on first use) unless no skin or ``check``."""
        self.sync_objects()  # (the check points too)
        return self.points if self.n_tris and not check else None

    def set_hold_depth(self, depth: float) -> None:
        """How deep (m) an anchor must lie inside an object to hold its skin from the next frame on
        (bones.py; ``bones.hold_depth``'s choice by default: SoftHand sets ``HOLD_DEPTH`` where the
        model has no proxies for the margin to keep the bones out)."""
        self.hold_depth = float(depth)
        self.bone_hold.depth.fill_(self.hold_depth)

    @contextlib.contextmanager
    def bones_free(self):
        """No skin held within the block (bones.py; SoftHand's settling, whose bones sweep through
        objects on their way to the pose: a transient there is no start to keep)."""
        d = self.bone_hold.depth
        d.fill_(1.0e30)
        try:
            yield
        finally:
            d.fill_(self.hold_depth)

    def bone_report(self, state, world: int = 0) -> dict:
        """The bones of world ``world`` against the objects now, and the skin the last frame held
        (:func:`~physhand_mj.contact.bones.bone_report`)."""
        return bone_report(self.model, self.objects, state.x, self.geoms_per_world,
                           self.bone_hold.held if self.config.bone_hold else None, world)

    def object_points_inside(self, state) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`points` inside the skin of ``state`` now (:meth:`ContactMeasures.object_points_inside`)."""
        return self.measures.object_points_inside(state, self.points)

    def penetrating_samples(self, state, order: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """The skin samples inside objects now (:meth:`ContactMeasures.penetrating_samples`)."""
        return self.measures.penetrating_samples(state, order)

    def read_metrics(self, synchronize: bool = True) -> np.ndarray:
        """The last frame's rows, (substeps + 1, 6) (:meth:`ContactMeasures.read_metrics`); ``synchronize``:
        copy them (and the frame's other reports, :meth:`copy_metrics`) and wait first."""
        if synchronize:
            self.copy_metrics()
            wp.synchronize_device(self.measures.rows.metrics.device)
        return self.measures.read_metrics()

    def read_metrics_worlds(self, synchronize: bool = True) -> np.ndarray:
        """:meth:`read_metrics` per world, (W, substeps + 1, 6) (:meth:`ContactMeasures.read_metrics_worlds`)."""
        if synchronize:
            self.copy_metrics()
            wp.synchronize_device(self.measures.rows.metrics.device)
        return self.measures.read_metrics_worlds()

    # -- the object's side of a pass: one feature push (contact/features.py) -----------------------

    @property
    def last_push_offset(self) -> float:
        """The stand-off (m) of a stage's last feature push: Config.tuning.feature_last_offset, or
        feature_offset where that is None (read when a stage is recorded, as feature_offset is)."""
        cfg = self.config
        return float(cfg.feature_offset if cfg.feature_last_offset is None else cfg.feature_last_offset)

    def _record_features(self, rec, state, p, skin, feat_count, stamp) -> tuple:
        """The feature push of pass ``p`` (features.py): the stage's listed features against the skin
        as it is now, applied at once; returns the counter slot of the vertices it moved and that
        counter."""
        m, cfg = self.model, self.config
        if p and not self.tiled_features:  # (pass 0 sees the skin its stage's list was made on; CUDA's
            # scans read the skin's shifted copy, which apply_contact keeps current: no refit there)
            rec.ops.append(self.space.refit_op(self.space.volume(state, winding=False), feat_count))
        slot = self._slot
        feat_touched = self._counter()
        # the stage's last push (Config.tuning.feature_last: pass p == contact_passes) to its own, smaller stand-off
        off = self.last_push_offset if p == cfg.contact_passes else cfg.feature_offset
        if p == 0 and self.tiled_features:  # CUDA: pushed by the stage's feature-list launch (record)
            assert feat_touched.ptr == self._first_push.ptr, "the first pass's feature counter slot moved"
        elif self.feature_scan:  # CUDA batches: a thread per feature over its patch
            rec.launch(feature_contact_scan, self.points.n_features,
                       self._feature_inputs(state, self.features.stage, feat_count, off, feat_touched), [])
        elif self.tiled_features:  # CUDA: a block per feature over its patch (or the frame's list)
            nb = tiled_blocks(m.device, self.points.n_features, self.feature_lanes)
            rec.launch(feature_contact_tiled, (nb, self.feature_lanes),
                       self._feature_inputs(state, self.features.stage, feat_count, off, feat_touched, stride=nb), [],
                       block_dim=self.feature_lanes)
        else:
            rec.launch(feature_contact, self.points.n_features,
                       self._feature_inputs(state, self.features.stage, feat_count, off, feat_touched, skin=skin), [],
                       count=feat_count)
        shift, shifted = self.space.apply_shift(state)
        a = self.acc
        rec.launch(apply_contact, m.n_vertices, [a.sums, feat_touched, stamp, shift, self.bone_hold, self.exchange],
                   [state.x, a.push, a.moved, a.disp, self.lists.pass_move, shifted], count=feat_touched)
        return slot, feat_touched

    def _feature_inputs(self, state, cand, cand_count, offset: float, touched_count, skin=None, stride: int = 0,
                        out=None, out_count=None) -> list:
        """A feature kernel's arguments (features.feature_inputs) over the features ``cand`` (the
        frame's list, or a stage's) on ``state``'s skin: pushed to ``offset`` (m) with the vertices
        counted in ``touched_count``; ``skin`` the refitted skin volume (the BVH search), ``stride``
        the tiled launch's blocks, ``out``/``out_count`` a stage's list."""
        m, o, cfg = self.model, self.objects, self.config
        return feature_inputs(m.skin_faces, self.space.skin_x(state), cand, cand_count, self.points.pts,
                              self.points.geom, self.points.normal, self.space.pose, cfg.contact_frame_margin,
                              skin=skin.id if skin is not None else 0, tris=self.lists.cand, tri_count=self.cand_count,
                              stride=stride, geom_obj=o.obj, keep=cfg.contact_margin, near=self.near_query,
                              eps=self.feature_eps, offset=offset, max_step=cfg.contact_margin, pose0=o.pose,
                              x0=state.x, winding=self._winding_args(), side=self._side(), out=out,
                              out_count=out_count,
                              push=(self.acc.sums, touched_count))

    def _winding_args(self) -> list:
        """The feature kernels' local-winding-number inputs (features.py): [on, patches]; off: the
        feature list's arrays stand in (FeatureLists.patches, never read)."""
        return [int(bool(self.config.feature_winding)), self.features.patches]

    def _side(self):
        """The CPU's per-stage sides of the listed features (features.stage_features)."""
        return self.features.side if self.config.feature_winding else self.features.no_side

    # -- the frame's host-side reports: the copies the frame's one sync waits for, and what they say --

    def copy_metrics(self) -> None:
        """Start the device-to-host copy of the metrics and list lengths (the caller synchronises
        once per frame)."""
        self.measures.copy_rows()
        wp.copy(self.lists.counters_host, self.lists.counters)
        # (CUDA: the ops report's; the CPU's host array is the device's)
        if len(self.lists.pass_move) and self.lists.pass_move_host is not self.lists.pass_move:
            wp.copy(self.lists.pass_move_host, self.lists.pass_move)
        if self.lists.world_stage is not None:
            wp.copy(self.lists.world_stage_host, self.lists.world_stage)
        if self.features is not None:
            wp.copy(self.features.count_host, self.features.count)
            if self.config.feature_winding:
                wp.copy(self.features.patch_used_host, self.features.patch_used)
            self.slack_check.copy_report()

    def features_listed(self) -> int:
        """Object feature points in the last frame's list (after the frame's sync). Sizes the patch
        pool (the local winding number's, winding.py) for the frames to come
        (:func:`~physhand_mj.contact.patch_pool.fit_patch_pool`): where the frame's patches needed more
        than half of it packed (what the BVH path is sure to fit) or did not fit, it grows to twice
        their need, up to PATCH_POOL_MAX, and the solver records its frames again (a frame that
        overflowed kept, for the points past the pool, the pseudo-normal sign (one hand) or pushed
        them not at all (CUDA batches)). An overflow at PATCH_POOL_MAX warns once."""
        if self.features is None:
            return 0
        if self.config.feature_winding:
            grown, self._patch_warned = patch_pool.fit_patch_pool(self.features, self.model.device, self.worlds,
                                                                  self._patch_warned)
            self.reallocations += int(grown)
        return int(self.features.count_host.numpy()[0])

    def stage_counts(self) -> np.ndarray:
        """(stages, 2) int of the last frame (after ``read_metrics``): per contact stage, the active
        triangles and the skin vertices its first pass corrected (in contact at the stage's start; Eq. 9's
        and the feature push's, a vertex both moved counted twice)."""
        c = self.lists.counters_host.numpy()
        return np.array([[c[a], c[t] + (c[f] if f >= 0 else 0)] for a, t, f in self._stage_slots],
                        dtype=int).reshape(-1, 2)

    def stage_counts_worlds(self) -> np.ndarray:
        """(W, stages, 2) int: :meth:`stage_counts` per world (after the frame's sync; one world:
        the frame's own, (1, stages, 2))."""
        if self.lists.world_stage is None:
            return self.stage_counts()[None]
        n = len(self._stage_slots)
        return self.lists.world_stage_host.numpy().reshape(self.worlds, -1, 2)[:, :n].copy()

    # -- host side ---------------------------------------------------------------------------------
    def run_stage(self, state) -> np.ndarray:
        """Run one contact stage now (broadphase + passes) on ``state.x``; returns (F, 4) decision
        points of the last pass (x*, phi(x*)) with phi = FAR for triangles the broadphase skipped.
        For tests and diagnostics: inside a frame the solver records the same launches."""
        rec = Recorder(self.model.device)
        rec.ops.append(lambda: self.acc.decision.fill_(wp.vec4(0.0, 0.0, 0.0, 1.0e6)))
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
        return self.acc.decision.numpy()[: self.n_tris].copy()
