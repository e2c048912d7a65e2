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
same path on every node).

With ``batch=W`` each task runs one batch instead: up to W runs whose scenes hold the same objects
(grouped on the driver as :func:`physhand_mj.batch_rollout.rollout_batched` groups them), in one
solver step with :func:`~physhand_mj.batch_rollout.rollout_batched`; it writes the same run folders
and returns their rows, and a batch whose task failed is retried as a whole.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from physhand_mj.rollout import SUMMARY_COLUMNS, check_measure_every, failed_row, run_names, write_summary

NOSET_CUDA = "RAY_EXPERIMENTAL_NOSET_CUDA_VISIBLE_DEVICES"  # Ray's switch: GPU tasks keep the node's visible GPUs
CANCEL_GRACE_S = 30.0  # after Ctrl-C: how long the driver waits for the cancelled runs' partial summaries


def rollout_ray(targets, out, *, address: str | None = None, num_workers: int | None = None,
                gpus_per_worker: float | None = None, max_retries: int = 2, emit=None, progress: bool = True,
                batch: int | None = None, **rollout_kwargs) -> list[dict]:
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

    ``batch``: W, worlds per task: each task runs one batch of up to W runs with the same objects
    through :func:`~physhand_mj.batch_rollout.rollout_batched` (``rollout_kwargs``: its options,
    steps, substeps, contact, device, config, spacing); the driver loads every scene once to group
    them and submits each batch as soon as it is full, while it loads the rest (a scene it cannot
    load is a failed row at once). ``num_workers`` then counts batches at
    once; retries, Ctrl-C and the summary work per batch as they do per run.
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
    check_measure_every(rollout_kwargs.get("measure_every", 1))
    asset = None
    if batch is not None:
        import physhand_mj as ph
        from physhand_mj.batch_rollout import check_worlds
        from physhand_mj.rollout import check_counts

        check_worlds(batch)
        check_counts(rollout_kwargs.get("steps", 36), rollout_kwargs.get("substeps", 10))
        asset = ph.load_asset()  # (its errors before Ray starts; the driver groups the list with it)
    out_user = Path(out)
    out_abs = out_user.resolve()
    out_abs.mkdir(parents=True, exist_ok=True)
    names = run_names(targets)
    rollout_kwargs.pop("progress", None)
    started = not ray.is_initialized()
    if started:
        import logging

        # workers' own output (Warp's banner, ...) stays in Ray's session logs: stdout keeps one JSON line a run
        # None: a new local Ray (not a cluster this machine runs, which Ray would join by default: --ray auto)
        local = {} if address is not None else dict(include_dashboard=False)
        ray.init(address=address if address is not None else "local", log_to_driver=False,
                 logging_level=logging.ERROR, **local)
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
        if gpus_per_worker and str(device).startswith("cuda") and str(device) not in ("cuda", "cuda:0"):
            raise ValueError(f"device={device!r}: each Ray GPU task runs on the GPU Ray gives it; use "
                             f"device='cuda' (--device cuda), or gpus_per_worker=0 for CPU tasks")
        client = address is not None and str(address).startswith("ray://")
        # a worker on the driver's node writes in place; elsewhere (and under Ray Client) it ships its files
        driver_node = None if client else ray.get_runtime_context().get_node_id()
        # GPU tasks: Ray leaves CUDA_VISIBLE_DEVICES alone and each task picks the GPU it was given
        # (task_device), so a worker process serves task after task, Warp's kernels loaded once,
        # without a reused worker running on the GPU a previous task was given (ray#29624)
        gpu_env = dict(runtime_env={"env_vars": {NOSET_CUDA: "1"}}) if gpus_per_worker else {}
        task = ray.remote(_run_one if batch is None else _run_group).options(
            num_cpus=1, num_gpus=gpus_per_worker, max_retries=max_retries, retry_exceptions=True, **gpu_env)
        kwargs = dict(rollout_kwargs, device=device)
        warming = []  # warm-up tasks: not waited on (the list's tasks queue behind them); cancelled at the end
        if batch is None:
            source = iter([i] for i in range(len(targets)))
        else:  # batches go out as they fill, while this process loads the rest of the list to group it
            from physhand_mj.batch_rollout import iter_batch_groups

            source = iter_batch_groups(targets, batch, asset)
            # meanwhile the workers start (process, imports, Warp and the GPU's context): one per slot,
            # at most one per batch of the list
            slots = int(gpus // gpus_per_worker) if gpus_per_worker else int(ray.cluster_resources().get("CPU", 1))
            n = min(slots, num_workers or slots, -(-len(targets) // batch))
            warm = ray.remote(_warm).options(num_cpus=1, num_gpus=gpus_per_worker, max_retries=0, **gpu_env)
            warming = [warm.remote(kwargs) for _ in range(n)]
        groups: list[list[int]] = []  # the jobs submitted so far: indices into targets (a run, or a batch)
        window = num_workers or len(targets) + 1

        def submit(g):
            run_dirs = [str(out_abs / names[i]) for i in groups[g]]
            if batch is None:
                scene, key = targets[groups[g][0]]
                return task.remote(str(scene), key, run_dirs[0], driver_node, os.getcwd(), kwargs)
            return task.remote([(str(targets[i][0]), targets[i][1]) for i in groups[g]], run_dirs, driver_node,
                               os.getcwd(), batch, kwargs)

        def collect(ref, g):
            job = groups[g]
            if batch is None:
                i = job[0]
                return {i: _collect(ray, ref, targets[i], out_user / names[i], out_abs / names[i], max_retries)}
            got = _collect_group(ray, ref, [targets[i] for i in job], [out_user / names[i] for i in job],
                                 [out_abs / names[i] for i in job], max_retries)
            return dict(zip(job, got))

        if progress:
            print(f"rollout_ray: {len(targets)} runs"
                  + (f" in batches of up to {batch}" if batch is not None else "")
                  + f" on Ray ({int(ray.cluster_resources().get('CPU', 0))} CPUs, {gpus:g} GPUs), "
                  f"device {device}, {gpus_per_worker:g} GPU per task"
                  + (f", {num_workers} at once" if num_workers else ""), file=sys.stderr, flush=True)
        pending: dict = {}  # ObjectRef -> index into groups (a run, or a batch of runs)
        bar = tqdm(total=len(targets), desc="rollouts (ray)", unit="run", file=sys.stderr, disable=not progress)
        more, ahead = True, None  # the source has jobs left; the next one, grouped while tasks run

        def next_job():
            """The next run or batch of the list; the runs whose scene the driver could not load on the
            way get their failed rows."""
            failed = []
            try:
                while True:
                    job = next(source, None)
                    if not isinstance(job, tuple):
                        return job
                    i, e = job  # (index, error)
                    rows[i] = failed_row(*targets[i], e)
                    failed.append(i)
            finally:
                if failed:
                    _write_tables(rows, out_abs)
                    bar.update(len(failed))
                    if emit:
                        for i in failed:
                            emit(rows[i])

        def fill():
            nonlocal more, ahead
            while more and len(pending) < window:
                job, ahead = (ahead if ahead is not None else next_job()), None
                if job is None:
                    more = False
                else:
                    groups.append(job)
                    pending[submit(len(groups) - 1)] = len(groups) - 1
            if more and ahead is None and batch is not None:  # a full window: group the next batch now
                ahead = next_job()
                more = ahead is not None

        try:
            while True:
                fill()
                if not pending:
                    break
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    got = collect(ref, pending[ref])
                    for i, row in got.items():
                        rows[i] = row
                    del pending[ref]  # after its rows are kept: a Ctrl-C in between collects them again
                    _write_tables(rows, out_abs)
                    bar.update(len(got))
                    if emit:
                        for row in got.values():
                            emit(row)
        except KeyboardInterrupt:
            bar.close()
            open_runs = [i for i, r in enumerate(rows) if r is None]
            _cancel(ray, pending, rows, collect)
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
        except BaseException:  # an unexpected error here (say, while grouping): no task runs on without us
            for ref in pending:
                ray.cancel(ref)
            _write_tables([r for r in rows if r is not None], out_abs)
            raise
        finally:
            bar.close()
            if warming:  # one still starting (a GPU that hangs) gives its slot back
                _, running = ray.wait(warming, num_returns=len(warming), timeout=0)
                for ref in running:
                    ray.cancel(ref, force=True)
    finally:
        if started:
            ray.shutdown()
    return [r for r in rows if r is not None]


def task_device(device, gpu_ids, visible: str | None):
    """The Warp device of a Ray task given GPUs ``gpu_ids`` (``ray.get_gpu_ids()``) in a process
    that sees the GPUs ``visible`` (its ``CUDA_VISIBLE_DEVICES``; ``None``: all of them): ``"cuda"``
    (and ``"cuda:0"``, the first of the task's GPUs, as it was while Ray narrowed
    ``CUDA_VISIBLE_DEVICES`` to them) becomes ``"cuda:K"``, K that GPU's ordinal in this process; any
    other device (``"cpu"``), or a task without GPUs, stays as it is (``rollout_ray`` refuses
    ``"cuda:N"``, N > 0, for GPU tasks)."""
    if str(device) not in ("cuda", "cuda:0") or not gpu_ids:
        return device
    gid = str(gpu_ids[0]).strip()
    ids = [v.strip() for v in visible.split(",")] if visible and visible.strip() else None
    if ids is None:
        if not gid.isdigit():
            raise ValueError(f"Ray gave this task GPU {gid!r}, which is no CUDA ordinal; set CUDA_VISIBLE_DEVICES")
        return f"cuda:{gid}"
    if gid not in ids:
        raise ValueError(f"Ray gave this task GPU {gid!r}, which this worker does not see "
                         f"(CUDA_VISIBLE_DEVICES={visible!r})")
    return f"cuda:{ids.index(gid)}"


def _on_my_gpu(kwargs: dict) -> dict:
    """``kwargs`` with the device of the GPU Ray gave this task (see :func:`task_device`)."""
    import ray

    dev = task_device(kwargs.get("device"), ray.get_gpu_ids(), os.environ.get("CUDA_VISIBLE_DEVICES"))
    if dev == kwargs.get("device"):
        return kwargs
    import warp as wp

    wp.set_device(dev)  # also what Warp's host-side CUDA work (pinned buffers) runs on
    return dict(kwargs, device=dev)


def _warm(kwargs: dict) -> int:
    """The warm-up task: the worker's imports, Warp and its device (the GPU's context), the asset's
    files read once (into the page cache); a worker serves the list's tasks after it. Returns its
    process id."""
    import warp as wp

    import physhand_mj as ph
    import physhand_mj.batch_rollout  # noqa: F401  (the batch path's imports)

    try:
        kwargs = _on_my_gpu(kwargs)
        dev = kwargs.get("device")
        wp.init()
        with wp.ScopedDevice(dev):
            wp.zeros(1)  # the device's context
        ph.load_asset()
    except Exception:  # the real tasks report it (a bad device, a GPU it does not see)
        pass
    return os.getpid()


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
            kwargs = _on_my_gpu(kwargs)
            res = rollout(path, keyframe, out=run_dir if here else tmp, progress=False, **kwargs)
        except (FileNotFoundError, ValueError, SolverError) as e:  # bad input: a rerun fails the same way
            return failed_row(scene, keyframe, e), {}
        res["scene"] = scene
        files = {} if here else {p.name: p.read_bytes() for p in Path(tmp).iterdir() if p.is_file()}
        return res, files
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _run_group(targets: list, run_dirs: list, driver_node, cwd: str, worlds: int, kwargs: dict):
    """The Ray task of ``batch=W``: one batch of runs (the same objects, up to W) with
    :func:`~physhand_mj.batch_rollout.rollout_batched` into a temporary folder; each run's folder
    then moves to its place in the driver's output when this worker is on the driver's node, else
    its files go back. Returns ([summary row or None per run], [{file name: bytes} per run])."""
    import ray

    from physhand_mj.batch_rollout import rollout_batched
    from physhand_mj.rollout import run_names

    start = time.time()
    kwargs = _on_my_gpu(kwargs)
    paths = [(str(Path(s) if Path(s).is_absolute() else Path(cwd) / s), key) for s, key in targets]
    here = driver_node is not None and ray.get_runtime_context().get_node_id() == driver_node
    tmp = Path(tempfile.mkdtemp(prefix="physhand_batch_"))
    ready, user_on_start = [], kwargs.pop("on_start", None)

    def on_start(*args):  # the batch set up and settled: its first frame is next
        ready.append(time.time())
        if user_on_start is not None:
            user_on_start(*args)

    try:
        got = rollout_batched(paths, tmp, worlds=worlds, progress=False, on_start=on_start, **kwargs)
        # when this task ran (unix s) and where: benchmarks/ray_scaling.py splits the command's time with it
        task = dict(task_pid=os.getpid(), task_device=str(kwargs.get("device")), task_start=round(start, 3),
                    task_ready=round(ready[0], 3) if ready else None, task_end=round(time.time(), 3))
        for r in got:
            r.update(task)
        got = iter(got)
        row = next(got, None)
        rows, files = [], []
        for (scene, key), path, name, run_dir in zip(targets, paths, run_names(paths), run_dirs):
            mine = row is not None and row.get("scene") == path[0]  # the keyframe may be the scene's default
            src = tmp / name
            if mine:
                row["scene"] = scene
                rows.append(row)
                row = next(got, None)
            else:  # Ctrl-C before this run's batch set up: no row
                rows.append(None)
            ship = {}
            if src.is_dir():
                if here:
                    Path(run_dir).mkdir(parents=True, exist_ok=True)
                    for p in src.iterdir():
                        shutil.move(str(p), str(Path(run_dir) / p.name))
                else:
                    ship = {p.name: p.read_bytes() for p in src.iterdir() if p.is_file()}
            files.append(ship)
        return rows, files
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _collect_group(ray, ref, targets, runs_user: list, runs_abs: list, max_retries: int) -> list[dict]:
    """The summary rows of a finished batch task (one per run of ``targets``); writes the files it
    shipped into the run folders. A failed or cancelled task: every run of the batch gets the row."""
    try:
        res, files = ray.get(ref)
    except ray.exceptions.TaskCancelledError:
        return [dict(scene=str(s), keyframe=k, finite=False, interrupted=True, error="cancelled (Ctrl-C)")
                for s, k in targets]
    except ray.exceptions.RayError as e:
        cause = getattr(e, "cause", None) or e
        return [failed_row(s, k, f"{type(cause).__name__}: {str(cause)[:400]} (failed {max_retries + 1} times)")
                for s, k in targets]
    out = []
    for (scene, key), row, ship, run_user, run_abs in zip(targets, res, files, runs_user, runs_abs):
        if ship:
            run_abs.mkdir(parents=True, exist_ok=True)
            for name, data in ship.items():
                (run_abs / name).write_bytes(data)
        if row is None:
            row = dict(scene=str(scene), keyframe=key, finite=False, interrupted=True, error="cancelled (Ctrl-C)")
        elif "log" in row:
            row.update(log=str(run_user / "log.csv"), skin=str(run_user / "skin_final.ply"))
        out.append(row)
    return out


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


def _cancel(ray, pending: dict, rows: list, collect):
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
            for i, row in collect(ref, pending[ref]).items():
                rows[i] = row
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
