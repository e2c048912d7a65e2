"""Jacobi corrections by float atomics against the per-vertex gather (``Config.execution.jacobi_gather``,
physhand_mj/solver/gather.py): one hand's solver frame, time and agreement.

The hand closes from ``open`` to ``power`` over 8 frames of 5 ms (10 substeps), then holds; the
median of ``--frames`` held frames is timed (after the closing: compilation, recording and graph
capture excluded), each solver run twice (``run a`` / ``run b``) to show what repeats bit for bit.

    python benchmarks/jacobi_gather.py [--device cpu|cuda] [--frames 20]

Writes docs/benchmarks/jacobi_gather_<device>.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run(device: str, gather: bool, frames: int):
    import warp as wp

    import physhand_mj as ph

    asset, model, data = ph.open_hand_scene("hand_only", "open")
    bones = ph.body_ids(model, asset.body_names)
    config = ph.Config(device=device, sleep_speed=0.0, execution=ph.Execution(jacobi_gather=gather))
    solver = ph.Solver(ph.make_model(asset, config), config)
    state = solver.make_state(*ph.mount_pose(model, data))
    for k in range(8):
        q = model.key("open").qpos + (k + 1) / 8 * (model.key("power").qpos - model.key("open").qpos)
        solver.set_body_poses(state, *ph.bone_poses_at(model, data, q, bones))
        solver.step(state)
    ms = []
    for _ in range(frames):
        wp.synchronize_device(device)
        t = time.perf_counter()
        solver.step(state)
        wp.synchronize_device(device)
        ms.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ms)), state.x.numpy().copy()


def main() -> None:
    import warp as wp

    from physhand_mj.bench import device_name

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--frames", type=int, default=20, help="timed frames (5 ms each) after the closing")
    a = p.parse_args()
    wp.init()
    rows, x = [], {}
    for gather in (False, True):
        for rep in ("a", "b"):
            ms, x[gather, rep] = run(a.device, gather, a.frames)
            rows.append(dict(method="gather" if gather else "atomics", run=rep, ms_per_frame=round(ms, 4)))
            print(json.dumps(rows[-1]), flush=True)
    um = lambda u, v: float(np.abs(u - v).max() * 1e6)  # noqa: E731
    agree = dict(
        atomics_a_vs_b_um=um(x[False, "a"], x[False, "b"]), gather_a_vs_b_um=um(x[True, "a"], x[True, "b"]),
        gather_vs_atomics_um=um(x[True, "a"], x[False, "a"]),
        gather_repeats_bit_for_bit=bool(np.array_equal(x[True, "a"], x[True, "b"])),
        gather_equals_atomics_bit_for_bit=bool(np.array_equal(x[True, "a"], x[False, "a"])))
    print(json.dumps(agree))
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    out = ROOT / "docs" / "benchmarks" / f"jacobi_gather_{a.device.split(':')[0]}.json"
    out.write_text(json.dumps(dict(device=dev, frames=a.frames, command="python benchmarks/jacobi_gather.py "
                                   f"--device {a.device} --frames {a.frames}", rows=rows, agreement=agree), indent=1))
    print(json.dumps(dict(device=dev, out=str(out.relative_to(ROOT)))))


if __name__ == "__main__":
    main()
