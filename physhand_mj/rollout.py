"""Offline rollouts with penetration logging: a scene's keyframe, N frames of the soft hand, a log.

    summary = rollout("mjcf/scenes/hoi_apple.xml", keyframe="grasp", steps=36, out="out/apple")

The hand settles from its rest pose into the keyframe's pose *without* contact (so the first frame
starts from the undeformed posed skin, with the grasp's penetrations), then MuJoCo steps and the
soft hand runs ``steps`` frames with contact. Written to ``out``:

- ``log.csv`` (:data:`LOG_COLUMNS`): the user's figures, one row per substep, each the state at
  the substep's end, flushed every frame, so an interrupted run keeps what it logged; row (0, 0) is
  the settled skin before any contact.
- ``counters.csv`` (:data:`COUNTER_COLUMNS`): what each frame ran, one row per frame, for profiling.
- ``skin_final.ply``: the final skin, world frame, metres.

``contacts`` counts the skin vertices the substep's contact stage corrected in its first pass
(those in contact at its start); ``active_triangles`` the triangles its broadphase kept;
``ms_frame`` the wall time of the frame the substep belongs to (hand.step: sync, solver, write-back).
Times exclude the first frame, which compiles the contact kernels. ``object_in_skin_count`` /
``_max_um``: the second measure (object surface points inside the closed skin), taken at the end
of a frame, so on its last row (and row 0) and empty on the other rows and on frames it skips
(``measure_every``); evaluated after the frame's timing.
``counters.csv``: ``objects_near`` / ``triangles_tested`` / ``features_listed`` / ``ops_run``
(physhand_mj/solver/activity.py: objects in the work set, triangles the contact passes queried, object
feature points listed, recorded ops run) and ``feature_slack_exceeded``: 1 where a skin vertex moved
far enough in the frame, near enough to an object's feature point, that the point's list or patch
could have missed a skin triangle (Config.tuning.feature_slack, physhand_mj/contact/slack.py), else 0;
empty without feature points.
- ``forces.csv`` (:data:`FORCE_COLUMNS`; with ``Config.two_way`` only, ``physhand rollout --two-way``):
  per frame and object what the skin applied to it (``SoftHand.applied_wrenches``): the mean force
  (N) and torque about its centre of mass (N m) over the frame, world frame, and the force's friction
  part (N); ``contacts``: the skin vertices the contact moved against it in that frame.
"""

from __future__ import annotations

import contextlib
import csv
import math
import signal
import threading
import time
from pathlib import Path

import numpy as np

LOG_COLUMNS = ["step", "substep", "time_s", "penetration_count", "penetration_max_um", "penetration_avg_um",
               "contacts", "active_triangles", "ms_frame", "object_in_skin_count", "object_in_skin_max_um"]
COUNTER_COLUMNS = ["step", "objects_near", "triangles_tested", "features_listed", "ops_run",
                   "feature_slack_exceeded"]  # counters.csv: what a frame ran (physhand_mj/solver/activity.py)
# forces.csv (Config.two_way): what the skin applied to each object, per frame
FORCE_COLUMNS = ["step", "time_s", "object", "force_x_n", "force_y_n", "force_z_n", "torque_x_nm", "torque_y_nm",
                 "torque_z_nm", "friction_x_n", "friction_y_n", "friction_z_n", "contacts"]


def load_scene(scene, keyframe: str | None = None, model=None):
    """(model, data, keyframe name or None) with the keyframe applied and kinematics run. Raises
    FileNotFoundError / ValueError with one line that says what to fix. ``model``: the scene's
    MjModel compiled before (batched rollouts share one per scene file); a new MjData either way."""
    import mujoco

    path = Path(scene)
    if not path.is_file():
        raise FileNotFoundError(f"scene file not found: {path}")
    if model is None:
        try:
            model = mujoco.MjModel.from_xml_path(str(path))
        except ValueError as e:
            first = " ".join(str(e).split())[:300]
            raise ValueError(f"malformed MJCF {path}: {first}") from None
    data = mujoco.MjData(model)
    names = [model.key(k).name for k in range(model.nkey)]
    if keyframe is not None:
        if keyframe not in names:
            raise ValueError(f"unknown keyframe '{keyframe}' in {path.name}; it has: {', '.join(names) or 'none'}")
        mujoco.mj_resetDataKeyframe(model, data, names.index(keyframe))
    elif names:
        keyframe = names[0]
        mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    return model, data, keyframe


