"""The fused substep (Config.execution.fused_substep, physhand_mj/solver/fused.py) against the five-launch substep,
interleaved frame by frame in one process so that a shared host's drift hits both alike.

W worlds of the embedded hand (BatchedHands; W = 1 is one hand), open pose, each world's index
finger bending at its own rate (as benchmarks/batch_throughput.py), no contact; ``--frames`` frames
each way after 2 warm-up frames (compilation, recording and graph capture excluded), alternating
five-launch / fused frame by frame; the median ms per frame each way, and how far the two runs'
positions end apart (0 on the CPU, where the fused substep adds in the atomic path's order).
On CUDA the five-launch side is the batch's default (gathers from W = 2).

    python benchmarks/fused_substep.py [--device cpu|cuda] [--worlds 1,4] [--frames 20] [--block 1024]
                                       [--sum scatter|gather] [--order asset|strided] [--tag NAME]

``--sum``: how the fused kernel sums a group's corrections per vertex (solver/fused.py SUM);
``--order``: the order a block walks the constraints in (solver/fused.py ORDER).
Writes docs/benchmarks/fused_substep_<device>[_gather][_strided][_<tag>].json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    import warp as wp

    from physhand_mj.batch import BatchedHands
    from physhand_mj.bench import device_name
    from physhand_mj.solver import fused
    from physhand_mj.types import Config, Execution

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from batch_throughput import bending_poses, hand_only_setup

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--worlds", default="1,4", help="comma-separated world counts")
    p.add_argument("--frames", type=int, default=20, help="timed 5 ms frames each way per world count")
    p.add_argument("--block", type=int, default=fused.BLOCK_DIM, help="threads per world's block on CUDA")
    p.add_argument("--sum", default=fused.SUM, choices=("scatter", "gather"), help="solver/fused.py SUM")
    p.add_argument("--order", default=fused.ORDER, choices=("asset", "strided"), help="solver/fused.py ORDER")
    p.add_argument("--tag", default="", help="suffix of the JSON's name (a run beside the earlier ones)")
    a = p.parse_args()
    fused.BLOCK_DIM = a.block
    fused.SUM = a.sum
    fused.ORDER = a.order
    wp.init()
    asset, model, data, ids, mount = hand_only_setup()
    rows = []
    for w in [int(s) for s in a.worlds.split(",")]:
        poses = bending_poses(model, data, ids, w)

        runs = {name: BatchedHands(asset, w, Config(device=a.device, sleep_speed=0.0, execution=Execution(fused_substep=flag)), *mount)
                for name, flag in (("five_launch", False), ("fused", True))}
        inputs = [poses(f) for f in range(2 + a.frames)]  # (bone poses from MuJoCo: not timed)
        times = {name: [] for name in runs}
        for f, (pos, quat) in enumerate(inputs):
            for name, hands in runs.items():
                t = time.perf_counter()
                out = hands.step(pos, quat)
                if f >= 2:
                    times[name].append((time.perf_counter() - t) * 1e3)
                assert out["nonfinite"] == 0
        # (every world at once: both batches lay their worlds' vertices out alike, and positions(k)
        # copies the whole batch off the device for each world)
        apart = float(np.abs(runs["fused"].state.x.numpy() - runs["five_launch"].state.x.numpy()).max())
        med = {name: float(np.median(t)) for name, t in times.items()}
        rows.append(dict(worlds=w, five_launch_ms=round(med["five_launch"], 3), fused_ms=round(med["fused"], 3),
                         speedup=round(med["five_launch"] / med["fused"], 3),
                         fused_hand_frames_per_s=round(w / med["fused"] * 1e3, 1),
                         positions_apart_m=apart,
                         ops_per_frame=dict(five_launch=runs["five_launch"].solver.last_activity.get("ops_run"),
                                            fused=runs["fused"].solver.last_activity.get("ops_run"))))
        print(json.dumps(rows[-1]), flush=True)
        for hands in runs.values():
            hands.close()
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    tag = ("_gather" if a.sum == "gather" else "") + ("_strided" if a.order == "strided" else "") + (f"_{a.tag}" if a.tag else "")
    out = ROOT / "docs" / "benchmarks" / f"fused_substep_{a.device.split(':')[0]}{tag}.json"
    out.write_text(json.dumps(dict(device=dev, frames=a.frames, block_dim=a.block if "cuda" in a.device else None, sum=a.sum,
                                   order=a.order,
                                   command="python benchmarks/fused_substep.py " + " ".join(sys.argv[1:]),
                                   rows=rows), indent=1))
    print(json.dumps(dict(device=dev, out=str(out.relative_to(ROOT)))))


if __name__ == "__main__":
    main()
