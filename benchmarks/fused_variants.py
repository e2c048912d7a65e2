"""The fused substep's accumulation variants against each other, interleaved frame by frame in one
process (solver/fused.py: ACCUM, MASS, LAM_EVERY_SUBSTEP, PIN_LOADS, VEC_LOADS, FRAME_LAUNCH, FOLD_END,
SKIP_BONES).

W worlds of the embedded hand (BatchedHands with ``fused_substep=True``), open pose, each world's
index finger bending at its own rate (benchmarks/batch_throughput.py), no contact; ``--frames`` frames
each way after 2 warm-up frames (compilation, recording and graph capture excluded). Variants:

- ``base``: float shared-memory atomics, inverse masses per vertex, multipliers written every
  substep (the kernel as it was up to 2026-11-26);
- ``lam``: the multipliers written in a frame's last substep only;
- ``row``: that, and the inverse masses stored per constraint;
- ``fixed``: ``lam`` with the fixed-point int32 sum (ACCUM "fixed");
- ``fixed_row``: both;
- ``pinned``: ``fixed_row`` with the rest data loaded at the top of each iteration (PIN_LOADS);
- ``vec``: ``pinned`` with each constraint's ids and masses in one vector load (VEC_LOADS);
- ``frame``: ``vec`` with a frame's substeps in one launch, the positions kept in shared memory
  (FRAME_LAUNCH; shipped 2026-11-27);
- ``end``: ``frame`` that also ends the frame (the last substep's velocities, x_safe, the fast and
  inverted counts from shared memory: FOLD_END), so no last ``advance`` and no ``count_inverted``;
- ``bones``: ``end`` with a skeleton vertex's global rows left alone between a frame's first and last
  substeps (SKIP_BONES; the default as shipped).

Per world count: the median ms per frame each way, hand-frames/s, and how far each variant's
positions end from ``base``'s (every world; CUDA's float atomics alone differ by ~0.4 um between two
runs: docs/solver.md). Tried and measured, not in the tree (docs/scale.md): each thread loading its
next constraint while it solves one, and the substep's start two vertices a thread at a time.

    python benchmarks/fused_variants.py [--device cpu|cuda] [--worlds 1024] [--frames 10]
                                        [--variants base,lam,row,fixed,fixed_row,pinned,vec,frame,end,bones]
                                        [--block 1024] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# (ACCUM, MASS, LAM_EVERY_SUBSTEP, PIN_LOADS, VEC_LOADS, FRAME_LAUNCH, FOLD_END, SKIP_BONES) of solver/fused.py
VARIANTS = dict(base=("float", "vertex", True, False, False, False, False, False),
                lam=("float", "vertex", False, False, False, False, False, False),
                row=("float", "row", False, False, False, False, False, False),
                fixed=("fixed", "vertex", False, False, False, False, False, False),
                fixed_row=("fixed", "row", False, False, False, False, False, False),
                pinned=("fixed", "row", False, True, False, False, False, False),
                vec=("fixed", "row", False, True, True, False, False, False),
                frame=("fixed", "row", False, True, True, True, False, False),
                end=("fixed", "row", False, True, True, True, True, False),
                bones=("fixed", "row", False, True, True, True, True, True))


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
    p.add_argument("--worlds", default="4", help="comma-separated world counts")
    p.add_argument("--frames", type=int, default=10, help="timed 5 ms frames each way per world count")
    p.add_argument("--variants", default="base,lam,row,fixed,fixed_row,pinned,vec,frame",
                   help=f"comma-separated, of {list(VARIANTS)}")
    p.add_argument("--block", type=int, default=None,
                   help="threads per world's block on CUDA, every variant (solver/fused.py BLOCK_DIM)")
    p.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/fused_variants_<device>.json)")
    a = p.parse_args()
    names = [s for s in a.variants.split(",") if s]
    bad = [s for s in names if s not in VARIANTS]
    if bad:
        p.error(f"unknown variant(s) {bad}; choose from {list(VARIANTS)}")
    if a.block:
        fused.BLOCK_DIM = a.block
    wp.init()
    asset, model, data, ids, mount = hand_only_setup()
    rows = []
    switches = ("ACCUM", "MASS", "LAM_EVERY_SUBSTEP", "PIN_LOADS", "VEC_LOADS", "FRAME_LAUNCH", "FOLD_END", "SKIP_BONES")
    saved = tuple(getattr(fused, k) for k in switches)
    for w in [int(s) for s in a.worlds.split(",")]:
        poses = bending_poses(model, data, ids, w)
        inputs = [poses(f) for f in range(2 + a.frames)]  # (bone poses from MuJoCo: not timed)
        runs = {}
        for name in names:
            for k, v in zip(switches, VARIANTS[name]):
                setattr(fused, k, v)
            try:
                runs[name] = BatchedHands(asset, w, Config(device=a.device, sleep_speed=0.0, execution=Execution(fused_substep=True)), *mount)
                runs[name].step(*inputs[0])  # (its kernel built and its frame recorded with these switches)
            finally:
                for k, v in zip(switches, saved):
                    setattr(fused, k, v)
        times = {name: [] for name in runs}
        for f, (pos, quat) in enumerate(inputs[1:], start=1):
            for name, hands in runs.items():
                t = time.perf_counter()
                out = hands.step(pos, quat)
                if f >= 2:
                    times[name].append((time.perf_counter() - t) * 1e3)
                assert out["nonfinite"] == 0, name
        ref = runs[names[0]].state.x.numpy()
        row = dict(worlds=w, reference=names[0])
        for name, hands in runs.items():
            med = float(np.median(times[name]))
            row[name] = dict(ms=round(med, 3), hand_frames_per_s=round(w / med * 1e3, 1),
                             apart_m=float(np.abs(hands.state.x.numpy() - ref).max()),
                             speedup=round(float(np.median(times[names[0]])) / med, 3))
        rows.append(row)
        print(json.dumps(row), flush=True)
        for hands in runs.values():
            hands.close()
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    out = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"fused_variants_{a.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(dict(device=dev, frames=a.frames, block_dim=fused.BLOCK_DIM,
                                   variants={k: VARIANTS[k] for k in names},
                                   command="python benchmarks/fused_variants.py " + " ".join(sys.argv[1:]),
                                   rows=rows), indent=1))
    print(json.dumps(dict(device=dev, out=str(out))))


if __name__ == "__main__":
    main()
