"""Rollouts in batches of W worlds: ``physhand rollout LIST --batch W`` (issue 15).

    from physhand_mj.batch_rollout import rollout_batched
    from physhand_mj.rollout import batch_targets
    rows = rollout_batched(batch_targets("runs.txt"), "out/batch", worlds=8, steps=36)

The runs of a list whose scenes hold the same objects (the same geoms: types, sizes, meshes, and the
same time step) share a batch; the others go to batches of their own. A batch is one
:class:`~physhand_mj.batch.BatchedHands`: each run keeps its own MjModel / MjData, stepped with
``mujoco.mj_step`` one world after another, and its bone and object poses go into the batch, whose
one solver frame advances every world (stepping MuJoCo world by world costs 28-87 us a world-frame
on an H100 host, a few percent of a batch: benchmarks/mujoco_side.py, docs/scale.md). The frames
are pipelined (:meth:`~physhand_mj.batch.BatchedHands.submit`): MuJoCo's next step and the last
frame's log rows run on the host while the device runs a frame (not with ``Config.two_way``: there
each frame's wrenches go into every world's MuJoCo before its next step, as ``SoftHand`` does, and
each run writes ``forces.csv`` too). Each run then
writes what the serial
:func:`~physhand_mj.rollout.rollout` writes (``log.csv``, ``counters.csv``, ``skin_final.ply``, its
summary row, its JSON line), from per-world measures: every world is measured against its own objects.

Differences from the serial run, by construction: worlds holding objects are solved 1 m apart
(float32 rounds positions at that scale: the skins agree with the serial ones to tens of um, see
docs/scale.md); ``ms_frame`` / ``ms_per_frame`` are the host's time in the batch frame's submit
and in waiting for it, divided by W (the cost of one hand-frame: on the CPU the whole frame, which
runs inside submit; on a GPU what the host work meanwhile did not hide); ``objects_near``,
``triangles_tested``, ``features_listed`` and ``ops_run`` (counters.csv) count what the batch frame ran
for all its worlds.
"""

from __future__ import annotations

import csv
import gc
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

from physhand_mj.hand_mjcf import enable_self_proxies, set_proxy_margin
from physhand_mj.rollout import (FORCE_COLUMNS, LOG_COLUMNS, bone_clearances, carry_object_side, check_counts, check_measure_every, failed_row,
                                 frame_rows, load_rollout_scene, measured, rollout_config, run_names, self_summary,
                                 start_row, summary_row, write_summary)


def scene_key(scene) -> tuple | None:
    """A scene file's identity for sharing its compiled model: resolved path and modification time
    (None if it does not exist: the run fails on loading)."""
    path = Path(scene)
    try:
        return str(path.resolve()), path.stat().st_mtime_ns
    except OSError:
        return None