def rollout(scene, keyframe: str | None = None, *, steps: int = 36, substeps: int = 10, contact: str = "multires",
            device: str | None = None, out=None, progress: bool = True, hand_kwargs: dict | None = None,
            on_start=None, on_end=None, config: dict | None = None, measure_every: int = 1) -> dict:
    """Run one rollout (see the module docstring); returns the summary dict. Ctrl-C ends it early
    with ``interrupted: true`` and everything logged so far. ``on_start(hand, model, data)`` runs on
    the settled, undeformed hand before the first frame, ``on_end(...)`` after the last (pictures).
    ``config``: further :class:`~physhand_mj.Config` fields (SI units), e.g. ``{"contact_passes": 4}``.
    ``measure_every``: the object-side measure (object points inside the skin) every k-th frame
    (count; 0: the last frame only; its log cells are empty on the frames between); the last
    frame is always measured, so the summary of a run that ends is the same. The summary's
    ``object_in_skin_frame`` says which frame its object-side values come from (0: the settled
    start): the last frame, or for a run stopped early the last frame measured before it stopped
    (nothing is measured after a Ctrl-C, which may land inside a frame)."""
    import mujoco
    import trimesh
    from tqdm import tqdm

    import physhand_mj as ph
    from physhand_mj.solver import SolverError

    check_counts(steps, substeps)
    check_measure_every(measure_every)
    model, data, key = load_rollout_scene(scene, keyframe)
    cfg = rollout_config(model, substeps, contact, device, config)
    hand = ph.SoftHand(model, data, cfg, settle_contact=False, **(hand_kwargs or {}))
    out = Path(out) if out is not None else Path("rollout_out")
    out.mkdir(parents=True, exist_ok=True)
    log_path, skin_path, counters_path = out / "log.csv", out / "skin_final.ply", out / "counters.csv"
    start = hand.penetration()
    bones0 = bone_clearances(hand.solver.contact, hand.state)[0]
    if on_start is not None:
        on_start(hand, model, data)
    times: list[float] = []
    interrupted = False
    last = dict(start)
    obj_frame = 0  # the frame the object-side values in last come from
    forces_path = out / "forces.csv" if cfg.two_way else None
    with open(log_path, "w", newline="") as f, open(counters_path, "w", newline="") as fc, \
            (open(forces_path, "w", newline="") if forces_path else contextlib.nullcontext()) as ff:
        log, counters = csv.writer(f), csv.writer(fc)
        forces = csv.writer(ff) if ff is not None else None
        if forces is not None:
            forces.writerow(FORCE_COLUMNS)
        log.writerow(LOG_COLUMNS)
        log.writerow(start_row(data, start))
        counters.writerow(COUNTER_COLUMNS)
        f.flush()
        fc.flush()
        bar = tqdm(total=steps, desc=f"rollout {Path(scene).stem}", unit="frame", disable=not progress, leave=False)
        try:
            for step in range(1, steps + 1):
                mujoco.mj_step(model, data)
                t = time.perf_counter()
                res = hand.step()
                dt = time.perf_counter() - t
                both = hand.penetration() if measured(step, steps, measure_every) else None  # (not timed)
                rows = getattr(hand.solver, "substep_metrics", None)
                counts = hand.solver.contact.stage_counts() if hand.solver.contact is not None else None
                frame = frame_rows(step, data, cfg, rows, counts, dt, both)
                with whole_frame():  # a frame's rows and its count go out together: an interrupted log holds whole frames
                    log.writerows(frame)
                    counters.writerow(counter_row(step, res))
                    if forces is not None:
                        forces.writerows(force_rows(step, data, hand))
                        ff.flush()
                    f.flush()
                    fc.flush()
                    times.append(dt)
                    last, obj_frame = carry_object_side(res, both, last, step, obj_frame)
                bar.update(1)
                if res["nonfinite"]:
                    raise SolverError(f"{res['nonfinite']} skin/flesh positions turned non-finite in frame {step}")
        except KeyboardInterrupt:
            interrupted = True
        finally:
            bar.close()
    trimesh.Trimesh(hand.skin_vertices, hand.asset.skin_faces, process=False).export(skin_path)
    if on_end is not None:
        on_end(hand, model, data)
    m = hand.metrics()
    row = summary_row(scene, key, times, substeps, contact, start, last, bool(m["finite"]), str(hand.solver.device),
                      interrupted, log_path, skin_path, object_frame=obj_frame,
                      bones=(bones0, bone_clearances(hand.solver.contact, hand.state)[0]))
    if forces_path is not None:  # (two-way runs only: the default summary keeps its keys)
        row.update(two_way=True, forces=str(forces_path))
    if cfg.self_collision:  # (self-collision runs only, as two_way's keys)
        row.update(self_summary(hand.state.x.numpy(), hand.asset), self_proxies=int(len(hand.self_proxies)))
    return row


