"""Rollouts on Ray across the GPUs of one machine: wall time and hand-frames per second with 1, 2, ...
GPUs (issue 15: the 2 GPUs of an H200 pair at >= 1.8 x one GPU).

    python benchmarks/ray_scaling.py [--gpus 1,2] [--runs 256] [--batch 16] [--steps 36]
                                     [--scene mjcf/scenes/hoi_apple.xml] [--keyframe grasp] [--cluster]
                                     [--out FILE]

Per GPU count k: ``physhand rollout LIST --ray --batch W --device cuda`` as a user runs it, in a
fresh process that sees the first k GPUs (CUDA_VISIBLE_DEVICES), on a local Ray (one batch task per
GPU at a time); LIST holds ``--runs`` copies of the scene's keyframe. Wall time from the command's
start to its end (Ray start, worker start, kernel loading from Warp's cache, every batch's setup,
settling and frames, the logs and PLYs written), hand-frames = runs x steps. Also split from the
times the rows arrive (one burst per finished batch): ``first_rows_s`` (the start, up to the first
batches' rows) and ``steady_hand_frames_per_s`` (the rest of the list over the rest of the time),
so the speed-up of the GPUs' steady part shows apart from a start that does not shrink with GPUs;
and from the times each batch task reports in its rows (``task_start``, ``task_ready`` after its set-up
and settling, ``task_end``, ``task_pid``): when the first task started, the median batch's set-up and
frames, and how far apart the workers' last batches ended (the tail one GPU waits for the other).
With ``--cluster`` the command runs on a Ray cluster that is already up (``--ray auto``), as on a
cluster that serves many jobs: before each GPU count this script starts one (``ray start --head
--num-gpus k``, the first k GPUs visible to it) and stops it after, outside the timing; the command's
time then holds no Ray start (about 2.6 s on the CPU) and no shutdown (2.1 s: Ray's processes asked
to exit and waited for), the workers' start stays in. Outputs go to a temporary folder; the summary's rows are checked (all finite, none failed). One
JSON document.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gpus", default="1,2", help="GPU counts to compare (comma-separated)")
    ap.add_argument("--runs", type=int, default=256, help="rollouts in the list (count)")
    ap.add_argument("--batch", type=int, default=16, help="worlds per batch (one Ray task each)")
    ap.add_argument("--steps", type=int, default=36, help="5 ms frames per rollout")
    ap.add_argument("--scene", default=str(ROOT / "mjcf" / "scenes" / "hoi_apple.xml"))
    ap.add_argument("--keyframe", default="grasp")
    ap.add_argument("--device", default="cuda", help="Warp device of the rollouts (cpu: a local check, Ray's CPU workers)")
    ap.add_argument("--cluster", action="store_true",
                    help="run on a Ray cluster started before the timing (ray start --head), not a local ray.init; "
                         "`ray stop` after each timing stops every Ray of this user on the machine")
    ap.add_argument("--out", default=None, help="JSON path (default: stdout only)")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        lst = Path(tmp) / "runs.txt"
        lst.write_text("".join(f"{Path(a.scene).resolve()} {a.keyframe}\n" for _ in range(a.runs)))
        for k in [int(g) for g in a.gpus.split(",")]:
            out = Path(tmp) / f"out{k}"
            env = dict(os.environ, CUDA_VISIBLE_DEVICES=",".join(str(i) for i in range(k)))
            env.pop("RAY_ADDRESS", None)  # --ray auto: the cluster started here, not one named by the caller
            cmd = [sys.executable, "-m", "physhand_mj.cli", "rollout", str(lst), "--ray", "--batch", str(a.batch),
                   "--steps", str(a.steps), "--device", a.device, "--out", str(out)]
            if a.cluster:
                cmd[cmd.index("--ray") + 1:cmd.index("--ray") + 1] = ["auto"]
                start_cluster(k if a.device.startswith("cuda") else 0, env)
            try:
                wall, arrived, tasks, rc, err = time_command(cmd, env, Path(tmp) / f"stderr{k}.txt")
            finally:
                if a.cluster:
                    subprocess.run([sys.executable, "-m", "ray.scripts.scripts", "stop"], capture_output=True)
            summary = list(csv.DictReader(open(out / "summary.csv"))) if (out / "summary.csv").exists() else []
            ok = [r for r in summary if not r.get("error") and r.get("finite") == "True"]
            row = dict(gpus=k, runs=a.runs, batch=a.batch, steps=a.steps, wall_s=round(wall, 2),
                       hand_frames_per_s=round(a.runs * a.steps / wall, 1), rows=len(summary), finite_ok=len(ok),
                       exit=rc, stderr_tail=err[-600:] if rc else "")
            row.update(split_start(arrived, a.steps, wall))
            row.update(split_tasks(tasks, wall))
            rows.append(row)
            print(json.dumps(row), flush=True)
    if len(rows) > 1:
        base = rows[0]["wall_s"]
        for r in rows:
            r["speedup_vs_first"] = round(base / r["wall_s"], 3)
    doc = dict(device=_gpus() if a.device.startswith("cuda") else "cpu", command="python " + " ".join(sys.argv),
               ray="a cluster started before each timing (--ray auto)" if a.cluster else "a local ray.init per command",
               scene=a.scene, keyframe=a.keyframe, rows=rows)
    print(json.dumps(doc))
    if a.out:
        Path(a.out).write_text(json.dumps(doc, indent=1) + "\n")


def split_start(arrived: list, steps: int, wall: float, burst_s: float = 0.5) -> dict:
    """The command's start against its steady part from the times (s) its rows arrived: the first
    burst of rows (within ``burst_s`` of the first: the first batches, one per GPU, finishing) ends
    the start (Python, Ray and its workers, kernel loading, the first batches' set-up and frames);
    the hand-frames after it over the time after it is the steady rate the GPUs sustain."""
    if not arrived:
        return dict(first_rows_s=None, steady_hand_frames_per_s=None)
    t0 = arrived[0]
    first = sum(1 for x in arrived if x - t0 <= burst_s)
    rest, span = len(arrived) - first, arrived[-1] - t0
    return dict(first_rows_s=round(t0, 2), first_burst_rows=first, tail_s=round(wall - arrived[-1], 2),
                steady_hand_frames_per_s=round(rest * steps / span, 1) if rest and span > 0 else None)


def split_tasks(tasks: dict, wall: float) -> dict:
    """From the batch tasks' own times ((pid, start) -> (start, ready, end, device, the command's
    start), unix s): the first task's start (Python, Ray, the workers, the driver's grouping), the
    median set-up (scenes, BatchedHands, settling) and frames (frames, measures, logs, PLYs) of a
    batch, the spread of the GPUs' (CPU: the worker processes') last ends, the tail one waits for
    the other, and the time after the last task ended."""
    import statistics

    if not tasks:
        return {}
    v = list(tasks.values())
    t0 = v[0][4]
    last = {}
    for (pid, _), (_, _, end, dev, _) in tasks.items():
        key = dev if dev and str(dev).startswith("cuda") else pid  # a worker process may serve several GPUs
        last[key] = max(last.get(key, 0.0), end)
    ready = [r - s for s, r, *_ in v if r is not None]
    frames = [e - r for _, r, e, *_ in v if r is not None]
    return dict(tasks=len(v), workers=len(last), first_task_start_s=round(min(x[0] for x in v) - t0, 2),
                batch_setup_s_median=round(statistics.median(ready), 2) if ready else None,
                batch_frames_s_median=round(statistics.median(frames), 2) if frames else None,
                last_end_spread_s=round(max(last.values()) - min(last.values()), 2),
                after_last_task_s=round(t0 + wall - max(x[2] for x in v), 2))


def start_cluster(gpus: int, env: dict) -> None:
    """``ray start --head`` with ``gpus`` GPUs in ``env``; its output when it fails. A SIGTERM (a
    time limit) from here on raises, so the caller's ``finally`` stops the cluster."""
    signal.signal(signal.SIGTERM, _terminated)
    p = subprocess.run([sys.executable, "-m", "ray.scripts.scripts", "start", "--head", f"--num-gpus={gpus}",
                        "--include-dashboard=false", "--disable-usage-stats"], env=env, capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"ray start --head failed ({p.returncode}); is a Ray already running here (ray stop)?\n"
                           f"{p.stdout[-1500:]}{p.stderr[-1500:]}")