class _Run:
    """One run of a batch: its scene, its MuJoCo model and data, its log."""

    def __init__(self, index: int, scene, key, out: Path, asset, models: dict | None = None):
        """``models``: scene key (:func:`scene_key`) -> (MjModel, bones, geoms) of the scenes loaded
        before: runs of one scene file share its compiled model (each has its own MjData); compiling
        it once per run took ~20 ms a run (W = 1024: most of a batch's set-up)."""
        from physhand_mj.coupling import check_skin_mesh, geom_spec, select_object_geoms
        from physhand_mj.hand_mjcf import body_ids, skin_geom_id

        self.index, self.scene, self.out = index, scene, out
        k = scene_key(scene) if models is not None else None
        if k is not None and k in models:  # (models hold only scenes that loaded)
            model, self.bones, self.geoms = models[k]
            self.model, self.data, self.key = load_rollout_scene(scene, key, model)
        else:
            self.model, self.data, self.key = load_rollout_scene(scene, key)
            skin = skin_geom_id(self.model, "")
            check_skin_mesh(self.model, skin, asset)
            self.bones = body_ids(self.model, [str(b) for b in asset.body_names])
            self.geoms = select_object_geoms(self.model, self.bones, skin)
            if k is not None:
                models[k] = (self.model, self.bones, self.geoms)
        self.specs = [geom_spec(self.model, self.data, g) for g in self.geoms]
        self.times: list[float] = []
        self.error: str | None = None
        self.file = self.log = None  # log.csv
        self.cfile = self.counters = None  # counters.csv
        self.ffile = self.forces = None  # forces.csv (Config.two_way)

    def signature(self) -> tuple:
        """What a batch must share: the frame (time step) and the objects' geoms."""
        h = hashlib.sha1()
        for s in self.specs:
            h.update(str((int(s["gtype"]), None if s["size"] is None else np.asarray(s["size"], np.float64).tobytes(),
                          s.get("mesh_range"))).encode())
            for k in ("vertices", "faces"):
                if k in s:
                    h.update(np.ascontiguousarray(s[k]).tobytes())
        return float(self.model.opt.timestep), len(self.specs), h.hexdigest()

    def bone_poses(self):
        """(B, 3) m, (B, 4) w x y z of the bones now (SolverError if MuJoCo's state is not finite)."""
        from physhand_mj.solver import SolverError

        pos, quat = self.data.xpos[self.bones].copy(), self.data.xquat[self.bones].copy()
        ok = np.isfinite(pos).all(1) & np.isfinite(quat).all(1)
        if not ok.all():
            bad = [self.model.body(int(b)).name for b, o in zip(self.bones, ok) if not o]
            raise SolverError(f"non-finite MuJoCo pose for bones {bad}: check qpos / ctrl (NaN in data)")
        return pos, quat

    def object_poses(self):
        from physhand_mj.coupling import geom_quats

        if not self.geoms:
            return np.zeros((0, 3)), np.zeros((0, 4))
        return self.data.geom_xpos[self.geoms].copy(), geom_quats(self.data, self.geoms)


def replicated_batch(asset, scene, key, worlds: int, device: str = "cpu", spacing: float = 1.0, **config):
    """``worlds`` copies of one scene's keyframe in one :class:`~physhand_mj.batch.BatchedHands`, set up
    as a batched rollout sets up its batch (the rest placement, the settling frames without contact,
    the objects placed), to be held where the keyframe puts bones and objects (the HOI benchmarks'
    setting: Table 2's held grasp). The Config: the scene's time step, 10 substeps, ``device`` and
    the ``config`` fields. Returns (hands, (bone_pos, bone_quat, obj_pos, obj_quat)), the last four
    tiled per world: the arguments of ``hands.step`` that hold the keyframe."""
    import tempfile

    import mujoco

    import physhand_mj as ph
    from physhand_mj.batch import BatchedHands
    from physhand_mj.coupling import rest_placement

    w = int(worlds)
    run = _Run(0, scene, key, Path(tempfile.gettempdir()), asset)  # (writes nothing: no log is opened)
    mujoco.mj_kinematics(run.model, run.data)
    bone_pos, bone_quat = run.bone_poses()
    obj_pos, obj_quat = run.object_poses()
    place = rest_placement(asset, bone_pos[0], bone_quat[0])
    cfg = ph.Config(**{"frame_dt": float(run.model.opt.timestep), "substeps": 10, "device": device, **config})
    hands = BatchedHands(asset, w, cfg, np.tile(place[0], (w, 1)), np.tile(place[1], (w, 1)), objects=run.specs,
                         spacing=spacing)
    pos, quat = np.tile(bone_pos, (w, 1, 1)), np.tile(bone_quat, (w, 1, 1))
    hands.settle(pos, quat)
    op, oq = np.tile(obj_pos, (w, 1, 1)), np.tile(obj_quat, (w, 1, 1))
    hands.set_object_poses(op, oq)
    return hands, (pos, quat, op, oq)