def self_summary(x, asset) -> dict:
    """Config.self_collision: the summary's skin-on-skin figures from the final positions ``x`` (all
    vertices, skin first), by the independent measure (contact/self_measures.py, code the self-contact
    stage does not share): ``self_inside_200um`` / ``self_inside_1000um`` (skin vertices whose 0.2 / 1
    mm outward offset lies inside the closed skin), ``self_buried_200um`` (skin vertices with no point
    outside the closed skin 0.2 mm around them in any sampled direction: no normal involved, so the
    bottoms of closed creases do not count), ``self_crossing_edges`` (skin edges through another skin
    triangle), ``self_crossing_depth_max_um`` (how far the deepest of them pokes through) and
    ``inverted_tets``."""
    from physhand_mj.contact.self_measures import self_penetration

    m = self_penetration(np.asarray(x, float), np.asarray(asset.skin_faces), np.asarray(asset.tets),
                         np.asarray(asset.positions, float), buried=2e-4)
    return dict(self_collision=True, self_inside_200um=m["inside_200um"], self_inside_1000um=m["inside_1000um"],
                self_buried_200um=m["buried_200um"], self_crossing_edges=m["crossing_edges"],
                self_crossing_depth_max_um=m["crossing_depth_max_um"], inverted_tets=m["inverted_tets"])


def force_rows(step: int, data, hand) -> list:
    """A two-way frame's forces.csv rows (:data:`FORCE_COLUMNS`), one per object."""
    c = hand.solver.contact
    if c is None:
        return []
    n = hand.asset.n_skin
    touched = c.vertex_obj.numpy()[:n][c.push.numpy()[:n] > 0]
    rows = []
    for k, (name, w) in enumerate(hand.applied_wrenches().items()):
        rows.append([step, round(float(data.time), 6), name, *(round(float(v), 6) + 0.0 for v in w["force"]),
                     *(round(float(v), 7) + 0.0 for v in w["torque"]), *(round(float(v), 6) + 0.0 for v in w["friction"]),
                     int(np.count_nonzero(touched == k))])
    return rows


def bone_clearances(contact, state, worlds: int = 1) -> list:
    """Per world the bones' least clearance from its objects now (mm, 50 at most; negative: a bone
    that deep inside an object, where no penetration-free skin exists: contact/bones.py); None
    without contact."""
    if contact is None:
        return [None] * worlds
    from physhand_mj.contact.bones import world_clearances

    c = world_clearances(contact.model, contact.objects, state.x, contact.geoms_per_world)
    return [round(float(v) * 1e3, 4) for v in c[:worlds]]


@contextlib.contextmanager
def whole_frame():
    """Ctrl-C held back until the block ends: a frame's log rows and the summary's frame count are
    kept together (a stop between the two wrote one frame more than the summary counted). Ctrl-C and
    Ray's cancel (``ray.cancel``, which raises through the same SIGINT handler) arrive as Python's
    SIGINT handler; outside the main thread, where no handler can be set, the block runs as is."""
    old = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or not callable(old):
        yield
        return
    caught = []
    signal.signal(signal.SIGINT, lambda *a: caught.append(a))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if caught:
        old(*caught[0])  # (the handler that was there: Python's default raises KeyboardInterrupt)


def carry_object_side(res: dict, both: dict | None, last: dict, step: int, frame: int) -> tuple[dict, int]:
    """The rollout's running ``last`` after frame ``step``: what the frame ran (``res``) with the
    object side of its measure ``both`` (None: not measured this frame; then the frame's own
    metrics row where ``res`` has one, Config.object_metrics, else the last measured values), and
    the frame those object-side values come from."""
    if both is not None:
        return dict(res, **{k: v for k, v in both.items() if k.startswith("object_in_skin")}), step
    if "object_in_skin_count" in res:
        return dict(res), step
    return dict(res, **{k: v for k, v in last.items() if k.startswith("object_in_skin")}), frame


def check_measure_every(k) -> None:
    """--measure-every: an integer >= 0 (frames; 0: the last frame only)."""
    if not (isinstance(k, (int, np.integer)) and not isinstance(k, bool) and k >= 0):
        raise ValueError(f"--measure-every must be an integer >= 0 (frames; 0: the last only), got {k!r}")


def measured(step: int, steps: int, every: int) -> bool:
    """Whether frame ``step`` (1-based) of ``steps`` gets the object-side measure (--measure-every)."""
    return step == steps or (every > 0 and step % every == 0)


def check_counts(steps: int, substeps: int) -> None:
    """--steps and --substeps: at least 1 each (ValueError with one line)."""
    if steps < 1 or substeps < 1:
        raise ValueError(f"--steps and --substeps must be at least 1, got {steps} and {substeps}")