def _terminated(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def time_command(cmd: list, env: dict, err_path: Path):
    """Run ``cmd``; returns (wall s, the seconds from its start at which each JSON line came, the
    batch tasks' times {(pid, start): (start, ready, end, device, the command's start)} (unix s) from
    those lines, its exit code, its stderr)."""
    t, t_unix = time.perf_counter(), time.time()
    arrived, tasks = [], {}
    with open(err_path, "w") as ferr:
        p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=ferr, text=True)
        try:
            for line in p.stdout:
                if not line.startswith("{"):
                    continue
                arrived.append(time.perf_counter() - t)
                try:
                    r = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if r.get("task_start") is not None:
                    tasks[(r["task_pid"], r["task_start"])] = (r["task_start"], r["task_ready"], r["task_end"],
                                                               r.get("task_device"), t_unix)
            p.wait()
        finally:
            if p.poll() is None:
                p.terminate()
                p.wait()
    return time.perf_counter() - t, arrived, tasks, p.returncode, err_path.read_text()


def _gpus() -> str:
    """The machine's GPUs and driver, from nvidia-smi (empty when it is missing)."""
    try:
        p = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
                           capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return ""
    out = p.stdout.strip().splitlines()
    return f"{len(out)} x {out[0]}" if p.returncode == 0 and out else ""


if __name__ == "__main__":
    main()