def rollout_batched(targets, out, *, worlds: int, steps: int = 36, substeps: int = 10, contact: str = "multires",
                    device: str | None = None, config: dict | None = None, emit=None, progress: bool = True,
                    spacing: float | None = None, on_start=None, measure_every: int = 1) -> list[dict]:
    """Run each (scene, keyframe) of ``targets`` into ``out/<scene>[-<keyframe>]/``, up to ``worlds``
    runs with the same objects at once in one :class:`~physhand_mj.batch.BatchedHands`; writes
    ``out/summary.csv`` after every batch and returns the rows in the order of ``targets`` (failed
    runs carry their error, as in :func:`~physhand_mj.rollout.rollout_batch`). ``emit(row)`` is called
    for each run as its batch ends. Ctrl-C during a batch's frames ends it (its runs ``interrupted``,
    logs and skins kept) and the list; during a batch's set-up or settling (before its first frame)
    it ends the list without rows for that batch's runs. ``config.nonfinite`` must be RECOVER (each
    world is reset and reported alone). ``steps`` / ``substeps`` / ``contact`` / ``device`` / ``config`` as
    for :func:`~physhand_mj.rollout.rollout`; ``spacing``: m between worlds (BatchedHands' default: 1 m
    when they hold objects); ``on_start(hands, models, datas)`` runs once per batch after it settled,
    before its first frame (as ``rollout``'s ``on_start`` per run); ``measure_every`` as for ``rollout``
    (the object-side measure every k-th frame, 0: the last only)."""
    import physhand_mj as ph

    check_worlds(worlds)
    check_counts(steps, substeps)
    check_measure_every(measure_every)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    targets = list(targets)
    names = run_names(targets)
    rows: list[dict | None] = [None] * len(targets)
    asset = ph.load_asset()
    kw = dict(steps=steps, substeps=substeps, contact=contact, device=device, config=config, progress=progress,
              spacing=spacing, on_start=on_start, measure_every=measure_every)

    def finish(runs):
        if not runs:
            return False
        try:
            stop = _run_batch(runs, asset, rows, len(targets), **kw)
        except (ValueError, RuntimeError) as e:  # the batch could not start: each of its runs fails with it
            stop = False
            for r in runs:
                rows[r.index] = rows[r.index] or failed_row(r.scene, r.key, e)
        # free the batch's device arrays before the next batch allocates, cycles included (two W = 4096
        # batches in one process of benchmarks/batch_hoi.py ran out of an H100's 80 GB until the first
        # one's references were dropped and collected: docs/scale.md)
        gc.collect()
        for r in runs:
            if emit:
                emit(rows[r.index])
        write_summary([r for r in rows if r is not None], out)
        return stop

    try:
        for item in _grouped(targets, worlds, asset, out, names):
            if isinstance(item, list):
                if finish(item):
                    break
                continue
            i, e = item
            rows[i] = failed_row(*targets[i], e)
            if emit:
                emit(rows[i])
            write_summary([r for r in rows if r is not None], out)
    finally:
        write_summary([r for r in rows if r is not None], out)
    return [r for r in rows if r is not None]


def _grouped(targets, worlds: int, asset, out: Path, names):
    """The runs of ``targets`` in the order their batches start: yields a list of up to ``worlds``
    :class:`_Run` s with the same objects (a batch, as soon as it is full; the unfilled ones at the
    end), or ``(index, error)`` for a run whose scene could not be loaded."""
    open_batches: dict[tuple, list[_Run]] = {}
    models: dict = {}  # one compiled model per scene file
    for i, ((scene, key), name) in enumerate(zip(targets, names)):
        try:
            run = _Run(i, scene, key, out / name, asset, models)
        except (FileNotFoundError, ValueError, RuntimeError) as e:
            yield i, e
            continue
        group = open_batches.setdefault(run.signature(), [])
        group.append(run)
        if len(group) == worlds:
            del open_batches[run.signature()]
            yield group
    yield from list(open_batches.values())


def check_worlds(worlds) -> None:
    """--batch: an integer >= 1 (worlds per batch; ValueError with one line)."""
    if not (isinstance(worlds, (int, np.integer)) and worlds >= 1):
        raise ValueError(f"--batch must be an integer >= 1 (worlds per batch), got {worlds!r}")


def iter_batch_groups(targets, worlds: int, asset=None):
    """How :func:`rollout_batched` groups ``targets`` into batches, as it goes: yields the indices
    into ``targets`` of each batch (a list of up to ``worlds`` runs whose scenes hold the same
    objects) as soon as it is full (the unfilled ones at the end), in the order they run, or
    ``(index, error)`` for a run whose scene could not be loaded (it belongs to no batch). Loads
    every scene (on this machine), one at a time as the list is walked."""
    import physhand_mj as ph

    check_worlds(worlds)
    targets = list(targets)
    for item in _grouped(targets, worlds, asset or ph.load_asset(), Path("."), run_names(targets)):
        yield [r.index for r in item] if isinstance(item, list) else item