def load_rollout_scene(scene, keyframe: str | None = None, model=None):
    """:func:`load_scene`, and a SolverError when the keyframe holds non-finite qpos or ctrl."""
    from physhand_mj.solver import SolverError

    model, data, key = load_scene(scene, keyframe, model)
    if not (np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.ctrl))):
        raise SolverError(f"keyframe '{key}' of {Path(scene).name} holds non-finite qpos or ctrl")
    return model, data, key


def rollout_config(model, substeps: int, contact: str, device, config: dict | None = None):
    """The rollout's validated :class:`~physhand_mj.Settings`: the scene's time step as the frame,
    per-substep metrics on (the log), ``config``'s further options (any group's, ``Config.from_dict``)."""
    import physhand_mj as ph
    from physhand_mj.types import Strategy

    if not (config or {}).get("frame_metrics", True):
        raise ValueError("a rollout logs every frame's skin measure: leave Config.frame_metrics on (use "
                         "BatchedHands or Solver directly to run frames without it)")
    # (validated once: the log reads substep_dt every row; config may name any group's options)
    return ph.Config.from_dict(dict(frame_dt=float(model.opt.timestep), substeps=substeps,
                                    contact=Strategy[contact.upper()], device=device, substep_metrics=True,
                                    **(config or {}))).validate()


def start_row(data, start: dict) -> list:
    """The log's row (0, 0): the settled skin before any contact, both measures."""
    return [0, 0, round(float(data.time), 6), start["penetration_count"], _um(start["penetration_max_um"]),
            _um(start["penetration_avg_um"]), 0, 0, 0.0, start["object_in_skin_count"],
            _um(start["object_in_skin_max_um"])]


def counter_row(step: int, res: dict) -> list:
    """A frame's counters.csv row: what the frame ran, from ``res`` (``Solver.step``'s dict)."""
    return [step, *(res.get(k, "") for k in COUNTER_COLUMNS[1:])]


def frame_rows(step: int, data, cfg, rows, counts, dt: float, both: dict) -> list:
    """A frame's log rows, one per substep: ``rows`` (substeps, >= 3) the substeps' metrics rows
    (count, sum depth m, max depth m; None: no contact), ``counts`` (stages, 2) the contact stages'
    [active triangles, corrected vertices] (None: no contact), ``dt`` the frame's wall time (s) and
    ``both`` the frame end's two measures (summarized; None: not measured, its cells empty), whose
    object side goes on the frame's last row: it is the state at the frame's end."""
    lines = []
    for s in range(cfg.substeps):
        cnt, total, deepest = rows[s][:3] if rows is not None else (0.0, 0.0, 0.0)
        n = int(round(float(cnt)))
        act, con = (int(counts[s, 0]), int(counts[s, 1])) if counts is not None and s < len(counts) else (0, 0)
        lines.append([step, s + 1, round(float(data.time) - cfg.frame_dt + (s + 1) * cfg.substep_dt, 6), n,
                      _um(deepest * 1e6), _um(total / n * 1e6 if n else 0.0), con, act, round(dt * 1e3, 3),
                      *((both["object_in_skin_count"], _um(both["object_in_skin_max_um"]))
                        if both and s + 1 == cfg.substeps else ("", ""))])
    return lines


def summary_row(scene, key, times, substeps: int, contact: str, start: dict, last: dict, finite: bool, device: str,
                interrupted: bool, log_path, skin_path, object_frame: int | None = None, bones=(None, None)) -> dict:
    """A rollout's summary: ``times`` the frames' wall times (s; the first, which compiles, is not
    counted), ``start`` / ``last`` the measures before the first and after the last frame;
    ``object_frame``: the frame ``last``'s object-side values come from (default: the last);
    ``bones``: the bones' least clearance from the objects (mm) before the first and after the last
    frame (:func:`bone_clearances`)."""
    from physhand_mj.launch import device_name

    timed = times[1:] if len(times) > 1 else times
    d = device
    return dict(scene=str(scene), keyframe=key, steps=len(times), substeps=substeps, contact=contact,
                penetration_count=int(last.get("penetration_count", 0)),
                penetration_max_um=_um(last.get("penetration_max_um", 0.0)),
                penetration_avg_um=_um(last.get("penetration_avg_um", 0.0)),
                object_in_skin_count=int(last.get("object_in_skin_count", 0)),
                object_in_skin_max_um=_um(last.get("object_in_skin_max_um", 0.0)),
                object_in_skin_avg_um=_um(last.get("object_in_skin_avg_um", 0.0)),
                object_in_skin_frame=len(times) if object_frame is None else int(object_frame),
                initial_penetration_count=start["penetration_count"],
                initial_penetration_max_um=_um(start["penetration_max_um"]),
                initial_object_in_skin_count=start["object_in_skin_count"],
                initial_object_in_skin_max_um=_um(start["object_in_skin_max_um"]),
                initial_bone_clearance_mm=bones[0], bone_clearance_mm=bones[1],
                ms_per_frame=round(1e3 * float(np.mean(timed)), 3) if timed else math.nan,
                finite=finite and int(last.get("nonfinite", 0)) == 0, device=d, device_name=device_name(d),
                interrupted=interrupted, log=str(log_path), skin=str(skin_path))


