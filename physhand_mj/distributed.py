"""The rollouts of a batch spread over the workers of a Ray cluster: one Ray task per rollout.

    from physhand_mj.rollout import batch_targets
    from physhand_mj.distributed import rollout_ray
    rows = rollout_ray(batch_targets("runs.txt"), "out/batch", address="auto", steps=36)

Each task runs :func:`physhand_mj.rollout.rollout` (``progress=False``) for one (scene, keyframe)
into the folder :func:`~physhand_mj.rollout.rollout_batch` would use, ``out/<scene>[-<keyframe>]/``,
and the driver writes ``out/summary.csv`` (and ``summary.parquet`` when pyarrow is importable) with
the serial batch's columns after every finished run. A worker on the driver's node writes its run
folder in place; a worker on another node runs into a temporary folder and sends the files back,
so the outputs land in one folder on the driver either way (scene files must be readable at the
same path on every node). Each task runs one hand: batched worlds (several hands in one solver
step, physhand_mj/batch_rollout.py) run on one machine and do not combine with Ray yet.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

from physhand_mj.rollout import SUMMARY_COLUMNS, failed_row, run_names, write_summary

CANCEL_GRACE_S = 30.0  # after Ctrl-C: how long the driver waits for the cancelled runs' partial summaries


def rollout_ray(targets, out, *, address: str | None = None, num_workers: int | None = None,
                gpus_per_worker: float | None = None, max_retries: int = 2, emit=None, progress: bool = True,
                **rollout_kwargs) -> list[dict]:
    """Run each (scene, keyframe) of ``targets`` as one Ray task; returns the summary rows in the
    order of ``targets``.

    ``address``: a Ray cluster (``"auto"``, ``"ray://HOST:10001"``, ``"HOST:6379"``); ``None`` starts
    a local Ray (shut down again at the end). An already-initialised Ray is reused as it is.
    ``num_workers``: rollouts running at once (count; default: as many as the cluster's resources
    allow). ``gpus_per_worker``: GPUs per task (default 1 when the cluster has GPUs, else 0: CPU
    tasks of 1 CPU each); the device defaults to ``"cuda"`` for GPU tasks, ``"cpu"`` otherwise.
    ``max_retries``: reruns of a task whose worker died or that raised an unexpected exception;
    after them the run is a failed row with its error. Bad input (missing scene, unknown keyframe,
    a diverging solver) fails at once, as in the serial batch. ``emit(row)`` is called after each
    finished run, in the order they finish; ``progress``: a progress bar on stderr.
    ``rollout_kwargs``: :func:`~physhand_mj.rollout.rollout`'s options (steps, substeps, contact,
    device, config, ...).

    Ctrl-C cancels the tasks (a running one stops after its frame, keeping its partial log, as a
    serial rollout does), writes the summary and returns: runs that did not finish have
    ``interrupted: true`` (those that never gave a summary also ``error: "cancelled (Ctrl-C)"``).
    """
    try:
        import ray
    except ImportError:
        raise ImportError('Ray is not installed: pip install -e ".[ray]"') from None
    from tqdm import tqdm

    if num_workers is not None and num_workers < 1:
        raise ValueError(f"num_workers (--workers) must be at least 1, got {num_workers}")
    if max_retries < 0:
        raise ValueError(f"max_retries must be >= 0, got {max_retries}")
    targets = [(scene, key) for scene, key in targets]
    out_user = Path(out)
    out_abs = out_user.resolve()
    out_abs.mkdir(parents=True, exist_ok=True)
    names = run_names(targets)
    rollout_kwargs.pop("progress", None)
    started = not ray.is_initialized()
    if started:
        import logging

        # workers' own output (Warp's banner, ...) stays in Ray's session logs: stdout keeps one JSON line a run
        local = {} if address is not None else dict(include_dashboard=False)
        ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR, **local)
    rows: list[dict | None] = [None] * len(targets)
    try:
        gpus = float(ray.cluster_resources().get("GPU", 0))
        device = rollout_kwargs.pop("device", None)
        if gpus_per_worker is None:
            gpus_per_worker = 1 if gpus and (device is None or str(device).startswith("cuda")) else 0
        if gpus_per_worker and not gpus:
            raise ValueError(f"gpus_per_worker={gpus_per_worker} but the Ray cluster has no GPUs")
        if device is None:
            device = "cuda" if gpus_per_worker else "cpu"
        client = address is not None and str(address).startswith("ray://")
        # a worker on the driver's node writes in place; elsewhere (and under Ray Client) it ships its files
        driver_node = None if client else ray.get_runtime_context().get_node_id()
        task = ray.remote(_run_one).options(num_cpus=1, num_gpus=gpus_per_worker, max_retries=max_retries,
                                            retry_exceptions=True)
        kwargs = dict(rollout_kwargs, device=device)
        window = num_workers or len(targets)
        if progress:
            print(f"rollout_ray: {len(targets)} runs on Ray ({int(ray.cluster_resources().get('CPU', 0))} CPUs, "
                  f"{gpus:g} GPUs), device {device}, {gpus_per_worker:g} GPU per task"
                  + (f", {num_workers} at once" if num_workers else ""), file=sys.stderr, flush=True)
        pending: dict = {}  # ObjectRef -> index into targets
        submitted = 0
        bar = tqdm(total=len(targets), desc="rollouts (ray)", unit="run", file=sys.stderr, disable=not progress)
        try:
            while submitted < len(targets) or pending:
                while submitted < len(targets) and len(pending) < window:
                    scene, key = targets[submitted]
                    ref = task.remote(str(scene), key, str(out_abs / names[submitted]), driver_node, os.getcwd(),
                                      kwargs)
                    pending[ref] = submitted
                    submitted += 1
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    i = pending[ref]
                    rows[i] = _collect(ray, ref, targets[i], out_user / names[i], out_abs / names[i], max_retries)
                    del pending[ref]  # after its row is kept: a Ctrl-C in between collects it again
                    _write_tables(rows, out_abs)
                    bar.update(1)
                    if emit:
                        emit(rows[i])
        except KeyboardInterrupt:
            bar.close()
            open_runs = [i for i, r in enumerate(rows) if r is None]
            _cancel(ray, pending, rows, targets, out_user, out_abs, names, max_retries)
            for i in open_runs:
                if rows[i] is None:
                    scene, key = targets[i]
                    rows[i] = dict(scene=str(scene), keyframe=key, finite=False, interrupted=True,
                                   error="cancelled (Ctrl-C)")
            _write_tables(rows, out_abs)
            if emit:
                for i in open_runs:
                    emit(rows[i])
            if progress:
                print(f"rollout_ray: interrupted; {sum(not r.get('interrupted') for r in rows)} of {len(rows)} runs "
                      f"finished, table {out_user / 'summary.csv'}", file=sys.stderr, flush=True)
        finally:
            bar.close()
    finally:
        if started:
            ray.shutdown()
    return [r for r in rows if r is not None]


def _run_one(scene: str, keyframe, run_dir: str, driver_node, cwd: str, kwargs: dict):
    """The Ray task: one rollout; returns (summary row, {file name: bytes}), the files only when
    this worker is not on the driver's node (then the run goes to a temporary folder here)."""
    import ray

    from physhand_mj.rollout import rollout
    from physhand_mj.solver import SolverError

    path = Path(scene) if Path(scene).is_absolute() else Path(cwd) / scene  # the driver's working directory
    here = driver_node is not None and ray.get_runtime_context().get_node_id() == driver_node
    tmp = None if here else tempfile.mkdtemp(prefix="physhand_rollout_")
    try:
        try:
            res = rollout(path, keyframe, out=run_dir if here else tmp, progress=False, **kwargs)
        except (FileNotFoundError, ValueError, SolverError) as e:  # bad input: a rerun fails the same way
            return failed_row(scene, keyframe, e), {}
        res["scene"] = scene
        files = {} if here else {p.name: p.read_bytes() for p in Path(tmp).iterdir() if p.is_file()}
        return res, files
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _collect(ray, ref, target, run_user: Path, run_abs: Path, max_retries: int) -> dict:
    """The summary row of a finished task; writes the files it shipped into its run folder."""
    scene, key = target
    try:
        res, files = ray.get(ref)
    except ray.exceptions.TaskCancelledError:
        return dict(scene=str(scene), keyframe=key, finite=False, interrupted=True, error="cancelled (Ctrl-C)")
    except ray.exceptions.RayError as e:
        cause = getattr(e, "cause", None) or e  # RayTaskError: the task's own exception
        return failed_row(scene, key, f"{type(cause).__name__}: {str(cause)[:400]} "
                                      f"(failed {max_retries + 1} times)")
    if files:
        run_abs.mkdir(parents=True, exist_ok=True)
        for name, data in files.items():
            (run_abs / name).write_bytes(data)
    if "log" in res:
        res.update(log=str(run_user / "log.csv"), skin=str(run_user / "skin_final.ply"))
    return res