def batch_groups(targets, worlds: int, asset=None) -> tuple[list[list[int]], dict[int, Exception]]:
    """:func:`iter_batch_groups` at once: ``(groups, failed)``, ``groups`` the batches' indices in
    the order they run; ``failed``: index -> error of the runs whose scene could not be loaded."""
    groups, failed = [], {}
    for item in iter_batch_groups(targets, worlds, asset):
        if isinstance(item, list):
            groups.append(item)
        else:
            failed[item[0]] = item[1]
    return groups, failed


def _run_batch(runs: list[_Run], asset, rows: list, total: int, *, steps, substeps, contact, device, config,
               progress, spacing, on_start=None, measure_every: int = 1) -> bool:
    """One batch to its end; fills ``rows``; returns True after Ctrl-C."""
    import mujoco
    import trimesh
    from tqdm import tqdm

    from physhand_mj.batch import BatchedHands
    from physhand_mj.coupling import proxy_margin, rest_placement
    from physhand_mj.rollout import COUNTER_COLUMNS, counter_row
    from physhand_mj.solver import SolverError

    W = len(runs)
    cfg = rollout_config(runs[0].model, substeps, contact, device, config)  # (validated)
    poses, lit = [], []
    for r in runs:  # (Config.self_collision: each world's MuJoCo keeps its bones apart, as SoftHand's does)
        lit.append(len(enable_self_proxies(r.model, r.bones, cfg.self_collision and cfg.self_proxies)))
        set_proxy_margin(r.model, r.bones, proxy_margin(cfg))  # (and from objects, as SoftHand's)
        mujoco.mj_kinematics(r.model, r.data)
        poses.append(r.bone_poses())
    place = [rest_placement(asset, p[0][0], p[1][0]) for p in poses]
    k = len(runs[0].geoms)
    two_way = cfg.two_way and k > 0  # the exchange (forces.csv and the summary's keys: cfg.two_way, as serial)
    mj_side = [_TwoWaySide(r, cfg) for r in runs] if two_way else None
    hands = BatchedHands(asset, W, cfg, np.array([p for p, _ in place]), np.array([q for _, q in place]),
                         objects=runs[0].specs, spacing=spacing,
                         **(_TwoWaySide.batch_kwargs(mj_side) if two_way else {}))
    hands.settle(np.stack([p for p, _ in poses]), np.stack([q for _, q in poses]))
    if two_way and mj_side[0].names != hands.two_way.names:  # (both group the geoms by body, in order)
        raise RuntimeError(f"two-way objects {hands.two_way.names} != {mj_side[0].names}")
    if k:
        hands.set_object_poses(*(np.stack(a) for a in zip(*(r.object_poses() for r in runs))))
    if on_start is not None:
        on_start(hands, [r.model for r in runs], [r.data for r in runs])
    starts = hands.penetration()
    c = hands.solver.contact
    bones0 = bone_clearances(c, hands.state, W)
    alive = [True] * W
    last = [dict(s) for s in starts]
    interrupted = False
    for r, start in zip(runs, starts):
        r.out.mkdir(parents=True, exist_ok=True)
        r.file = open(r.out / "log.csv", "w", newline="")
        r.log = csv.writer(r.file)
        r.log.writerow(LOG_COLUMNS)
        r.log.writerow(start_row(r.data, start))
        r.file.flush()
        r.cfile = open(r.out / "counters.csv", "w", newline="")
        r.counters = csv.writer(r.cfile)
        r.counters.writerow(COUNTER_COLUMNS)
        r.cfile.flush()
        if cfg.two_way:
            r.ffile = open(r.out / "forces.csv", "w", newline="")
            r.forces = csv.writer(r.ffile)
            r.forces.writerow(FORCE_COLUMNS)
            r.ffile.flush()
    first = runs[0].index + 1
    bar = tqdm(total=steps, desc=f"batch of {W} (runs {first}-{runs[-1].index + 1} of {total})", unit="frame",
               file=sys.stderr, disable=not progress, leave=False)
    obj_frame = [0] * W  # per world: the frame the object-side values in last come from
    frame_pos = [p for p in poses]
    frame_obj = [r.object_poses() for r in runs]
    flight = None  # the frame in flight (BatchedHands.submit): (step, worlds in it, MuJoCo times, s in submit)
    frame_tw = [mj_side[w].frame_state() for w in range(W)] if two_way else None  # per world: two-way inputs

    def land(step, members, times, t_submit):
        """Frame ``step`` (in flight) ended: its measures, then each member world's nonfinite check;
        returns what its log rows need (written later, while the next frame runs)."""
        t = time.perf_counter()
        res = hands.wait()
        # the cost of one hand-frame: the host's time in the frame's submit and in waiting for it (CPU:
        # the whole frame, run inside submit; CUDA: what the host work between did not hide)
        dt = (t_submit + time.perf_counter() - t) / W
        both = hands.penetration() if measured(step, steps, measure_every) else None  # (not timed)
        subrows = c.read_metrics_worlds(synchronize=False) if c is not None else None
        counts = c.stage_counts_worlds() if c is not None else None
        touched = _touching(c, W, asset.n_skin, hands.two_way.n) if two_way else None
        logged = []
        for w in members:
            world = dict(res, **res["worlds"][w])  # the batch frame's activity, this world's measures
            if two_way:  # the skin's impulses into this world's MuJoCo before its next step
                world["forces"] = mj_side[w].apply(res["two_way"], w, touched[w])
            logged.append((w, world))
            last[w], obj_frame[w] = carry_object_side(world, both and both[w], last[w], step, obj_frame[w])
            if world["nonfinite"]:
                _fail(runs[w], SolverError(f"{world['nonfinite']} skin/flesh positions turned non-finite in frame "
                                           f"{step}"), rows)
                alive[w] = False
        return step, times, dt, both, subrows, counts, logged

    def write(step, times, dt, both, subrows, counts, logged):
        for w, world in logged:
            r = runs[w]
            r.log.writerows(frame_rows(step, _At(times[w]), cfg, None if subrows is None else subrows[w][:-1],
                                       None if counts is None else counts[w], dt, both and both[w]))
            r.counters.writerow(counter_row(step, world))
            if "forces" in world:
                r.forces.writerows([[step, round(times[w], 6), *row] for row in world["forces"]])
                r.ffile.flush()
            r.file.flush()
            r.cfile.flush()
            r.times.append(dt)

    # Pipelined (BatchedHands.submit): MuJoCo steps frame k + 1 and the log rows of frame k - 1 are
    # written while the device runs frame k. Every decision is the serial order's: a world that turns
    # non-finite in frame k keeps its frame-k poses in frame k + 1 (its MuJoCo step, taken ahead, is
    # dropped) and a MuJoCo failure of frame k + 1 counts only for worlds still alive after frame k.
    landed = None  # a frame that ended, its log rows not yet written
    done = 0  # the last frame whose log rows were all written
    try:
        for step in range(1, steps + 1):
            new, broken = {}, {}
            for w, r in enumerate(runs):
                if not alive[w]:
                    continue  # a failed world keeps its last poses: it no longer logs
                mujoco.mj_step(r.model, r.data)
                try:  # checked before it is kept: a failed world keeps its last finite poses
                    bones, obj = r.bone_poses(), r.object_poses()
                    if not (np.all(np.isfinite(obj[0])) and np.all(np.isfinite(obj[1]))):
                        raise SolverError(f"non-finite MuJoCo pose for object geoms of {Path(r.scene).name}")
                    new[w] = (bones, obj)
                except SolverError as e:
                    broken[w] = e
            times = {w: float(runs[w].data.time) for w in new}
            landed = land(*flight) if flight is not None else None  # frame step - 1
            flight = None
            for w, e in broken.items():
                if alive[w]:  # (not if frame step - 1 already failed it: the serial order never stepped it)
                    _fail(runs[w], e, rows)
                    alive[w] = False
            for w, (bones, obj) in new.items():
                if alive[w]:
                    frame_pos[w], frame_obj[w] = bones, obj
            if any(alive):
                pos, quat = np.stack([p for p, _ in frame_pos]), np.stack([q for _, q in frame_pos])
                t0 = time.perf_counter()
                if two_way:  # each world's objects and bones as its MuJoCo step left them
                    for w in new:
                        if alive[w]:
                            frame_tw[w] = mj_side[w].frame_state()
                    hands.submit(pos, quat, np.stack([o for o, _ in frame_obj]), np.stack([q for _, q in frame_obj]),
                                 **{key: np.stack([f[key] for f in frame_tw]) for key in frame_tw[0]})
                elif k:
                    hands.submit(pos, quat, np.stack([o for o, _ in frame_obj]), np.stack([q for _, q in frame_obj]))
                else:
                    hands.submit(pos, quat)
                flight = (step, [w for w in range(W) if alive[w]], times, time.perf_counter() - t0)
                if two_way:  # two-way: the frame's wrenches act on MuJoCo before its next step (no pipeline)
                    landed, flight = land(*flight), None
            if landed is not None:
                pending, landed = landed, None  # (cleared first: a stop inside write writes no row twice)
                write(*pending)
                done = pending[0]
                bar.update(1)
            if not any(alive):
                break
        if flight is not None:
            landed, flight = land(*flight), None
            pending, landed = landed, None
            write(*pending)
            done = pending[0]
            bar.update(1)
    except KeyboardInterrupt:
        interrupted = True
        # as the serial loop: a frame that ended keeps its rows (each written once), and a stop while
        # MuJoCo steps frame k + 1 comes after frame k's rows (the frame in flight ends and is
        # logged), unless the rows before it were cut short (then no world's log gets a gap)
        try:
            if landed is not None:
                pending, landed = landed, None
                write(*pending)
                done = pending[0]
            if flight is not None and flight[0] == done + 1 and hands.solver._in_flight is not None:
                pending, flight = land(*flight), None
                write(*pending)
        except KeyboardInterrupt:  # (a second Ctrl-C: stop now, with what is written)
            pass
    finally:
        bar.close()
        for r in runs:
            for f in (r.file, r.cfile, r.ffile):
                if f is not None:
                    f.close()
    d = str(hands.solver.device)
    skins = hands.skins()  # (one copy from the device for the batch)
    bones1 = bone_clearances(hands.solver.contact, hands.state, W)
    for w, r in enumerate(runs):
        if rows[r.index] is not None:  # failed: no skin, as the serial run
            continue
        skin = skins[w].astype(np.float64)
        skin_path = r.out / "skin_final.ply"
        trimesh.Trimesh(skin, asset.skin_faces, process=False).export(skin_path)
        rows[r.index] = summary_row(r.scene, r.key, r.times, substeps, contact, starts[w], last[w],
                                    bool(np.all(np.isfinite(skin))), d, interrupted, r.out / "log.csv", skin_path,
                                    object_frame=obj_frame[w], bones=(bones0[w], bones1[w]))
        if cfg.two_way:  # (as the serial two-way rollout's row)
            rows[r.index].update(two_way=True, forces=str(r.out / "forces.csv"))
        if cfg.self_collision:  # (as the serial self-collision rollout's row)
            rows[r.index].update(self_summary(hands.positions(w), asset), self_proxies=lit[w])
    hands.close()  # the batch's device memory back before the next batch allocates
    return interrupted


