"""The XPBD frame, Algorithm 1 of the paper, over preallocated Model/State arrays.

    bone poses at the end of every substep                 begin_frame (once per frame)
    for each substep (h = frame_dt / substeps):
        x^i <- x;  x <- x^i + h v + h^2 M^-1 f_ext            advance: predict   (line 3)
        skeleton vertices <- bone poses at this substep        (kinematic input)
        lambda <- 0 (in the first pass);  alpha~ = alpha / h^2  (lines 4-5)
        contact correction                                     hook (line 6; the contact issue)
        for each iteration, for each family                    (lines 7-13)
            edge (Eq. 2) with the attachments (Eq. 4-5), tet (Eq. 3), smoothness (Eq. 6)
        v <- (x - x^i) / h                                     advance: finish   (lines 14-15) + guard

``advance`` finishes one substep and predicts the next in the same per-vertex launch, so a Jacobi
substep is 6 launches: advance, edges, apply, tets, apply, dihedrals; with ``Config.execution.fused_substep``
(the CPU's default) 1: the substep's start and its three groups in one launch per world in shared
memory (solver/fused.py; advance stays a launch of its own where a contact stage comes between).

On CUDA the whole frame is one CUDA graph (captured on the second frame, after compilation).
"""

from __future__ import annotations

import math
import os

import numpy as np
import warp as wp

from physhand_mj.solver import fused as fused_launch
from physhand_mj.solver import fused_choice
from physhand_mj.solver import integrate
from physhand_mj.solver.carry import FleshCarry
from physhand_mj.solver.edge import solve_edges
from physhand_mj.solver.gather import GATHER_LANES
from physhand_mj.rotations import compose_quat, quat_to_mat
from physhand_mj.solver.model import JACOBI_GROUPS
from physhand_mj.solver.poses import PoseInput
from physhand_mj.solver.sleep import Sleep, frame_rigid
from physhand_mj.solver.smooth import solve_dihedrals
from physhand_mj.solver.tet import solve_tets
from physhand_mj.launch import Recorder, launch_options
from physhand_mj.types import Config, Model, NonFinite, Scheme, SolverError, State, Strategy

wp.config.log_level = wp.LOG_WARNING  # keep stdout for the CLI's JSON line