def _cancel(ray, pending: dict, rows: list, targets, out_user: Path, out_abs: Path, names, max_retries: int):
    """Ctrl-C: cancel the unfinished tasks and gather the partial summaries of those that were
    running (a second Ctrl-C stops waiting)."""
    for ref in pending:
        ray.cancel(ref)  # not forced: a running rollout gets KeyboardInterrupt and returns its partial summary
    if not pending:
        return
    print(f"rollout_ray: Ctrl-C: cancelling {len(pending)} runs (again to stop waiting)", file=sys.stderr, flush=True)
    try:
        done, _ = ray.wait(list(pending), num_returns=len(pending), timeout=CANCEL_GRACE_S)
        for ref in done:
            i = pending[ref]
            rows[i] = _collect(ray, ref, targets[i], out_user / names[i], out_abs / names[i], max_retries)
    except KeyboardInterrupt:
        pass


def _write_tables(rows: list, out: Path):
    """summary.csv (and summary.parquet when pyarrow is importable) of the finished runs, in the
    order of the batch; written to a temporary name and renamed, so a table on disk is whole."""
    done = [r for r in rows if r is not None]
    write_summary(done, out)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return
    pq.write_table(pa.Table.from_pylist([{c: r.get(c) for c in SUMMARY_COLUMNS} for r in done]),
                   out / "summary.parquet.tmp")
    os.replace(out / "summary.parquet.tmp", out / "summary.parquet")