def _um(v: float) -> float:
    return round(float(v), 4)


def batch_targets(source, keyframe: str | None = None) -> list[tuple[Path, str | None]]:
    """(scene, keyframe) pairs of a batch: a folder (every *.xml; each with ``keyframe`` if given,
    else all its keyframes) or a list file (lines ``SCENE.xml [KEYFRAME]``, relative to the file,
    ``#`` comments)."""
    import mujoco

    src = Path(source)
    if src.is_dir():
        out = []
        for xml in sorted(src.glob("*.xml")):
            if keyframe is not None:
                out.append((xml, keyframe))
                continue
            try:
                m = mujoco.MjModel.from_xml_path(str(xml))
                keys = [m.key(k).name for k in range(m.nkey)] or [None]
            except ValueError:
                keys = [None]  # the run reports the malformed file
            out += [(xml, k) for k in keys]
        if not out:
            raise ValueError(f"no *.xml scenes in folder {src}")
        return out
    if not src.is_file():
        raise FileNotFoundError(f"scene file, folder or list not found: {src}")
    out = []
    for line in src.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            parts = line.split()
            out.append(((src.parent / parts[0]).resolve(), parts[1] if len(parts) > 1 else keyframe))
    if not out:
        raise ValueError(f"list file {src} names no scenes")
    return out


SUMMARY_COLUMNS = ["scene", "keyframe", "steps", "contact", "initial_penetration_count", "initial_penetration_max_um",
                   "penetration_count", "penetration_max_um", "penetration_avg_um", "initial_object_in_skin_count",
                   "object_in_skin_count", "object_in_skin_max_um", "initial_bone_clearance_mm",
                   "bone_clearance_mm", "ms_per_frame", "finite", "device",
                   "interrupted", "error"]  # the columns of a batch's summary.csv, one row per run


def run_names(targets) -> list[str]:
    """The run folder names of a batch, in order: ``<scene>[-<keyframe>]``, and ``-<index>`` after a
    name already taken (the same scene name from two folders: keep both)."""
    names, used = [], set()
    for i, (scene, key) in enumerate(targets):
        name = Path(scene).stem + (f"-{key}" if key else "")
        if name in used:
            name = f"{name}-{i}"
        used.add(name)
        names.append(name)
    return names


def failed_row(scene, keyframe, error) -> dict:
    """The summary row of a run that failed: its scene, keyframe and the error on one line."""
    return dict(scene=str(scene), keyframe=keyframe, error=" ".join(str(error).split()), finite=False)


def write_summary(rows, out) -> Path:
    """Write ``out/summary.csv`` (:data:`SUMMARY_COLUMNS`, one row per run); returns its path. It is
    written under a temporary name and renamed: the table on disk is always a whole one."""
    path = Path(out) / "summary.csv"
    tmp = path.with_name("summary.csv.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    tmp.replace(path)
    return path


def rollout_batch(targets, out, *, emit=None, **kwargs) -> list[dict]:
    """Run each (scene, keyframe) into ``out/<scene>[-<keyframe>]/``; writes ``out/summary.csv``
    (one row per run; failed runs carry their error). ``emit(summary)`` is called after each run.
    Ctrl-C stops the batch after the current run's partial log. On a Ray cluster:
    :func:`physhand_mj.distributed.rollout_ray`."""
    check_counts(kwargs.get("steps", 36), kwargs.get("substeps", 10))  # (once, not as a failed row per run)
    check_measure_every(kwargs.get("measure_every", 1))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    targets = list(targets)
    rows = []
    for (scene, key), name in zip(targets, run_names(targets)):
        try:
            res = rollout(scene, key, out=out / name, **kwargs)
        except (FileNotFoundError, ValueError, RuntimeError) as e:
            res = failed_row(scene, key, e)
        rows.append(res)
        if emit:
            emit(res)
        write_summary(rows, out)
        if res.get("interrupted"):
            break
    return rows