class Solver:
    """XPBD solver for one layered body. With ``objects`` (a :class:`~physhand_mj.contact.Objects`)
    and ``config.contact`` not NONE, each substep also runs the skin-object contact correction
    (Algorithm 1 line 6, placed by ``config.contact_placement``) and ``step`` reports penetration."""

    def __init__(self, model: Model, config: Config | None = None, objects=None):
        self.model = model
        self.config = (config or Config()).validate()
        self.device = wp.get_device(model.device)
        if self.config.device is not None and wp.get_device(self.config.device) != self.device:
            raise ValueError(f"Config.device {self.config.device!r} differs from the model's {model.device!r}")
        self.contact = None
        if objects is not None and self.config.contact != Strategy.NONE:
            from physhand_mj.contact import Contact

            self.contact = Contact(model, objects, self.config)
        # Tuning.flesh_carry / wall_carry: the flesh under contact-moved skin moves with it (solver/carry.py;
        # wall_carry only by the skin near a wall, and only in a scene that has one)
        cfg = self.config
        self.carry = FleshCarry(model, cfg.flesh_carry, self.device, cfg.wall_carry) \
            if self.contact is not None and (cfg.flesh_carry > 0 or cfg.wall_carry > 0) else None
        self.selfc = None  # Config.self_collision: the skin kept out of itself (solver/self_contact.py)
        if self.config.self_collision:
            from physhand_mj.solver.self_contact import SelfContact

            self.selfc = SelfContact(model, self.config, self.device)
            if self.config.self_edges:  # Tuning.self_edges: its edge-edge pairs beside it (solver/self_edges.py)
                from physhand_mj.solver.self_edges import SelfEdges

                self.selfc.edge_pairs = SelfEdges(self.selfc, self.device)
        from physhand_mj.solver.activity import Activity

        self.activity = Activity(self)  # what runs each frame (gated contact blocks, the work set)
        self.last_activity: dict = {}
        self._graphs: dict[tuple, object] = {}
        self._ops: dict[tuple, list] = {}
        self.last_graph = None
        self._pre: dict[tuple, list] = {}  # CUDA gates: the frame broadphase, run ahead of the graph
        # the objects' geoms and the contact's buffer replacements when the frames were recorded (_queue_frame)
        self._recorded_geoms = (0, 0)
        self._tail: list = []  # ops run at the end of every frame, inside its graph (set_frame_tail)
        self._in_flight = None  # (state, ops or None asleep, rigid, frame poses) between launch and finish
        self._cand_host = wp.zeros(1, dtype=int, device="cpu", pinned=self.device.is_cuda)
        h = self.config.substep_dt
        self._h = h
        self._inv_h2 = 1.0 / (h * h)
        self._damp = math.exp(-self.config.damping * h)
        self._gravity = wp.vec3(*[float(g) for g in self.config.gravity])
        self._guard_host = wp.zeros(self._guard_len(), dtype=int, device="cpu", pinned=self.device.is_cuda)
        self._guard_np = self._guard_host.numpy()  # (its numpy view, made once)
        self._asleep_summary = None  # (an asleep frame's contact summary while the host rows stay: _finish_asleep)
        self.guard_worlds = np.zeros((model.worlds, 4), int)  # the last frame's guard counts per world
        self.warn_feature_slack = True  # warn (once) when the skin outran the feature lists' slack (slack.py)
        self._fused = fused_choice.choose(model, self.config, self.device)  # Config.execution.fused_substep
        # Config.self_collision with the fused substep: its substep passes inside the fused kernel, a fourth
        # group (solver/fused_self.py; fused.SELF_IN_KERNEL False: self_contact.py's launches after it)
        self._self_fused = (self.selfc is not None and self._fused is not None and fused_launch.SELF_IN_KERNEL
                            and self.selfc.edge_pairs is None)  # (Tuning.self_edges: the passes as launches)
        if self._self_fused:
            self._fused.attach_self(self.selfc)  # (SelfContact.in_kernel set: it lists per world too)
        # per-region sleeping (physhand_mj/solver/regions.py; one world)
        self.regions = None
        if self.config.region_sleep and int(getattr(model, "worlds", 1)) == 1 and model.n_bodies:
            from physhand_mj.solver.regions import RegionSleep

            self.regions = RegionSleep(self)
        # the bone poses going in (poses.py): their checks, the fast-motion warning, the upload buffers
        self.poses = PoseInput(model, self.config, self.contact, self.regions, self.device.is_cuda)
        # whole-hand sleeping (sleep.py): its tests and its recorded sleeping frames
        self.sleep = Sleep(model, self.config, self.device, self.activity, self.contact, self.regions)

    # -- state -------------------------------------------------------------------------------
    def make_state(self, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0)) -> State:
        """The rest shape placed by one rigid transform (position m, quaternion w x y z), at rest."""
        m = self.model
        rot = quat_to_mat(np.asarray(quat, float))
        pos = np.asarray(pos, float)
        x = m.rest_x.numpy().astype(np.float64) @ rot.T + pos
        bp = m.body_rest_pos @ rot.T + pos
        bq = compose_quat(np.asarray(quat, float), m.body_rest_quat)
        d = self.device
        n = m.n_vertices
        st = State(
            x=wp.array(x.astype(np.float32), dtype=wp.vec3, device=d),
            v=wp.zeros(n, dtype=wp.vec3, device=d), x_prev=wp.array(x.astype(np.float32), dtype=wp.vec3, device=d),
            x_safe=wp.array(x.astype(np.float32), dtype=wp.vec3, device=d),
            delta=wp.zeros(n, dtype=wp.vec3, device=d),
            corr=wp.zeros(m.n_slots, dtype=wp.vec3, device=d),
            lam_edge=wp.zeros(m.edge_rest.shape[0], dtype=float, device=d),
            lam_tet=wp.zeros(m.tet_rest6v.shape[0], dtype=float, device=d),
            lam_dih=wp.zeros(m.dih_rest.shape[0], dtype=float, device=d),
            body_pose=wp.zeros((2, m.n_bodies), dtype=wp.transform, device=d),
            pose_host=np.zeros((2, m.n_bodies, 7), np.float32),
            body_sub=wp.zeros((self.config.substeps, m.n_bodies), dtype=wp.transform, device=d),
            guard=wp.zeros(self._guard_len(), dtype=int, device=d),
        )
        self.set_body_poses(st, bp, bq)
        st.pose_host[0] = st.pose_host[1]
        return st

    # -- the bone poses going in (poses.py) ------------------------------------------------------
    def set_body_poses(self, state: State, pos: np.ndarray, quat: np.ndarray) -> None:
        """Bone poses at the end of the next frame: pos (B, 3) m, quat (B, 4) w x y z, in the
        solver's world frame, ordered as ``model.body_names`` (:meth:`PoseInput.set_body_poses`)."""
        self.poses.set_body_poses(state, pos, quat, self._state_in_flight())

    def pose_rows(self, pos: np.ndarray, quat: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """:meth:`set_body_poses`' checks and conversion without a state, (B, 7) rows (:meth:`PoseInput.pose_rows`)."""
        return self.poses.pose_rows(pos, quat, out)

    def set_body_pose_rows(self, state: State, rows: np.ndarray) -> None:
        """The next frame's end poses as :meth:`pose_rows` made them (:meth:`PoseInput.set_body_pose_rows`)."""
        self.poses.set_body_pose_rows(state, rows, self._state_in_flight())

    def stage_pose_rows(self, state: State, rows: np.ndarray):
        """While a frame of ``state`` is in flight, fill the next frame's upload buffer; a token for
        :meth:`launch` or None (:meth:`PoseInput.stage_pose_rows`)."""
        return self.poses.stage_pose_rows(state, rows, self._state_in_flight())

    @property
    def warn_fast_motion(self) -> bool:
        """Warn (once) when a bone outruns Config.contact_frame_margin in a frame
        (:attr:`PoseInput.warn_fast_motion`)."""
        return self.poses.warn_fast_motion

    @warn_fast_motion.setter
    def warn_fast_motion(self, on: bool) -> None:
        self.poses.warn_fast_motion = on

    def _state_in_flight(self) -> State | None:
        """The state whose frame is in flight (between :meth:`launch` and :meth:`finish`), else None."""
        return None if self._in_flight is None else self._in_flight[0]

    # -- the frame -------------------------------------------------------------------------------
    def step(self, state: State) -> dict:
        """Advance one frame (``config.frame_dt``). Returns the frame's guard counts
        ``{"nonfinite": int, "inverted": int}`` (with contact and a tether also ``"tethered"``: skin
        vertices Config.skin_tether held, summed over substeps) and, with contact, the penetration
        summary; what ran (activity.py: ``objects_near`` ... ``contact_ops_run``) and ``asleep``
        (the frame only carried a settled hand along its bones: Config.sleep_speed); raises
        SolverError under ``NonFinite.RAISE``. The same as :meth:`launch` then :meth:`finish`."""
        self.launch(state)
        return self.finish(state)

    def launch(self, state: State, staged=None, rows: np.ndarray | None = None) -> None:
        """The frame's first half: every decision made before it (the poses, sleeping, the work
        set), its launches queued on the device (on CUDA one graph) with the copies of its reports.
        :meth:`finish` waits for it and reads them; until then the host is free (a batch checks the
        next frame's poses meanwhile: BatchedHands.submit) and ``state`` must not be read or
        changed. One frame in flight at a time. ``staged``: :meth:`stage_pose_rows`' token.
        ``rows``: the frame's end poses (:meth:`pose_rows`), set as :meth:`set_body_pose_rows` would
        before the launch; with ``staged`` made for these very rows and no sleep test to take before
        the launch, their host copy is made after the frame is queued (:meth:`PoseInput.set_rows_late`)."""
        if self._in_flight is not None:
            raise RuntimeError("a frame is in flight: Solver.finish(state) before the next launch")
        late = None
        if rows is not None:
            if not self.sleep.settled(state) and self.poses.set_rows_late(state, rows, staged, self._state_in_flight()):
                late = rows  # (no decision before the frame's launch reads the host rows: sleep.py's test would)
            else:
                self.set_body_pose_rows(state, rows)
        try:
            pin, frame_poses = self.poses.frame_poses_in(state, staged)  # (the frame's poses, their upload buffer)
            if self.contact is not None:  # (Config.contact_linear: planes made for another state are dropped)
                self.contact.forget_planes(state)
            # the sleep test's bone conditions (activity.py), from the poses on the host: before the frame
            # only for a settled hand (may it sleep?), else after it and only if no vertex was fast
            rigid = self.sleep.bones_still(state) if self.sleep.settled(state) else None
            if self.regions is not None:
                self.regions.before_frame(*frame_poses)
            # a frame that may sleep on CUDA graphs uploads its poses inside its graph (sleep.py); else now
            upload = pin if rigid and self.regions is None and self._capturable() else None
            if upload is None:
                wp.copy(state.body_pose, pin)
            if self.regions is not None:
                self.regions.apply(state)
        except BaseException:
            if late is not None:  # (no frame queued: the rows stay set, as set_body_pose_rows leaves them)
                state.pose_host[1] = late
            raise
        try:
            self._queue_frame(state, rigid, frame_poses, upload)
        finally:  # (after the frame is queued: the host copy is off the device's critical path)
            if late is not None:
                self.poses.rows_landed(state, late)
            else:
                state.pose_host[0] = state.pose_host[1]
            state.pose_fresh = False

    def _queue_frame(self, state: State, rigid, frame_poses, upload=None) -> None:
        """:meth:`launch`'s decisions and launches, after the pose upload (``rigid``: the sleep
        test's bone conditions; ``frame_poses``: the frame's start and end poses on the host;
        ``upload``: the pose buffer not yet uploaded, which a sleeping frame's graph copies and any
        other frame copies before its first launch)."""
        key = (id(state), id(self.contact))
        c = self.contact
        if c is not None:
            c.sync_objects()  # (a geom added or resized: its points made again)
        geoms = (c.objects.version, c.reallocations) if c is not None else (0, 0)  # (version: every add counts)
        if geoms != self._recorded_geoms:  # a geom added or resized since the frames were recorded (which kernels a frame
            self._forget_recordings()  # launches depends on them: query_tiled.tiled_kernel_for), or a buffer
            self._recorded_geoms = geoms  # the frames read replaced (a grown patch pool): record again
        ops = self._ops.get(key)
        self.activity.begin_frame(state)  # CPU: is any object near the skin (the contact's level-0 gate)?
        first = ops is None
        if first:  # record every launch of a frame once: replaying skips Python argument packing
            ops = self._ops[key] = self._record_frame(state, key)
            self.activity.finish_recording(ops, self._pre.get(key, []))
            if self.contact is not None:
                self.contact.finish_recording(self.activity.passes_gated)
        act = self.activity
        if not first and rigid and self.sleep.asleep_and_alone(state, frame_poses):
            self._launch_asleep(state, key, upload)  # (CUDA: no broadphase ahead, no extra sync)
            self._in_flight = (state, None, rigid, frame_poses)
            return
        if upload is not None:  # (before the broadphase ahead or the frame)
            wp.copy(state.body_pose, upload)
        if act.gate_ahead:  # the frame broadphase ahead of the frame: its count picks the graph
            for op in self._pre[key]:
                op()
            wp.copy(self._cand_host, self.contact.cand_count)
            wp.synchronize_device(self.device)
            act.open1 = bool(self._cand_host.numpy()[0])
        if not first and rigid and self.sleep.may_sleep(state):
            self._launch_asleep(state, key)
            self._in_flight = (state, None, rigid, frame_poses)
            return
        # Tuning.self_every: whether this frame lists its self-contact pairs anew (a graph for each)
        listing = self.selfc.begin_frame(state) if self.selfc is not None else True
        if first:
            for op in ops:  # the first frame runs uncaptured (it compiles the kernels)
                op()
        else:
            graph = self.replay(ops, key + (act.open1, listing))
            if graph is not None:
                self.last_graph = graph  # (bench.py replays it for the GPU-only cost)
        wp.copy(self._guard_host, state.guard)
        if self.contact is not None:
            self.contact.copy_metrics()
        if self.selfc is not None:
            self.selfc.copy_report()
        if self.regions is not None:
            self.regions.copy_back()
        self._in_flight = (state, ops, rigid, frame_poses)

    def finish(self, state: State) -> dict:
        """The frame :meth:`launch` queued: its one host sync, then its report (:meth:`step`'s)."""
        if self._in_flight is None or self._in_flight[0] is not state:
            raise RuntimeError("no frame of this state is in flight: Solver.launch(state) first")
        _, ops, rigid, frame_poses = self._in_flight
        self._in_flight = None
        if ops is None:  # a sleeping frame
            return self._finish_asleep(state)
        wp.synchronize_device(self.device)  # the frame's host sync (on CUDA with contact: its second)
        g = self._guard_np
        self._asleep_summary = None
        self._read_guard_worlds(g)
        state.time += self.config.frame_dt
        state.frames += 1
        out = {"nonfinite": int(g[0]), "inverted": int(g[1])}
        if self.contact is not None and self.config.skin_tether > 0:
            out["tethered"] = int(g[2])
        if self.contact is not None:
            self._contact_summary(out)
            self.last_activity = self.activity.report(self.contact.lists.counters_host.numpy(),
                                                      self.contact.features_listed(), self.contact)
            self.last_activity.update(self.contact.feature_motion(self.activity.last_open1, self.warn_feature_slack))
        else:
            self.last_activity = dict(objects_near=0, triangles_frame=0, triangles_stage=0, triangles_tested=0,
                                      features_listed=0, ops_run=len(ops), contact_ops_run=0)
        if self.regions is not None:
            self.regions.after_frame(frame_poses[1])
            self.last_activity.update(self.regions.report())
        if self.selfc is not None:
            self.last_activity.update(self.selfc.report())
        out.update(self.last_activity)
        # settled: no soft vertex faster than Config.sleep_speed and rigid bone motion (activity.py)
        if self.config.sleep_speed > 0 and not g[3] and rigid is None:
            rigid = frame_rigid(*frame_poses, self.config.sleep_bone_motion)
        state.still = state.still + 1 if rigid and not g[3] else 0
        state.sleep_onset = state.sleep_box = None
        out["asleep"] = False
        if out["nonfinite"] and self.config.nonfinite == NonFinite.RAISE:
            raise SolverError(f"{out['nonfinite']} vertex positions turned non-finite in frame "
                              f"{state.frames}; state kept at their last finite positions")
        return out

    def _launch_asleep(self, state: State, key, upload=None) -> None:
        """A sleeping frame's launch (:meth:`Sleep.launch`), then its report's copies."""
        pin = -1 if upload is None else next(i for i, p in enumerate(self.poses.pins) if p is upload)
        self.sleep.launch(state, key, self.replay, self._tail, self._guard_host, pin, upload)
        if self.contact is not None and state.sleep_box is None:  # (asleep on: the host rows stay zero)
            self.contact.copy_metrics()
            self._asleep_summary = None

    def _finish_asleep(self, state: State) -> dict:
        """:meth:`finish` for a sleeping frame (:meth:`Sleep.finish`): the guard's counts, the contact
        summary the host rows last gave, the activity and the regions' reports."""
        self.last_activity = self.sleep.finish(state, self._pre)
        g = self._guard_np
        self._read_guard_worlds(g)
        out = {"nonfinite": int(g[0]), "inverted": 0}
        if self.contact is not None:
            if self.config.skin_tether > 0:
                out["tethered"] = 0
            if self._asleep_summary is None:  # (the host rows stay as they were: the same summary)
                self._asleep_summary = {}
                self._contact_summary(self._asleep_summary)
            out.update(self._asleep_summary)
        out.update(self.last_activity)
        if self.regions is not None:  # (the regions' own state waits under the whole hand's sleep)
            out.update(self.regions.report(whole_hand=True))
        out["asleep"] = True
        return out

    def wake(self, state: State) -> None:
        """Forget that ``state`` had settled (it sleeps again after Config.tuning.sleep_frames still frames;
        :meth:`Sleep.wake`)."""
        self.sleep.wake(state)

    def _contact_summary(self, out: dict) -> None:
        """The frame's penetration summary (its metrics row, read at the frame's sync) into ``out``."""
        from physhand_mj.contact.metrics import summarize  # contact imports the solver's types: no cycle here

        rows = self.contact.read_metrics(synchronize=False)
        both = summarize(rows[-1])  # (the frame measured only what Config.frame_metrics / object_metrics ask)
        out.update({k: v for k, v in both.items() if (self.config.frame_metrics and k.startswith("penetration"))
                    or (self.config.object_metrics and k.startswith("object_in_skin"))})
        self.substep_metrics = rows[:-1]

    def _guard_len(self) -> int:
        """The guard's length: the frame's four counts, then (batched worlds) four per world."""
        w = int(getattr(self.model, "worlds", 1))
        return 4 + (4 * w if w > 1 else 0)

    def _read_guard_worlds(self, g: np.ndarray) -> None:
        """``guard_worlds`` (W, 4) of the frame just read back (one world: the frame's own counts)."""
        self.guard_worlds = g[4:].reshape(-1, 4).copy() if len(g) > 4 else g[None, :4].copy()

    def replay(self, ops: list, gkey):
        """Run ``ops``: on CUDA with graphs as the graph captured under ``gkey`` (captured on first
        use) and returned; otherwise one by one (returns None)."""
        if not self._capturable():
            for op in ops:
                op()
            return None
        graph = self._graphs.get(gkey)
        if graph is None:
            with wp.ScopedCapture(device=self.device) as cap:
                for op in ops:
                    op()
            graph = self._graphs[gkey] = cap.graph
        wp.capture_launch(graph)
        return graph

    @property
    def fused_substep(self) -> bool:
        """Whether a substep's constraint groups run as one launch per world (``Config.execution.fused_substep``
        resolved for this body and device: solver/fused.py)."""
        return self._fused is not None

    def _capturable(self) -> bool:
        return self.device.is_cuda and self.config.cuda_graph

    def _record_frame(self, state: State, key=None) -> list:
        """The frame as a list of zero-argument operations (recorded launches, memsets, copies)."""
        rec = FrameRecorder(self.device, self.activity)
        self._record_frame_ops(state, key, rec)
        rec.make()
        return rec.ops

    def _record_frame_ops(self, state: State, key, rec: "FrameRecorder") -> None:
        """:meth:`_record_frame`'s recording into ``rec`` (its launches made once the frame's
        modules are compiled)."""
        m, cfg, d = self.model, self.config, self.device
        n = m.n_vertices
        ops, launch, gated = rec.ops, rec.launch, rec.gated
        self.activity.reset_recording()
        if self.contact is not None:
            self.contact.begin_frame(ops)

        lams = dict(edge=state.lam_edge, tet=state.lam_tet, dih=state.lam_dih)
        fam = {
            "edge": (solve_edges, m.edge_ids, m.edge_rest, m.edge_alpha),
            "tet": (solve_tets, m.tet_ids, m.tet_rest6v, m.tet_alpha),
            "dih": (solve_dihedrals, m.dih_ids, m.dih_rest, m.dih_alpha),
        }
        jacobi = int(cfg.scheme == Scheme.JACOBI)
        gather = bool(m.gather_off)  # Config.execution.jacobi_gather: corrections in slots, summed per vertex
        no_int = wp.empty(0, dtype=int, device=d)
        no_vec = wp.empty(0, dtype=wp.vec3, device=d)

        def lists(group):
            """The gather lists and slots the apply of Jacobi group ``group`` reads (empty: atomics)."""
            if not gather or group < 0:
                return [no_int, no_int, no_vec]
            return [m.gather_off[group], m.gather_slot[group], state.corr]

        def apply(group):
            lanes = GATHER_LANES[group] if gather and wp.get_device(d).is_cuda else 1
            launch(integrate.apply_jacobi, n * lanes, [m.vertex_count, group, cfg.relaxation],
                   [state.x, state.delta] + lists(group) + [lanes])
        launch(integrate.begin_frame, (cfg.substeps, max(m.n_bodies, 1)), [state.body_pose],
               [state.body_sub, state.guard])
        carry = None  # (the stage's flesh carry: Tuning.flesh_carry / wall_carry, where they act)
        if self.contact is not None:
            contact = self.contact
            contact.record_frame_planes(rec)  # (Config.contact_linear, every frame: contact/linear.py)
            if self.activity.gate_ahead:  # CUDA: the broadphase runs ahead of the frame's graph (step)
                rec.ahead = self._pre[key] = []
            contact.zero_counters(rec)  # the frame's list lengths (the level-1 gates read one)
            if self.carry is not None and self.carry.acts(contact):
                carry = self.carry

            def frame(sub):
                contact.record_frame(rec, state)
                if carry is not None:  # (Tuning.wall_carry: the skin near a wall, from the frame's list)
                    rec.gated(lambda sub: carry.record_frame(rec, contact), 1)
            gated(frame, 0)
        if self.selfc is not None:  # the frame's self-contact list, from the positions at its start
            self.selfc.record_frame(rec, state)

        def stage(last: bool, s: int):
            """A contact stage in substep ``s`` (Eq. 9 and the features; ``last``: the frame's last, which
            it ends with); with Tuning.flesh_carry the flesh follows it."""
            if carry is None:
                contact.record(rec, state, last, s)
            else:
                carry.record(rec, state, inv_mass, lambda: contact.record(rec, state, last, s))

        pending = -1  # family whose Jacobi corrections await averaging (applied lazily, fused into advance)
        rs = self.regions  # per-region sleeping: the kernels read its live kinematic arrays
        inv_mass, vertex_body, body_local = ((rs.inv_mass, rs.vertex_body, rs.body_local) if rs is not None
                                             else (m.inv_mass, m.vertex_body, m.body_local))
        region_args = [rs.vertex_region, rs.fast] if rs is not None else [no_int, no_int]
        if rs is not None:
            rs.record_start(launch)
        solo = self.selfc is None or self._self_fused  # (no self-contact launch between the substeps)
        end_folded = (self._fused is not None and self._fused.frame_launch and self._fused.fold_end
                      and self.contact is None and solo and rs is None)
        for s in range(cfg.substeps + 1):
            contact = self.contact
            # Config.contact_every: the contact stages of this substep (the last substep always has them)
            staged = s < cfg.substeps and (cfg.substeps - 1 - s) % cfg.contact_every == 0
            before = contact is not None and staged and contact.wants("before")
            # Config.contact_linear: a substep without a stage holds the skin on the last stage's planes
            hold = contact is not None and not staged and s < cfg.substeps and contact.holds
            hold_after = hold and contact.wants("after")
            # the fused substep also makes the substep's start, unless a contact stage comes between
            fold = self._fused is not None and s < cfg.substeps and not before and not (hold and not hold_after)
            # a frame launch that also ends the frame (fused.FOLD_END): no last advance, no inverted-tet count
            if not fold and not (s == cfg.substeps and end_folded):
                # end substep s-1 (velocity update) and begin substep s (prediction) in one launch
                launch(integrate.advance, n, [inv_mass, vertex_body, body_local, m.vertex_count, self._gravity,
                                              self._h, self._damp, int(s > 0), pending, cfg.relaxation,
                                              s if s < cfg.substeps else -1, state.body_sub, float(cfg.sleep_speed),
                                              m.vertex_carrier, m.vertex_world],
                       [state.x_safe, state.x, state.v, state.x_prev, state.delta, state.guard] + lists(pending)
                       + region_args)
            pending = -1
            if s == cfg.substeps:
                break
            if before:  # (the frame's last stage where the last substep has no stage after its constraints)
                gated(lambda sub, s=s: stage(s == cfg.substeps - 1 and not contact.wants("after"), s), 1)
            elif hold and not hold_after:
                gated(lambda sub: contact.record_hold(rec, state), 1)
            # a frame without contact stages: every substep in the first one's launch (solver/fused.py)
            whole = self._fused is not None and self._fused.frame_launch and self.contact is None and solo
            if self._fused is not None and (s == 0 or not whole):  # the three groups, each averaged, in one launch
                fz = self._fused
                inputs = fz.inputs(self._inv_h2, cfg.relaxation, state, start=s if fold else -1, finish=int(s > 0),
                                   h=self._h, damp=self._damp, gravity=self._gravity, model=m,
                                   keep_lam=whole or s == cfg.substeps - 1, count=cfg.substeps if whole else 1,
                                   end=whole and end_folded, speed_limit=float(cfg.sleep_speed))
                rec.add(fz.kernel, fused_launch.BLOCK_DIM,
                        lambda inputs=inputs: wp.launch_tiled(fz.kernel, dim=[m.worlds], inputs=inputs,
                                                              block_dim=fused_launch.BLOCK_DIM, device=d,
                                                              record_cmd=True).launch)
            for it in range(0 if self._fused is not None else cfg.iterations):
                for row, group in enumerate(JACOBI_GROUPS):
                    names = [name for name in group if m.colors[name]]
                    if not names:
                        continue
                    if pending >= 0:
                        apply(pending)
                        pending = -1
                    for name in names:
                        kernel, ids, rest, alpha = fam[name]
                        order = rs.order.get(name) if rs is not None else None  # (regions.py: awake constraints)
                        for start, end in m.colors[name]:
                            launch(kernel, end - start, [inv_mass, ids, rest, alpha, self._inv_h2, start, int(it == 0)],
                                   [state.x, lams[name], state.delta if jacobi else state.x,
                                    state.corr if gather else no_vec, m.slot_base.get(name, 0),
                                    order[0] if order else no_int, order[1] if order else no_int],
                                   count=order[1] if order else None)
                    if jacobi:
                        pending = row
            if self.selfc is not None and not self._self_fused:  # self-contact after the constraints, before the
                # object contact (its last word; fused: inside the fused launch)
                if pending >= 0:
                    apply(pending)
                    pending = -1
                self.selfc.record_stage(rec, state, inv_mass)
            if contact is not None and ((staged and contact.wants("after")) or cfg.substep_metrics or hold_after):
                if pending >= 0:  # the substep's positions must be final before contact / metrics
                    apply(pending)
                    pending = -1
                if staged and contact.wants("after"):
                    gated(lambda sub, s=s: stage(s == cfg.substeps - 1, s), 1)
                elif hold_after:
                    gated(lambda sub: contact.record_hold(rec, state), 1)
            if contact is not None and (cfg.skin_tether > 0 or cfg.substep_metrics):
                if pending >= 0:
                    apply(pending)
                    pending = -1

                def after_contact(sub, s=s):
                    if cfg.skin_tether > 0:  # contact can drag the skin, nothing else can
                        launch(integrate.tether_skin, m.n_skin,
                               [m.skin_body, m.vertex_world, m.skin_local, state.body_sub, s, cfg.skin_tether],
                               [state.x, state.guard])
                    if cfg.substep_metrics:  # only when a log asks (rollout)
                        contact.record_metrics(rec, state, s, objects_side=False)

                gated(after_contact, 1)
        if self.contact is not None:  # nothing within the frame margin: nothing inside, the rows stay zero

            def frame_end(sub):
                if cfg.frame_metrics or cfg.object_metrics:  # (none when no one reads them: measured on demand)
                    self.contact.record_metrics(rec, state, cfg.substeps, objects_side=cfg.object_metrics,
                                                skin_side=cfg.frame_metrics)
                self.contact.record_frame_end(rec, state)  # the skin's move against the feature slack

            gated(frame_end, 1)
        if not end_folded:  # (else counted inside the frame launch, from shared memory)
            launch(integrate.count_inverted, m.guard_tets.shape[0], [m.guard_tets, m.vertex_world, state.x],
                   [state.guard])
        ops += self._tail

    def set_frame_tail(self, ops: list) -> None:
        """Run ``ops`` (zero-argument callables: recorded launches, copies) at the end of every frame,
        awake or asleep, inside the frame's CUDA graph, before the frame's one host sync: e.g.
        SoftHand's skin write-back (writeback.py), which then needs no launches or sync of its own.
        Frames recorded before are recorded again (kernels stay compiled)."""
        self._tail = list(ops)
        self._forget_recordings()

    def _forget_recordings(self) -> None:
        """Drop every recorded frame and graph: the next frame records again (kernels stay compiled)."""
        self._ops.clear()
        self.sleep.forget()
        self._graphs.clear()
        self._pre.clear()


class FrameRecorder(Recorder):
    """The solver's recorder of a frame (:class:`~physhand_mj.launch.Recorder`): its launches made
    once the frame is recorded (:class:`_DeferredLaunches`: the modules compiled first), each a
    CPU list launch sized by its list's length where it walks one; :meth:`gated` blocks the
    contact's work behind the solver's gates (``activity``: activity.py); :attr:`ahead` the list
    the frame broadphase runs from ahead of the frame's graph (CUDA), set by the solver."""

    def __init__(self, device, activity):
        super().__init__(device)
        self.activity = activity
        self.deferred = _DeferredLaunches(device)

    def launch(self, kernel, dim, inputs, outputs, count=None, block_dim=None, min_dim=0) -> None:
        """Record a launch of ``dim`` threads; with ``count`` (a (1,) int array: the length of
        the list the kernel walks) a CPU launch runs only that many threads (CPU memory is
        read on the host for free; CUDA launches at most ``list_launch_blocks`` blocks, whose
        threads past the list return); ``block_dim`` for tiled kernels (CUDA: a block per list
        entry, capped the same way); ``min_dim``: a CPU list launch runs at least that many
        threads (a kernel whose thread 0 has work of its own however long the list)."""
        if not dim:
            return
        d = self.device
        kw = launch_options(d, count, block_dim)

        def make():
            cmd = wp.launch(kernel, dim, inputs=inputs, outputs=outputs, device=d, record_cmd=True, **kw)
            return cmd.launch if count is None or d.is_cuda else _ListLaunch(cmd, count, min_dim)

        self.add(kernel, block_dim, make)

    def add(self, kernel, block_dim, make) -> None:
        """Record the launch ``make()`` returns once the frame's modules are compiled (``kernel``,
        ``block_dim``: the module variant it needs)."""
        self.deferred.add(self.ops, kernel, block_dim, make)

    def gated(self, record, level, slots=(), flag=None):
        """Record ``record(sub_ops)`` into a block that runs only when contact has work
        (activity.py: level 0 = an object may be near, 1 = the frame broadphase kept a triangle,
        2 = one of the contact counters at ``slots`` is not zero; ``flag``: a device flag
        already set from them, for CUDA's conditional node); returns the gate (None: nothing
        recorded)."""
        sub: list = []
        outer, self.ops = self.ops, sub
        try:
            record(sub)
        finally:
            self.ops = outer
        if sub:
            outer.append(self.activity.gate(sub, level, slots, flag))
            return outer[-1]
        return None

    def make(self) -> None:
        """Make the recorded launches (:meth:`_DeferredLaunches.make`)."""
        self.deferred.make()


class _DeferredLaunches:
    """The launches of a frame being recorded, made once it is recorded: first the Warp modules
    they need compiled (on CUDA side by side, a thread per module up to the host's cores:
    :func:`load_modules`), then each launch recorded (``wp.launch(record_cmd=True)``, which would
    compile its module alone, one after the other) and put where its stand-in was. A fresh GPU
    host compiles the package's modules in minutes one by one and in ~20 s on 16 cores. Only the
    modules the frame launches compile: a scene without objects compiles no contact kernel."""

    def __init__(self, device):
        self.device = device
        self.pending: list = []  # (list, index, stand-in, make)
        self.modules: dict = {}  # Warp module -> the block_dim values it is launched with

    def add(self, ops: list, kernel, block_dim, make) -> None:
        """Record in ``ops`` a stand-in for the launch ``make()`` returns (``kernel``, ``block_dim``:
        which module variant it needs)."""
        stand_in = _StandIn()
        self.pending.append((ops, len(ops), stand_in, make))
        ops.append(stand_in)
        self.modules.setdefault(kernel.module, set()).add(block_dim)

    def make(self) -> None:
        """Compile the modules (those already loaded return at once), then make every launch."""
        if not self.pending:
            return
        load_modules(self.device, self.modules)
        for ops, i, stand_in, make in self.pending:
            stand_in.op = make()
            if i < len(ops) and ops[i] is stand_in:
                ops[i] = stand_in.op
        self.pending, self.modules = [], {}


class _StandIn:
    """A recorded launch's place until it is made (_DeferredLaunches; a list copied meanwhile
    keeps it, calling the launch made)."""

    op = None

    def __call__(self):
        self.op()


def load_modules(device, modules: dict, workers: int | None = None) -> None:
    """Compile (or load from the kernel cache) Warp ``modules`` on ``device``, on CUDA side by side
    (a thread per module up to the host's cores: NVRTC runs outside Python's lock), on the CPU one
    after the other: {module: the ``block_dim`` values (None: the launch's default) it will be
    launched with}; each as its launches would load it (``wp.force_load``). ``workers``: threads
    (None: as said)."""

    cuda = wp.get_device(device).is_cuda

    def load(module):
        for block_dim in modules[module]:
            if block_dim is None:  # (the variant a launch without one loads: 1 on the CPU, and on CUDA the
                block_dim = module.options["block_dim"] if cuda else 1  # module's, 256: none sets another)
            wp.force_load(device=device, modules=[module], block_dim=block_dim, max_workers=0)

    # (CUDA only: Warp's CPU builds contend: on a 2-core host the solver's two modules side by side
    # took 1.2-2.2 x the wall time and 1.3 x the CPU time of one after the other, the grasp demo's
    # first frame (nine modules) 1.4-1.7 x the wall time)
    if workers is None:
        workers = (os.cpu_count() or 1) if cuda else 1
    workers = min(len(modules), workers)
    if workers <= 1:
        for module in modules:
            load(module)
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for f in [pool.submit(load, module) for module in modules]:
            f.result()


class _ListLaunch:
    """A recorded CPU launch sized, when run, by the list length in ``count[0]``."""

    def __init__(self, cmd, count, min_dim: int = 0):
        self.cmd, self.count, self.dim, self.min_dim = cmd, count.numpy(), -1, int(min_dim)

    def __call__(self):
        n = max(int(self.count[0]), self.min_dim)
        if n:
            if n != self.dim:
                self.cmd.set_dim(n)
                self.dim = n
            self.cmd.launch()
