"""Benchmarks behind ``physhand bench``: figures as dicts, timings that exclude compilation.

Timings are wall-clock per frame after two warm-up frames (the first compiles the kernels, the
second captures the CUDA graph on GPUs), synchronised with the device every frame.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from physhand_mj.bench.cases import CONE, SHEET
from physhand_mj.launch import device_name

CACHE = Path(os.environ.get("PHYSHAND_CACHE", Path.home() / ".cache" / "physhand_mj"))

def hand_asset(resolution: int | None = None, asset_path: str | Path | None = None):
    """The embedded hand, an asset file, or the MyoHand rebuilt with ``resolution`` skin vertices
    (cached under $PHYSHAND_CACHE; building needs the ``build`` extra)."""
    from physhand_mj.asset import load_asset

    if asset_path is not None:
        return load_asset(asset_path)
    asset = load_asset()
    if resolution is None or resolution == asset.n_skin:
        return asset
    if resolution < 500:
        raise ValueError(f"--resolution is a skin vertex count (>= 500), got {resolution}")
    path = CACHE / f"myohand_skin{resolution}.npz"
    if not path.exists():
        try:
            from physhand_mj.build import build_myohand
        except ImportError as e:
            raise ImportError(f"building a {resolution}-vertex hand needs the build extra "
                              f"(pip install -e '.[build]'): {e}") from e
        skeleton = max(3300, int(round(3300 * resolution / 5000)))
        build_myohand(path, None, skin_vertices=resolution, skeleton_vertices=skeleton)
    return load_asset(path)


def bench_solver(device: str = "cpu", frames: int = 100, resolution: int | None = None, asset_path=None,
                 **config) -> dict:
    """Time the XPBD frame on the hand in its open pose, palm down under gravity, no contact.

    ``ms_per_frame`` is a whole ``Solver.set_body_poses`` + ``Solver.step`` (pose upload, the frame,
    guard read-back, synchronisation); on CUDA ``graph_ms_per_frame`` is the captured frame alone,
    replayed back to back (the GPU's cost without the per-frame host round trip)."""
    import warp as wp

    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
    from physhand_mj.solver import Solver, make_model
    from physhand_mj.types import Config

    if frames < 1:
        raise ValueError(f"--steps must be >= 1, got {frames}")
    wp.init()
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ValueError("--device cuda: no CUDA device is visible to Warp on this machine")
    asset = hand_asset(resolution, asset_path)
    _, model, data = open_hand_scene("hand_only", "open")  # MuJoCo bones: the same for every resolution
    ids = body_ids(model, asset.body_names)
    cfg = Config.from_dict({"device": device, "sleep_speed": 0.0, **config}).validate()  # awake: a still hand sleeps
    t0 = time.perf_counter()
    solver = Solver(make_model(asset, cfg), cfg)
    state = solver.make_state(*mount_pose(model, data))
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    setup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(2):
        solver.set_body_poses(state, *poses)
        solver.step(state)
    warmup_s = time.perf_counter() - t0
    times, guard = [], {}
    for _ in range(frames):
        t = time.perf_counter()
        solver.set_body_poses(state, *poses)
        guard = solver.step(state)
        times.append(time.perf_counter() - t)
    ms = np.asarray(times) * 1e3
    device_ms = None
    graph = solver.last_graph
    if graph is not None:  # GPU cost only: the captured frame replayed back to back, one sync
        wp.synchronize_device(solver.device)
        t = time.perf_counter()
        for _ in range(frames):
            wp.capture_launch(graph)
        wp.synchronize_device(solver.device)
        device_ms = round((time.perf_counter() - t) / frames * 1e3, 4)
    m = solver.model
    return dict(
        command="bench solver", ms_per_frame=round(float(ms.mean()), 4), ms_per_frame_median=round(float(np.median(ms)), 4),
        ms_per_frame_min=round(float(ms.min()), 4), graph_ms_per_frame=device_ms, frames=frames, frame_dt_s=cfg.frame_dt,
        substeps=cfg.substeps, iterations=cfg.iterations, scheme=cfg.scheme.name.lower(),
        fused_substep=solver.fused_substep, vertices=m.n_vertices, skin_vertices=m.n_skin, tets=int(m.tet_ids.shape[0]),
        edges=int((~m.edge_is_att).sum()), attachments=int(m.edge_is_att.sum()), dihedrals=int(m.dih_ids.shape[0]),
        device=str(solver.device), device_name=device_name(str(solver.device)),
        cuda_graph=solver._capturable(), setup_s=round(setup_s, 3), warmup_s=round(warmup_s, 3),
        nonfinite=guard.get("nonfinite", 0), inverted=guard.get("inverted", 0), ops_run=guard.get("ops_run"),
    )




def bench_cone(contact: str = "multires", device: str = "cpu", steps: int = 30, substeps: int = 10,
               **config) -> dict:
    """The paper's cone experiment (section 4.2): a 2,400-vertex sheet with edge and smoothness
    constraints falls on an analytic cone; 5 ms steps of 10 substeps; after every substep the 21
    lattice samples per triangle are checked. Returns the summary and the per-substep log."""
    import warp as wp

    from physhand_mj.bodies import sheet
    from physhand_mj.contact import Objects
    from physhand_mj.solver import Solver, make_model
    from physhand_mj.types import Config, GeomType, Strategy

    if steps < 1:
        raise ValueError(f"--steps must be >= 1, got {steps}")
    wp.init()
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ValueError("--device cuda: no CUDA device is visible to Warp on this machine")
    try:
        strategy = Strategy[contact.upper()]
    except KeyError:
        raise ValueError(f"--contact must be vertex, opt or multires, got {contact!r}") from None
    body = sheet(**SHEET)
    # the paper's sheet: edges and smoothness only (no tets, no bones)
    cfg = Config.from_dict(dict(device=device, substeps=substeps, contact=strategy, edge_compliance_skin=1.0e-6,
                                smooth_compliance=10.0, damping=0.0, substep_metrics=True, volumes=False,
                                attachment=False, **config)).validate()
    objects = Objects(str(wp.get_device(device)), 1)
    objects.add(GeomType.CONE, [CONE["radius"], CONE["height"]], name="cone")
    solver = Solver(make_model(body, cfg), cfg, objects=objects)
    state = solver.make_state()
    solver.step(solver.make_state())  # compile (and capture) on a scratch state: timing excludes it
    log, times = [], []
    for step in range(steps):
        t = time.perf_counter()
        out = solver.step(state)
        times.append(time.perf_counter() - t)
        for s, row in enumerate(solver.substep_metrics):
            count = int(round(row[0]))
            log.append(dict(step=step, substep=s, penetration_count=count, penetration_max_um=float(row[2]) * 1e6,
                            penetration_avg_um=float(row[1]) / count * 1e6 if count else 0.0))
    counts = [r["penetration_count"] for r in log]
    return dict(
        command="bench cone", contact=strategy.name.lower(), penetration_count_final=log[-1]["penetration_count"],
        penetration_count_max=int(max(counts)), penetration_count_mean=round(float(np.mean(counts)), 3),
        penetration_avg_um_final=round(log[-1]["penetration_avg_um"], 4),
        penetration_max_um_final=round(log[-1]["penetration_max_um"], 4),
        penetration_max_um_all=round(max(r["penetration_max_um"] for r in log), 4),
        ms_per_step=round(float(np.median(times)) * 1e3, 3), steps=steps, substeps=substeps,
        vertices=body.n_vertices, triangles=len(body.skin_faces), queries=_queries(cfg),
        contact_passes=cfg.contact_passes, placement=cfg.contact_placement.name.lower(),
        device=str(solver.device), device_name=device_name(str(solver.device)), finite=bool(out["nonfinite"] == 0),
    ), log


def _queries(cfg) -> int:
    from physhand_mj.types import Strategy

    if cfg.contact == Strategy.VERTEX:
        return 6
    if cfg.contact == Strategy.OPT:
        return cfg.opt_queries
    return cfg.multires_samples * cfg.multires_rounds


def bench_accuracy(device: str = "cpu", out="accuracy_out", quick: bool = False, frames: int | None = None,
                   repeats: int | None = None, workloads=None, progress=None) -> dict:
    """What accuracy costs in time (physhand_mj/bench/accuracy.py): every swept contact setting on the HOI
    grasps, hard cases, held-out cases and the paper's cone; writes ``out/accuracy_<device>.csv`` (one row per setting and workload),
    ``.json`` (the rows, one row per setting with its Pareto flags, the device) and ``.png`` (the
    Pareto fronts). ``quick``: 2 settings, 3 workloads, 2 frames, 1 repeat (a smoke run)."""
    import warp as wp

    from physhand_mj.bench import accuracy as acc

    wp.init()
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ValueError("--device cuda: no CUDA device is visible to Warp on this machine")
    frames = frames if frames is not None else (2 if quick else 20)
    repeats = repeats if repeats is not None else (1 if quick else 2)
    if repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {repeats}")
    workloads = tuple(workloads) if workloads else (acc.QUICK_WORKLOADS if quick else acc.WORKLOADS)
    points = acc.sweep_points(quick)
    t0 = time.perf_counter()
    rows = acc.run_sweep(points, workloads, device=device, frames=frames, repeats=repeats, progress=progress)
    dev = str(wp.get_device(device))
    import physhand_mj as ph

    asset = ph.load_asset()
    heldout = {}  # what each held-out workload is, and whether a penetration-free skin exists there
    for w in workloads:
        if w.startswith("heldout:"):
            h = acc.heldout_case(w[len("heldout:"):], asset)
            heldout[w] = dict(case=h.label, kind=h.kind, clearance_mm=round(h.clearance_mm, 3), feasible=h.feasible)
    out = write_sweep(out, dev, frames, repeats, workloads, heldout, points, rows)
    return dict(out, seconds=round(time.perf_counter() - t0, 1))


def write_sweep(out, dev: str, frames: int, repeats: int, workloads, heldout: dict, points, rows,
                device_label: str | None = None) -> dict:
    """Write a sweep's ``out/accuracy_<device>.csv`` (one row per setting and workload), ``.json``
    (the rows, one row per setting with its Pareto flags, the device) and ``.png`` (the Pareto
    fronts) from its ``rows`` (accuracy.run_sweep's, or several runs' joined:
    benchmarks/accuracy_merge.py); returns the summary line (the front, ``Config()``'s place, the
    cheapest settings at zero, the paths). ``device_label``: the device's name where the rows were not
    run on this machine (default: this machine's, ``launch.device_name``)."""
    import csv
    import json

    from physhand_mj.bench import accuracy as acc
    from physhand_mj.types import Config

    table = acc.summarize_points(points, rows)
    tag = dev.split(":")[0]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    csv_path, json_path, png_path = (out / f"accuracy_{tag}.{e}" for e in ("csv", "json", "png"))
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=acc.ROW_COLUMNS)
        w.writeheader()
        w.writerows(rows)
    name = device_label or device_name(dev)
    json_path.write_text(json.dumps(dict(device=dev, device_name=name, frames=frames, repeats=repeats,
                                         workloads=list(workloads), hold_frames=acc.HOLD, heldout=heldout,
                                         points=table, rows=rows),
                                    indent=1))
    acc.plot_front(table, png_path, f"physhand bench accuracy: {len(points)} settings x {len(workloads)} workloads, "
                                    f"{frames} frames, {name}")
    default = next((p for p in table if p["default"]), None)
    front = [dict(point=p["point"], ms_per_frame=p["ms_per_frame"], skin_um=p["skin_um"], object_um=p["object_um"])
             for p in sorted(table, key=lambda p: p["ms_per_frame"]) if p["pareto_both"]]
    # the fastest setting at zero by every measure: of all, and of those at Config()'s substeps (its material)
    zero = {k: (None if p is None else dict(point=p["point"], ms_per_frame=p["ms_per_frame"]))
            for k, p in (("any", acc.cheapest_zero(table)),
                         ("default_substeps", acc.cheapest_zero(table, substeps=Config().substeps)))}
    return dict(command="bench accuracy", device=dev, device_name=name, points=len(points), workloads=list(workloads),
                frames=frames, repeats=repeats, pareto=front, cheapest_zero=zero,
                default_on_front=None if default is None else dict(skin=default["pareto_skin"],
                                                                   object=default["pareto_object"],
                                                                   both=default["pareto_both"]),
                csv=str(csv_path), json=str(json_path), plot=str(png_path))
