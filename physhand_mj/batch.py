"""Batched worlds: W hands advanced by one solver step (issue 15).

W copies of one asset become one body with W disconnected components (``replicate_asset``): the
skins of all worlds first (the solver's layout: skin vertices lead), then every world's flesh and
skeleton; bodies ``name#w``. Every solver kernel is element-parallel over vertices and constraints,
so the replicated model runs through the unchanged :class:`~physhand_mj.solver.Solver`: one
frame of W hands is one recorded frame (one CUDA graph on a GPU), its launches W times wider, like
Newton's replicated builders and mujoco_warp's ``nworld``. Worlds never interact: no constraint
crosses them, and each world is solved at its own place in space (``BatchedHands.offsets``), far
enough apart that no distance-limited contact query reaches another world.

:class:`BatchedHands` keeps the per-world views: bone poses in per world, skins out per world,
and per-world reports: the guard counts (non-finite vertices, inverted tets, tethered skin) and
both penetration measures per world (:meth:`BatchedHands.metrics`, ``step()["worlds"]``); a world
that goes non-finite is reset vertex by vertex (``integrate.advance``) and reported alone. The
contact is world-indexed: a skin triangle's broadphase tests only its own world's geoms
(contact/broadphase.py), its decision points query only those (world-relative masks,
contact/query.py), and the metrics measure each world against its own objects.
``physhand rollout LIST --batch W`` (physhand_mj/batch_rollout.py) runs rollouts W at a time.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from physhand_mj.rotations import quat_to_mat
from physhand_mj.solver.model import vertex_world
from physhand_mj.solver.worlds import check_worlds
from physhand_mj.types import GeomType, Layer


def replicate_asset(asset, worlds: int):
    """``worlds`` disconnected copies of ``asset`` as one asset: all skins first (world 0's, then
    world 1's, ...), then each world's other vertices; every index array remapped, bodies
    ``name#w``. World w's skin is vertices [w n_skin, (w + 1) n_skin)."""
    check_worlds(worlds)
    n, ns, nb = asset.n_vertices, asset.n_skin, len(asset.body_names)
    if not np.all(asset.layer[:ns] == Layer.SKIN):
        raise ValueError("asset: skin vertices must come first (layer SKIN for vertices [0, n_skin))")
    w = np.arange(worlds)[:, None]
    i = np.arange(n)[None, :]
    new = np.where(i < ns, w * ns + i, worlds * ns + w * (n - ns) + (i - ns))  # (W, N): old -> new index
    order = np.empty(worlds * n, np.int64)
    order[new.ravel()] = np.arange(worlds * n)  # new index -> (world, old index) flattened

    def per_vertex(a):
        return np.asarray(a)[order % n]

    def indices(a):
        a = np.asarray(a)
        return np.concatenate([new[k][a] for k in range(worlds)]).astype(a.dtype)

    def tiled(a):
        return np.concatenate([np.asarray(a)] * worlds)

    vb = np.asarray(asset.vertex_body)
    body = per_vertex(vb)
    body = np.where(body >= 0, body + (order // n) * nb, -1).astype(vb.dtype)
    return dataclasses.replace(
        asset,
        positions=per_vertex(asset.positions), layer=per_vertex(asset.layer), mass=per_vertex(asset.mass),
        vertex_body=body, skin_faces=indices(asset.skin_faces), tets=indices(asset.tets),
        tet_rest_volume=tiled(asset.tet_rest_volume), edges=indices(asset.edges),
        edge_rest_length=tiled(asset.edge_rest_length), attach=indices(asset.attach),
        attach_rest_length=tiled(asset.attach_rest_length), dihedral=indices(asset.dihedral),
        dihedral_rest_angle=tiled(asset.dihedral_rest_angle), bone_faces=indices(asset.bone_faces),
        body_names=np.array([f"{b}#{k}" for k in range(worlds) for b in asset.body_names]),
        body_rest_pos=tiled(asset.body_rest_pos), body_rest_quat=tiled(asset.body_rest_quat),
        meta={**asset.meta, "worlds": int(worlds)},
    )


class BatchedHands:
    """W hands of one asset in one solver: ``step(pos, quat)`` with bone poses (W, B, 3) m and
    (W, B, 4) w x y z per world advances all W by one frame.

    ``objects``: the geoms every world holds, as dicts of :meth:`Objects.add`'s arguments (``gtype``,
    ``size``, ``name``; ``vertices``/``faces`` for a mesh); each world gets its own copy, posed by
    ``step(..., object_pos (W, k, 3), object_quat (W, k, 4))``. Every world is solved at the
    origin: the skin side of the contact (broadphase, decision points, metrics) tests a triangle
    against its own world's geoms only, and the object side (feature lists and pushes, object points
    inside the skin), which queries one BVH over every world's skin, runs on the skin and geoms moved
    by ``query_offsets[w]`` (a square grid, ``spacing`` m apart, default 1 m; those queries are
    distance-limited to ~1 cm, so they stay in their world while each world's objects stay within
    spacing / 2 - 0.15 m of its hand's origin). Batched worlds then equal serial runs (CPU: bit
    for bit where the object side's float32 rounding at the offset does not flip a decision). Poses in and
    positions out are in each world's own frame. A triangle's broadphase and decision points test
    only its world's geoms; :meth:`penetration`, :meth:`metrics` and ``step()["worlds"]`` report per world (the
    frame dict's own counts and penetration summary are the batch's: sums, deepest).
    """

    def __init__(self, asset, worlds: int, config=None, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0),
                 objects=(), spacing: float | None = None, object_mass=None, object_inertia=None,
                 object_friction=None):
        """``pos`` (3,) m / ``quat`` (4,) w x y z place the rest shape of every world; (W, 3) and
        (W, 4) place each world's own (in its frame). With ``Config.two_way`` (:class:`BatchTwoWay`),
        per object (``objects``' geoms grouped by their ``obj``; (n,) for every world or (W, n)):
        ``object_mass`` kg (0 or None: the skin does not move it within the frame; its wrench is
        still reported), ``object_inertia`` (n, 3) / (W, n, 3) kg m^2 principal moments in its
        inertial frame, ``object_friction`` its friction coefficient against the skin (default 1,
        MuJoCo's default; MuJoCo's rule for a geom pair is the larger of the two)."""
        from physhand_mj.contact import Objects
        from physhand_mj.solver import Solver
        from physhand_mj.types import Config

        check_worlds(worlds)
        self.asset, self.worlds = asset, int(worlds)
        self.config = (config if config is not None else Config()).validate()
        from physhand_mj.types import NonFinite

        if NonFinite(self.config.nonfinite) != NonFinite.RECOVER:
            raise ValueError(f"BatchedHands needs Config.nonfinite=NonFinite.RECOVER (got {NonFinite(self.config.nonfinite).name}): "
                             "a world that turns non-finite is reset and reported alone (step()['worlds']); "
                             "raising would stop every world for one")
        import warp as wp

        from physhand_mj.solver import fused_choice

        if fused_choice.cuda_auto(self.config, asset, self.worlds, wp.get_device(self.config.device)):
            # Config.execution.fused_substep=None on CUDA: a block per world in shared memory from 0.3 worlds per SM
            self.config = dataclasses.replace(self.config, fused_substep=True)
        if spacing is None:  # the object side's queries apart by 1 m (the solve stays at the origin)
            spacing = 1.0
        if objects and self.worlds > 1 and not (np.isfinite(spacing) and spacing >= 0.3):
            raise ValueError(f"BatchedHands spacing must be at least 0.3 m with objects (got {spacing!r}): the "
                             "contact's object side queries each world moved to its place on a grid that many m "
                             "apart, and a hand with its objects spans ~0.3 m")
        side = int(np.ceil(np.sqrt(self.worlds)))
        k = np.arange(self.worlds)
        # every world is solved at the origin (offsets, kept for callers: zero); only the object side's
        # queries see world w moved by query_offsets[w] (Contact.set_query_offsets)
        self.offsets = np.zeros((self.worlds, 3))
        self.query_offsets = np.stack([k % side, k // side, np.zeros(self.worlds)], axis=1) * float(spacing)
        self.objects = None
        self.n_objects = len(objects)
        if objects:
            self.objects = Objects(str(self.config.device or "cpu"), self.worlds * len(objects))
            for w in range(self.worlds):
                for spec in objects:  # (coupling.geom_spec's dicts too: their pose is set by step)
                    spec = {k: v for k, v in spec.items() if k not in ("pos", "quat")}
                    name = f"{spec.pop('name', 'object')}#{w}"
                    obj = f"{spec.pop('obj')}#{w}" if spec.get("obj") else name
                    spec.pop("obj", None)
                    if spec.get("gtype") == GeomType.MESH:
                        spec.setdefault("mesh_grid_spacing", self.config.mesh_grid)
                    self.objects.add(spec.pop("gtype"), spec.pop("size", None), self.offsets[w] + 1e3,
                                     name=name, obj=obj, **spec)  # parked far away until step poses them
        self.solver = Solver(self._model(), self.config, objects=self.objects)
        if self.solver.contact is not None and self.worlds > 1:
            self.solver.contact.set_query_offsets(self.query_offsets)
        self.n_bodies = len(asset.body_names)
        pos, quat = np.asarray(pos, float), np.asarray(quat, float)
        each = pos.ndim == 2
        if each and (pos.shape != (self.worlds, 3) or quat.shape != (self.worlds, 4)):
            raise ValueError(f"placements per world must be {(self.worlds, 3)} positions and {(self.worlds, 4)} "
                             f"quaternions, got {pos.shape} and {quat.shape}")
        self.state = self.solver.make_state(*((pos, quat) if not each else ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))))
        world = vertex_world(self.solver.model.n_vertices, self.solver.model.n_skin, self.worlds)
        if each:
            self._place(pos, quat, world)
        # shift each world to its place: positions (x, x_prev, x_safe) and the bones' host poses (the
        # offsets are zero: every world is solved at the origin; kept for a layout that spreads them)
        if np.any(self.offsets):
            import warp as wp

            shift = self.offsets[world].astype(np.float32)
            for name in ("x", "x_prev", "x_safe"):
                arr = getattr(self.state, name)
                arr.assign(wp.array(arr.numpy() + shift, dtype=wp.vec3, device="cpu"))
        self.body_shift = np.repeat(self.offsets, self.n_bodies, axis=0)
        self.state.pose_host[:, :, :3] += self.body_shift.astype(np.float32)
        self.last_worlds: list[dict] = []
        self._unclaimed = None  # (report, per-world arrays) of a finished frame not yet returned
        # Config.two_way: the objects' and bones' exchange, world by world as rows (BatchTwoWay)
        self.two_way = None
        if self.config.two_way and self.solver.contact is not None:
            self.two_way = BatchTwoWay(self, object_mass, object_inertia, object_friction)
        elif any(a is not None for a in (object_mass, object_inertia, object_friction)):
            raise ValueError("object_mass / object_inertia / object_friction are two-way coupling's "
                             "(Config(two_way=True), with objects)")

    # -- lifetime ----------------------------------------------------------------------------------
    def close(self) -> None:
        """Release the batch's arrays now (its solver with the recorded frames and CUDA graphs, its
        state and objects) instead of whenever the garbage collector gets to them: a process running
        batch after batch needs the memory back before the next allocates (two W = 4096 batches ran an
        H100 out of memory, docs/scale.md). The batch cannot step afterwards. Also ``with
        BatchedHands(...) as hands:``."""
        import gc

        import warp as wp

        if self.solver is None:
            return
        if self._launched:  # (the frame in flight ends before its arrays go; its report with them)
            wp.synchronize_device(self.solver.device)
        s = self.solver
        s._forget_recordings()
        s.last_graph = None
        self.solver = self.state = self.objects = None
        del s
        gc.collect()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _alive(self) -> None:
        if self.solver is None:
            raise RuntimeError("this BatchedHands was closed (BatchedHands.close): make a new batch")

    def _model(self):
        """The W-world model: one world's arrays tiled (Jacobi: a copy, no per-world rebuild), or for
        the colored scheme (colours over the whole body) the model of the replicated asset."""
        from physhand_mj.solver.model import make_model, model_arrays
        from physhand_mj.types import Scheme

        cfg = self.config.validate()
        if cfg.scheme != Scheme.JACOBI:
            return make_model(self.replicated, cfg)
        from physhand_mj.solver.worlds import tile_model

        # one world's arrays, tiled by kernels on the device (the same arrays as tile_model_arrays +
        # upload_model, without the W-wide host copies: solver/worlds.py)
        return tile_model(model_arrays(self.asset, cfg, batch=self.worlds > 1), self.worlds, cfg)

    @property
    def replicated(self):
        """The asset replicated W times (:func:`replicate_asset`), built on first use."""
        if getattr(self, "_replicated", None) is None:
            self._replicated = replicate_asset(self.asset, self.worlds)
        return self._replicated

    def _place(self, pos: np.ndarray, quat: np.ndarray, world: np.ndarray) -> None:
        """Each world's rest shape placed by its own rigid transform (as ``Solver.make_state`` places
        one hand), in its frame."""
        import warp as wp

        from physhand_mj.rotations import quat_to_mat
        from physhand_mj.rotations import compose_quat

        m = self.solver.model
        rot = quat_to_mat(quat).reshape(self.worlds, 3, 3)
        x = np.einsum("nij,nj->ni", rot[world], m.rest_x.numpy().astype(np.float64)) + pos[world]
        for name in ("x", "x_prev", "x_safe"):
            getattr(self.state, name).assign(wp.array(x.astype(np.float32), dtype=wp.vec3, device="cpu"))
        bw = np.repeat(np.arange(self.worlds), self.n_bodies)
        bp = np.einsum("nij,nj->ni", rot[bw], m.body_rest_pos) + pos[bw]
        bq = np.concatenate([compose_quat(quat[w], m.body_rest_quat[w * self.n_bodies:(w + 1) * self.n_bodies])
                             for w in range(self.worlds)])
        self.solver.set_body_poses(self.state, bp, bq)
        self.state.pose_host[0] = self.state.pose_host[1]

    def settle(self, pos: np.ndarray, quat: np.ndarray, frames: int = 20) -> None:
        """Move every world's bones from where they are (the rest placement after construction) to
        ``pos`` (W, B, 3) m / ``quat`` (W, B, 4) w x y z over ``frames`` frames without contact, as
        ``SoftHand(..., settle_contact=False)`` does for one hand (a grasp keyframe starts from the
        undeformed posed skin, its penetrations included)."""
        self._alive()
        self._complete()  # (a submitted frame first: its report stays for submit / wait)
        from physhand_mj.rotations import nlerp
        from physhand_mj.solver import Solver

        pos, quat = self._check_poses(pos, quat)
        if self.two_way is not None:  # (the bones' velocities start over after the settle's moves)
            self.two_way.forget_bones()
        settler = Solver(self.solver.model, self.config)
        settler.warn_fast_motion = False  # settling moves the bones on purpose
        hp = self.state.pose_host[1]
        rest_pos = hp[:, :3].astype(float)
        rest_quat = hp[:, [6, 3, 4, 5]].astype(float)  # x y z w -> w x y z
        target = pos.reshape(-1, 3) + self.body_shift
        for k in range(frames):
            a = (k + 1) / frames
            settler.set_body_poses(self.state, (1 - a) * rest_pos + a * target, nlerp(rest_quat, quat.reshape(-1, 4), a))
            settler.step(self.state)

    def restart(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """A new episode in every world, as ``SoftHand.reset`` starts one before its settling frames:
        each world's rest shape placed by its own ``pos`` (W, 3) m / ``quat`` (W, 4) w x y z (its
        frame; :func:`~physhand_mj.coupling.rest_placement` of its first bone), velocities, multipliers
        and guards zeroed, the solver awake, the bones' two-way velocities forgotten. The bones are then
        moved to the episode's pose by the caller's settling frames."""
        self._alive()
        self._complete()
        self._unclaimed = None
        import warp as wp

        pos, quat = np.asarray(pos, float), np.asarray(quat, float)
        if pos.shape != (self.worlds, 3) or quat.shape != (self.worlds, 4):
            raise ValueError(f"restart: placements must be {(self.worlds, 3)} positions (m) and {(self.worlds, 4)} "
                             f"quaternions (w x y z), got {pos.shape} and {quat.shape}")
        fresh = self.solver.make_state()
        for name in ("v", "delta", "lam_edge", "lam_tet", "lam_dih", "body_sub", "guard"):
            wp.copy(getattr(self.state, name), getattr(fresh, name))
        self.state.pose_fresh, self.state.time, self.state.frames = fresh.pose_fresh, 0.0, 0
        self._place(pos, quat, vertex_world(self.solver.model.n_vertices, self.solver.model.n_skin, self.worlds))
        self.solver.wake(self.state)
        if self.solver.contact is not None:  # (the feature lists' slack, the two-way exchange: SoftHand.reset)
            self.solver.contact.new_episode()
        if self.two_way is not None:
            self.two_way.forget_bones()

    def last_penetration(self) -> tuple[np.ndarray, np.ndarray]:
        """Per world, the last frame's skin samples inside objects (the solver's frame metric, the
        paper's 21-sample measure): counts (W,) and deepest (W,) um; zeros without contact or with
        Config.frame_metrics off. Arrays, no per-world dicts (a batched environment's observations)."""
        self._alive()
        c = self.solver.contact
        if c is None or not self.config.frame_metrics:
            return np.zeros(self.worlds, np.int64), np.zeros(self.worlds)
        rows = c.read_metrics_worlds(synchronize=False)[:, -1, :3].astype(np.float64)
        return np.rint(rows[:, 0]).astype(np.int64), rows[:, 2] * 1e6

    @staticmethod
    def two_way_poses(report: dict, pos, quat) -> tuple[np.ndarray, np.ndarray]:
        """Body poses (W, n, 3) m / (W, n, 4) w x y z at a two-way frame's start moved as that frame
        moved each object (``report``: the frame report's ``two_way``; :meth:`BatchTwoWay.moved_poses`)."""
        return BatchTwoWay.moved_poses(report, pos, quat)

    def set_object_poses(self, object_pos, object_quat) -> None:
        """Every world's object poses, ``object_pos`` (W, k, 3) m and ``object_quat`` (W, k, 4) w x y z,
        each in its world's frame (``step`` takes them too)."""
        self._alive()
        self._complete()  # (a submitted frame still reads the poses it was given)
        rows = self._object_rows(object_pos, object_quat)
        if rows is not None:
            self.objects.set_pose_rows(rows)

    def _object_rows(self, object_pos, object_quat):
        """The objects' pose rows (Objects.pose_rows), checked; None without objects."""
        if self.objects is None:
            return None
        if object_pos is None or object_quat is None:
            raise ValueError(f"object poses are needed: object_pos {(self.worlds, self.n_objects, 3)} m and "
                             f"object_quat {(self.worlds, self.n_objects, 4)} w x y z")
        op = np.asarray(object_pos, float).reshape(self.worlds, self.n_objects, 3) + self.offsets[:, None]
        return self.objects.pose_rows(op.reshape(-1, 3), np.asarray(object_quat, float).reshape(-1, 4))

    def _check_poses(self, pos, quat):
        pos, quat = np.asarray(pos, float), np.asarray(quat, float)
        want = (self.worlds, self.n_bodies)
        if pos.shape != want + (3,) or quat.shape != want + (4,):
            raise ValueError(f"bone poses must be {want + (3,)} positions and {want + (4,)} quaternions, "
                             f"got {pos.shape} and {quat.shape}")
        return pos, quat

    def step(self, pos: np.ndarray, quat: np.ndarray, object_pos=None, object_quat=None, **two_way) -> dict:
        """One frame of every world: bone poses at its end, ``pos`` (W, B, 3) m, ``quat`` (W, B, 4)
        w x y z, bodies ordered as ``asset.body_names``; with objects their poses ``object_pos``
        (W, k, 3) m and ``object_quat`` (W, k, 4) w x y z, in each world's frame. Returns the
        solver's frame dict (counts summed over worlds, the batch's penetration summary) with
        ``worlds``: per world its guard counts and the frame's skin-sample penetration summary
        (:meth:`frame_worlds`). The same as :meth:`submit` then :meth:`wait`.

        With ``Config.two_way`` the objects' state comes as keywords (:meth:`BatchTwoWay.frame_state`:
        ``object_vel`` (W, n, 6) [linear m/s of the centre, angular rad/s], ``object_com``,
        ``object_iquat``, ``bone_com``, ``bone_vel``) and the report's ``two_way`` says what the skin
        did to them (:meth:`BatchTwoWay.report`: wrenches, friction, the bones' reaction, the
        objects' motion in the frame)."""
        self._alive()
        if self._launched or self._unclaimed is not None:
            raise RuntimeError("a submitted frame's report is not read yet: BatchedHands.wait() before step()")
        self.submit(pos, quat, object_pos, object_quat, **two_way)
        return self.wait()

    def submit(self, pos: np.ndarray, quat: np.ndarray, object_pos=None, object_quat=None, **two_way) -> dict | None:
        """:meth:`step` in a pipeline: the frame is queued on the device and the call returns the
        report of the frame submitted before it (None for the first). The new poses are checked on
        the host and copied into the next upload buffer (``Solver.stage_pose_rows``) while the
        device still runs that frame, and its per-world rows are built while
        the device runs this one; every decision a frame takes (sleeping, the work set) is taken
        from the same inputs as in :meth:`step`, so the frames are the same. :meth:`wait` returns
        the last frame's report. Reading the batch (skins, penetration, metrics) waits for the
        frame in flight first; its report stays for the next :meth:`submit` or :meth:`wait`. A
        frame's error is raised by the call that waits for it; an error in the new frame's launch
        leaves the finished frame's report for :meth:`wait`::

            for k in range(frames):
                report = hands.submit(pos[k], quat[k])  # frame k-1's report (None at k = 0)
            report = hands.wait()                        # frame frames-1's
        """
        self._alive()
        pos, quat = self._check_poses(pos, quat)
        rows = self.solver.pose_rows((pos + self.offsets[:, None]).reshape(-1, 3), quat.reshape(-1, 4))
        obj = self._object_rows(object_pos, object_quat)
        if self.two_way is not None:  # (checked and packed on the host while the device runs)
            sent = self.two_way.frame_state(pos, quat, object_pos, object_quat, **two_way)
        elif two_way:
            raise TypeError(f"{sorted(two_way)}: two-way coupling's inputs (Config(two_way=True), with objects)")
        staged = self.solver.stage_pose_rows(self.state, rows)  # (the upload buffer filled meanwhile too)
        self._complete()  # the frame in flight: its sync and the solver's report
        if obj is not None:
            self.objects.set_pose_rows(obj)
        if self.two_way is not None:  # (after the frame in flight: it reads the exchange's inputs)
            self.two_way.send(sent)
        self.solver.launch(self.state, staged=staged, rows=rows)  # (the host's copy of the rows after the launch)
        return self._claim()

    def wait(self) -> dict | None:
        """The report of the frame in flight (:meth:`submit`), after waiting for it; None if every
        submitted frame was reported."""
        self._alive()
        self._complete()
        return self._claim()

    @property
    def _launched(self) -> bool:
        """A frame is in flight (:meth:`submit`): its report comes from the next submit / wait (the
        solver's own record, so an interrupted submit cannot leave the two apart)."""
        return self.solver is not None and self.solver._in_flight is not None

    def _complete(self) -> None:
        """Wait for the frame in flight (if any) and keep its report and the raw per-world rows,
        copied before the next frame's copies overwrite the host buffers. A frame's error
        (``Solver.finish``: a stuck stage, NonFinite.RAISE) is raised here, by whichever call
        waits for it; that frame's report is then lost."""
        if not self._launched:
            return
        out = self.solver.finish(self.state)
        if self.two_way is not None:
            out["two_way"] = self.two_way.report()
        self._asleep = bool(out.get("asleep", False))  # (frame_worlds' too: a sleeping frame ran no self-contact)
        self._unclaimed = (out, self._world_arrays(self._asleep))

    def _claim(self) -> dict | None:
        if self._unclaimed is None:
            return None
        out, raw = self._unclaimed
        self._unclaimed = None
        out["worlds"] = self.last_worlds = self._world_rows(*raw)
        return out

    def frame_worlds(self) -> list[dict]:
        """Per world, the last frame's ``nonfinite`` / ``inverted`` / ``tethered`` guard counts and its
        skin samples inside objects at the frame's end (``penetration_count`` / ``_max_um`` /
        ``_avg_um``, the solver's frame metric; none with Config.frame_metrics off: :meth:`penetration`
        measures them when called) and, with object feature points, whether its feature
        lists' check failed (``feature_slack_exceeded``, 0 or 1): what ``Solver.step`` reports for
        one hand."""
        self._complete()
        return self._world_rows(*self._world_arrays(getattr(self, "_asleep", False)))

    def _world_arrays(self, asleep: bool = False):
        """The last frame's per-world guard counts, skin-measure rows, feature checks and self-contact
        figures (copies; ``asleep``: the frame ran no self-contact, zeros)."""
        g = self.solver.guard_worlds  # (a copy per frame: Solver._read_guard_worlds)
        c = self.solver.contact
        rows = c.read_metrics_worlds(synchronize=False)[:, -1, :3] if c is not None else np.zeros((self.worlds, 3))
        if not self.config.frame_metrics:  # nothing measured in the frame (Config.frame_metrics): no columns
            rows = rows[:, :0]
        over = c.feature_motion_worlds(self.solver.activity.last_open1) if c is not None else None
        sc = self.solver.selfc  # Config.self_collision: the frame's pairs per world
        selfw = None if sc is None else (np.zeros((self.worlds, 4), int) if asleep else sc.report_worlds())
        return g, rows, over, selfw

    def _world_rows(self, g, rows, over, selfw=None) -> list[dict]:
        from physhand_mj.contact.metrics import summarize_rows

        out = [dict(nonfinite=nf, inverted=inv, tethered=teth, **pen)
               for nf, inv, teth, pen in zip(g[:, 0].tolist(), g[:, 1].tolist(), g[:, 2].tolist(),
                                             summarize_rows(rows))]
        if selfw is not None:  # (Solver.step's self_vertices / _pairs / _pairs_over / _corrections, per world)
            for row, (nv, npairs, nover, ncorr) in zip(out, selfw.tolist()):
                row.update(self_vertices=nv, self_pairs=npairs, self_pairs_over=nover, self_corrections=ncorr)
        if over is not None:  # this world's feature lists' check (Config.tuning.feature_slack), where it has feature points
            for row, o in zip(out, over):
                row["feature_slack_exceeded"] = o
        return out

    def penetration(self, order: int = 5) -> list[dict]:
        """Both penetration measures of every world's skin as it is now, each world against its own
        objects: ``penetration_*`` (skin samples on the order-``order`` lattice inside objects; the
        metric's is 5) and ``object_in_skin_*`` (object surface points inside the closed skin), as
        ``SoftHand.penetration`` gives them for one hand (counts, um)."""
        self._alive()
        self._complete()  # (a submitted frame first: its report stays for submit / wait)
        from physhand_mj.contact.metrics import summarize_rows

        c = self.solver.contact
        rows = c.measure_worlds(self.state, order=order) if c is not None else np.zeros((self.worlds, 6))
        return summarize_rows(rows)

    def metrics(self, order: int = 5) -> list[dict]:
        """Per world: both penetration measures now (:meth:`penetration`), the last frame's guard
        counts (``nonfinite``, ``inverted``, ``tethered``) and ``finite`` (its skin holds finite
        positions now)."""
        self._alive()
        self._complete()  # (a submitted frame first: its report stays for submit / wait)
        x = self.state.x.numpy()
        ns = self.asset.n_skin
        guards = self.frame_worlds() if self.state.frames else [
            dict(nonfinite=0, inverted=0, tethered=0)] * self.worlds
        out = []
        for w, pen in enumerate(self.penetration(order)):
            g = {k: guards[w][k] for k in ("nonfinite", "inverted", "tethered")}
            out.append(dict(pen, **g, finite=bool(np.all(np.isfinite(x[w * ns:(w + 1) * ns])))))
        return out

    def skin(self, world: int) -> np.ndarray:
        """(n_skin, 3) skin positions (m) of one world, in its frame (copies that world's part only)."""
        self._alive()
        self._complete()  # (a submitted frame first: its report stays for submit / wait)
        ns = self.asset.n_skin
        return self.state.x[world * ns:(world + 1) * ns].numpy() - self.offsets[world].astype(np.float32)

    def skins(self) -> np.ndarray:
        """(W, n_skin, 3) every world's skin positions (m), each in its frame, in one copy from the
        device (a batched rollout's end: skin(w) per world copied the whole state W times, 89 ms a
        world at W = 1024 on an H100, 91 of the batch's 147 s)."""
        self._alive()
        self._complete()  # (a submitted frame first: its report stays for submit / wait)
        ns = self.asset.n_skin
        x = self.state.x[: self.worlds * ns].numpy().reshape(self.worlds, ns, 3)
        return x - self.offsets[:, None, :].astype(np.float32)

    def positions(self, world: int) -> np.ndarray:
        """(N, 3) all positions (m) of one world, in the asset's vertex order and the world's frame."""
        self._alive()
        self._complete()  # (a submitted frame first: its report stays for submit / wait)
        n, ns = self.asset.n_vertices, self.asset.n_skin
        x = self.state.x.numpy()
        rest = self.worlds * ns + world * (n - ns)
        return np.concatenate([x[world * ns:(world + 1) * ns], x[rest:rest + n - ns]]) - \
            self.offsets[world].astype(np.float32)


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a * b of (..., 4) w x y z quaternions (broadcast)."""
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def _quat_rate(q: np.ndarray, q_prev: np.ndarray, dt: float) -> np.ndarray:
    """(..., 3) rad/s: the angular velocity that turns ``q_prev`` into ``q`` over ``dt`` (world frame;
    MuJoCo's mju_quat2Vel of q * conj(q_prev), the turn wrapped into (-pi, pi])."""
    dq = _qmul(q, q_prev * np.array([1.0, -1.0, -1.0, -1.0]))
    v = dq[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    speed = 2.0 * np.arctan2(s, dq[..., :1])
    speed = np.where(speed > np.pi, speed - 2.0 * np.pi, speed)
    return np.where(s > 0, v / np.where(s > 0, s, 1.0) * speed / dt, 0.0)


def _quat_turn(omega: np.ndarray, t) -> np.ndarray:
    """(..., 4) w x y z: the turn by angular velocity ``omega`` (..., 3) rad/s over ``t`` s ((..., 1) or a number)."""
    n = np.linalg.norm(omega, axis=-1, keepdims=True)
    a = n * t
    axis = omega / np.where(n > 0, n, 1.0)
    return np.concatenate([np.cos(a / 2), axis * np.sin(a / 2)], -1)


def _per_object(value, worlds: int, n: int, tail: tuple, what: str, default=None) -> np.ndarray:
    """``value`` given once for every world, (n,) + tail, or per world, (W, n) + tail, as (W, n) + tail."""
    if value is None:
        if default is None:
            raise ValueError(f"Config.two_way: {what} is needed, {(n,) + tail} or {(worlds, n) + tail}")
        value = default
    a = np.asarray(value, float)
    if a.ndim == 0 and not tail:  # (one number for every object)
        a = np.full(n, float(a))
    if a.shape == (n,) + tail:
        a = np.broadcast_to(a, (worlds, n) + tail)
    if a.shape != (worlds, n) + tail:
        raise ValueError(f"Config.two_way: {what} must be {(n,) + tail} or {(worlds, n) + tail}, got {a.shape}")
    return np.array(a)


class BatchTwoWay:
    """Two-way coupling for :class:`BatchedHands` (``Config.two_way``): world w's objects and bones
    are rows [w n, (w + 1) n) and [w B, (w + 1) B) of one exchange (contact/exchange.py), so every
    kernel of ``SoftHand``'s coupling runs unchanged over all worlds at once; the host side here is
    ``SoftHand._send_objects`` / ``_apply_wrenches`` without MuJoCo, vectorised over worlds.

    An *object* is a group of ``objects``' geoms with one ``obj`` (each geom its own by default): a
    MuJoCo body. Per frame it takes, for every world (its frame; world frame of a MuJoCo model):

    - ``object_vel`` (W, n, 6): [linear m/s of its centre of mass, angular rad/s] after the
      physics step (a MuJoCo free joint: qvel[0:3] + w x (xipos - xpos), xmat qvel[3:6]), and
      ``object_vel_start`` (W, n, 6): the same before the step (qvel before ``mj_step``, or its qvel -
      qacc dt after it, as ``SoftHand`` takes it): the step's velocity change is spread over the
      frame's substeps (default: ``object_vel``, the step's whole velocity change at the frame's
      start, which the skin's friction must take back within the frame);
    - ``object_com`` (W, n, 3) m: its centre of mass (default: its first geom's position), and
      ``object_iquat`` (W, n, 4) w x y z: its inertial frame (default: its first geom's orientation);
    - ``bone_com`` (W, B, 3) m: the bones' centres, about which their reaction torques are taken
      (default: the bone poses' origins); ``bone_vel`` (W, B, 6) [linear, angular] (default: from
      the poses a frame apart, as ``SoftHand``; the first frame after construction or ``settle``: 0).

    and after the frame (:meth:`report`, the frame report's ``two_way``) gives per object the mean
    wrench the skin applied, its friction part, the bones' reaction, and the motion of each object
    with a mass within the frame (its centre, turn and velocity at the frame's end, the skin's
    impulses in it; :meth:`moved_poses` moves body poses by it). A MuJoCo user then does per world
    what ``SoftHand`` does: ``qvel += M^-1 J^T [wrench * frame_dt]`` for every object body that can
    move and every bone (mj_applyFT at the centres, mj_solveM), and a free object's qpos = its
    :meth:`moved_poses` pose, replacing the physics step's own move of it. ``Config.frame_dt`` must
    be the physics step (checked by ``SoftHand``; here the caller's to keep).
    """

    def __init__(self, hands: BatchedHands, mass, inertia, friction):
        self.hands = hands
        c = hands.solver.contact
        self.exchange = c.two_way
        o = hands.objects
        W = hands.worlds
        self.n = len(o.object_names) // W  # objects per world (world w's: [w n, (w + 1) n))
        if self.n * W != len(o.object_names):
            raise ValueError("Config.two_way: every world must hold the same objects")
        self.names = [name.rsplit("#", 1)[0] for name in o.object_names[: self.n]]
        geom_obj = o.geom_objects[: hands.n_objects]
        # each object's first geom (its default centre and inertial frame)
        self.first = np.array([int(np.flatnonzero(geom_obj == k)[0]) for k in range(self.n)])
        self.n_bodies = hands.n_bodies
        self.set_mass(mass, inertia)
        self.mu = _per_object(friction, W, self.n, (), "object_friction", default=1.0)
        if not (np.all(np.isfinite(self.mu)) and np.all(self.mu >= 0)):
            raise ValueError(f"object_friction must be finite and >= 0, got {self.mu}")
        self._bones_prev = None  # (centres, quats) of the bones at the last frame
        self._fresh = np.zeros(W, bool)  # worlds whose bones start over (forget_bones(worlds)): velocity 0
        self._frame = None  # the inputs of the frame in flight (its report's motion starts from them)

    def set_mass(self, mass, inertia) -> None:
        """Each object's mass (kg; 0, inf or None: the skin does not move it within the frame) and
        principal moments (kg m^2, its inertial frame), (n,) / (n, 3) or per world (W, n) / (W, n, 3),
        from the next frame on."""
        W, n = self.hands.worlds, self.n
        m = _per_object(mass, W, n, (), "object_mass", default=np.zeros(n))
        free = np.isfinite(m) & (m > 0)
        self.inv_mass = np.where(free, 1.0 / np.where(free, m, 1.0), 0.0)
        if np.any(free):
            i = _per_object(inertia, W, n, (3,), "object_inertia (objects with a mass)")
            if not np.all(i[free] > 0):
                raise ValueError("object_inertia: every object with a mass needs positive principal moments")
            self.inv_inertia = np.where(free[..., None], 1.0 / np.maximum(i, 1e-12), 0.0)
        else:
            self.inv_inertia = np.zeros((W, n, 3))

    def forget_bones(self, worlds=None) -> None:
        """The bones' velocities start over (a settle or a new episode: the next frame's are 0), in
        every world or in the worlds of the (W,) bool mask ``worlds``."""
        if worlds is None:
            self._bones_prev = None
            self._fresh[:] = False
        else:
            self._fresh |= np.asarray(worlds, bool)

    def frame_state(self, pos, quat, object_pos, object_quat, object_vel=None, object_com=None, object_iquat=None,
                    bone_com=None, bone_vel=None, object_vel_start=None) -> dict:
        """The next frame's inputs, checked (see the class), on the host; :meth:`send` uploads them."""
        W, n, B = self.hands.worlds, self.n, self.n_bodies
        op = np.asarray(object_pos, float).reshape(W, -1, 3)
        oq = np.asarray(object_quat, float).reshape(W, -1, 4)
        com = op[:, self.first] if object_com is None else np.asarray(object_com, float)
        iq = oq[:, self.first] if object_iquat is None else np.asarray(object_iquat, float)
        vel = np.zeros((W, n, 6)) if object_vel is None else np.asarray(object_vel, float)
        v0 = vel if object_vel_start is None else np.asarray(object_vel_start, float)
        for name, a, shape in (("object_com", com, (W, n, 3)), ("object_iquat", iq, (W, n, 4)),
                               ("object_vel", vel, (W, n, 6)), ("object_vel_start", v0, (W, n, 6))):
            if a.shape != shape:
                raise ValueError(f"Config.two_way: {name} must be {shape} (worlds, objects: {self.names}), got {a.shape}")
        bc = pos if bone_com is None else np.asarray(bone_com, float)
        if bc.shape != (W, B, 3):
            raise ValueError(f"Config.two_way: bone_com must be {(W, B, 3)}, got {bc.shape}")
        dt = float(self.hands.config.frame_dt)
        if bone_vel is not None:
            bv = np.asarray(bone_vel, float)
            if bv.shape != (W, B, 6):
                raise ValueError(f"Config.two_way: bone_vel must be {(W, B, 6)}, got {bv.shape}")
            lin, ang = bv[..., :3], bv[..., 3:]
        elif self._bones_prev is not None:  # from the poses a frame apart (mocap-like bones have no velocity)
            lin = (bc - self._bones_prev[0]) / dt
            ang = _quat_rate(quat, self._bones_prev[1], dt)
            if self._fresh.any():
                lin, ang = (np.where(self._fresh[:, None, None], 0.0, a) for a in (lin, ang))
        else:
            lin = ang = np.zeros((W, B, 3))
        r = quat_to_mat(iq)  # the world inverse inertia R diag(1/I) R^T of each object
        inv_i = np.einsum("wkij,wkj,wklj->wkil", r, self.inv_inertia, r)
        return dict(com=com, vel=vel, start=v0, acc=(vel - v0) / dt, bone_com=bc, bone_quat=np.array(quat, float), bone_lin=lin, bone_ang=ang,
                    inv_i=inv_i)

    def send(self, frame: dict) -> None:
        """Upload a frame's inputs (:meth:`frame_state`; after the frame before it finished)."""
        ex = self.exchange
        ex.set_state(frame["com"].reshape(-1, 3), frame["start"][..., :3].reshape(-1, 3),
                     frame["start"][..., 3:].reshape(-1, 3), frame["bone_com"].reshape(-1, 3), self.mu.reshape(-1),
                     self.inv_mass.reshape(-1), frame["inv_i"].reshape(-1, 3, 3), frame["bone_lin"].reshape(-1, 3),
                     frame["bone_ang"].reshape(-1, 3), frame["acc"][..., :3].reshape(-1, 3), frame["acc"][..., 3:].reshape(-1, 3))
        self._bones_prev = (frame["bone_com"], frame["bone_quat"])
        self._fresh[:] = False
        self._frame = frame

    def report(self) -> dict:
        """The frame just finished (world frame, per world): ``wrench`` (W, n, 6) [force N, torque N m
        about the centre of mass], the skin's mean over the frame on each object; ``friction`` (W, n,
        3) N, the friction part of the force; ``bones`` (W, B, 6) the reaction on each bone (about
        ``bone_com``; per world ``wrench`` and ``bones`` forces sum to 0, Newton's third law);
        ``com`` (W, n, 3) m, ``turn`` (W, n, 4) w x y z, ``vel`` (W, n, 6) [linear, angular]: each
        object's centre, rotation over the frame about its centre and velocity at the frame's end
        (an object with a mass: moved within the frame by its velocity and the skin's impulses; the
        others: as sent, not moved); ``moved`` (W, n) bool: which moved."""
        f = self._frame
        if f is None:  # (a frame before any send: settle's)
            return {}
        W, n, B = self.hands.worlds, self.n, self.n_bodies
        w = self.exchange.wrenches()
        cfg = self.hands.config
        moved = self.inv_mass > 0
        shift = w["shift"][: W * n].reshape(W, n, 3)
        turn = w["turn"][: W * n].reshape(W, n, 4)[..., [3, 0, 1, 2]]  # x y z w -> w x y z
        dv = np.concatenate([w["dv"][: W * n], w["dw"][: W * n]], 1).reshape(W, n, 6)
        vel = f["vel"] + np.where(moved[..., None], dv, 0.0)
        wrench = w["objects"][: W * n].reshape(W, n, 6)
        touched = np.any(wrench != 0, axis=-1)
        s, h = cfg.substeps, cfg.frame_dt / cfg.substeps
        done = np.where(touched, w["steps"][: W * n].reshape(W, n), 0)
        # substeps without a stage (Config.contact_every > 1, nothing near): an object moves on over them
        # with its velocity there (the step's acceleration spread on; SoftHand._apply_wrenches); an
        # untouched one as the physics step moved it (its velocity after the step over the whole frame)
        shift = np.where(touched[..., None], shift, 0.0)
        turn = np.where(touched[..., None], turn, np.array([1.0, 0.0, 0.0, 0.0]))
        t = (h * (s - done))[..., None]
        ramp = (h * h * (s * (s - 1) - done * (done - 1)) / 2)[..., None]
        vr = np.where(touched[..., None], f["start"] + dv, f["vel"]) + np.where(touched[..., None], f["acc"], 0.0) * (
            ramp / np.maximum(t, 1e-30))
        late = moved & (s - done > 0)
        shift = np.where(late[..., None], shift + vr[..., :3] * t, shift)
        spins = late & (np.linalg.norm(vr[..., 3:], axis=-1) * t[..., 0] > 0)
        turn = np.where(spins[..., None], _qmul(_quat_turn(vr[..., 3:], t), turn), turn)
        shift = np.where(moved[..., None], shift, 0.0)
        turn = np.where(moved[..., None], turn, np.array([1.0, 0.0, 0.0, 0.0]))
        return dict(wrench=wrench, friction=w["friction"][: W * n].reshape(W, n, 3),
                    bones=w["bones"][: W * B].reshape(W, B, 6), com=f["com"] + shift, shift=shift, turn=turn, vel=vel,
                    moved=moved.copy())

    @staticmethod
    def moved_poses(report: dict, pos, quat) -> tuple[np.ndarray, np.ndarray]:
        """Body poses ``pos`` (W, n, 3) m / ``quat`` (W, n, 4) w x y z at the frame's start (a MuJoCo
        free body's xpos / xquat after the physics step) moved as the frame moved each object
        (``report``: :meth:`report`'s): turned by ``turn`` about its centre and carried with it."""
        start = report["com"] - report["shift"]
        r = quat_to_mat(report["turn"])
        p = report["com"] + np.einsum("wkij,wkj->wki", r, np.asarray(pos, float) - start)
        q = _qmul(report["turn"], np.asarray(quat, float))
        return p, q / np.linalg.norm(q, axis=-1, keepdims=True)