class _TwoWaySide:
    """Config.two_way in a batch: one world's MuJoCo side of the exchange, what SoftHand does for its
    model (coupling.object_motion / apply_impulses): the objects' and bones' state after the world's
    ``mj_step`` in (BatchTwoWay.frame_state's keywords), the frame's wrenches out into its qvel and a
    free object the skin touched at the pose the frame moved it to."""

    def __init__(self, run: _Run, cfg):
        from physhand_mj.coupling import check_two_way, free_qpos, friction_coefficients
        from physhand_mj.hand_mjcf import skin_geom_id

        check_two_way(run.model, cfg)
        self.run, self.dt = run, float(cfg.frame_dt)
        m = run.model
        firsts = {}  # each object (its geoms' body, as BatchedHands groups them) -> its first geom
        for i, spec in enumerate(run.specs):
            firsts.setdefault(spec["obj"], i)
        self.names = list(firsts)
        self.bodies = np.array([int(m.geom_bodyid[run.geoms[i]]) for i in firsts.values()], np.int64)
        self.free = free_qpos(m, self.bodies)
        index = {name: j for j, name in enumerate(firsts)}
        self.mu = friction_coefficients(m, skin_geom_id(m, ""), run.geoms, [index[s["obj"]] for s in run.specs],
                                        len(self.bodies))
        self.mass = np.where(self.free >= 0, m.body_mass[self.bodies], 0.0)
        self.inertia = m.body_inertia[self.bodies].copy()
        self._vel = None

    @staticmethod
    def batch_kwargs(sides) -> dict:
        """BatchedHands' per-world object masses, inertias and friction coefficients."""
        return dict(object_mass=np.stack([s.mass for s in sides]), object_inertia=np.stack([s.inertia for s in sides]),
                    object_friction=np.stack([s.mu for s in sides]))

    def frame_state(self) -> dict:
        """The objects' velocities ([linear, angular]: BatchTwoWay's order), centres and inertial
        frames and the bones' centres, as the world's last ``mj_step`` left them."""
        from physhand_mj.coupling import inertia_quats, object_motion

        m, d, b = self.run.model, self.run.data, self.bodies
        vel, acc = object_motion(m, d, b, self.free)  # [angular, linear]
        start = vel - acc * self.dt
        self._vel = vel
        return dict(object_vel=np.c_[vel[:, 3:], vel[:, :3]], object_vel_start=np.c_[start[:, 3:], start[:, :3]],
                    object_com=d.xipos[b].copy(), object_iquat=inertia_quats(d, b),
                    bone_com=d.xipos[self.run.bones].copy())

    def apply(self, report: dict, w: int, contacts) -> list:
        """World ``w``'s part of the batch frame's two-way ``report`` (BatchTwoWay.report) into its
        MuJoCo data; returns its forces.csv rows (without step and time)."""
        from physhand_mj.batch import BatchTwoWay
        from physhand_mj.coupling import apply_impulses

        m, d, b = self.run.model, self.run.data, self.bodies
        wrench = report["wrench"][w]
        apply_impulses(m, d, b, wrench, self.run.bones, report["bones"][w], self.dt)
        one = {key: v[w: w + 1] for key, v in report.items()}
        pos, quat = BatchTwoWay.moved_poses(one, d.xpos[b][None], d.xquat[b][None])
        for j, a in enumerate(self.free):
            if a >= 0 and np.any(wrench[j]):  # untouched: MuJoCo's own step moved it (qpos)
                d.qpos[a: a + 3], d.qpos[a + 3: a + 7] = pos[0, j], quat[0, j]
        return [[name, *(round(float(v), 6) + 0.0 for v in wrench[j, :3]), *(round(float(v), 7) + 0.0 for v in wrench[j, 3:]),
                 *(round(float(v), 6) + 0.0 for v in report["friction"][w, j]), int(contacts[j])]
                for j, name in enumerate(self.names)]


def _touching(contact, worlds: int, n_skin: int, n: int) -> np.ndarray:
    """(W, n) skin vertices of each world touching each of its ``n`` objects in the last frame
    (forces.csv's ``contacts``, as rollout.force_rows counts them): world w's skin is vertices
    [w n_skin, (w + 1) n_skin), its objects [w n, (w + 1) n)."""
    obj = contact.vertex_obj.numpy()[: worlds * n_skin]
    push = contact.push.numpy()[: worlds * n_skin] > 0
    w = np.arange(worlds * n_skin) // n_skin
    out = np.zeros((worlds, n), np.int64)
    np.add.at(out, (w[push], obj[push] - w[push] * n), 1)
    return out


class _At:
    """What :func:`~physhand_mj.rollout.frame_rows` reads of MjData (``time``, s), as it was when the
    frame's poses were taken (MuJoCo has stepped on since, the batch being pipelined)."""

    def __init__(self, t: float):
        self.time = t


def _fail(run: _Run, error: Exception, rows: list) -> None:
    """A world's run ends with ``error`` (as the serial run's exception would): its log stays."""
    rows[run.index] = failed_row(run.scene, run.key, error)
