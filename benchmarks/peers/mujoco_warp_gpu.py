"""MuJoCo Warp's flex as a peer, on the GPU (measured on an H100: docs/peers.md).

    python benchmarks/peers/mujoco_warp_gpu.py --device cuda [--frames 8] [--variant euler] [--out docs/benchmarks/peers_mjwarp_cuda.json]

The scene is mujoco_flex.flex_spec's (the hand's tet mesh, the same objects on common.object_path),
compiled by MuJoCo and put on the device with ``mujoco_warp.put_model``; each 5 ms frame is
``steps`` calls of ``mujoco_warp.step`` with the mocap object moved between them. Timing excludes the
first frame (kernel compilation); both penetration measures come from common.Measure on the
vertices copied back after every frame (not timed). Where mujoco_warp is missing or rejects the
model (put_model raises NotImplementedError for features it lacks), it says so in one line and exits 2.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import Measure, cases, ph  # noqa: E402
from mujoco_flex import FlexRun  # noqa: E402
from run_cpu import KEYS, VARIANTS, summary, table  # noqa: E402

from physhand_mj.bench import device_name  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--start", type=float, default=0.0)
    ap.add_argument("--press-frames", type=int, default=6)
    ap.add_argument("--depth", type=float, default=0.003)
    ap.add_argument("--variant", default="euler", choices=sorted(VARIANTS))
    ap.add_argument("--out", default="docs/benchmarks/peers_mjwarp_cuda.json")
    ap.add_argument("--solver", default="cg", choices=["cg", "newton"],
                    help="MuJoCo's constraint solver: cg (default here: MuJoCo Warp's newton factorises the "
                         "dense nv x nv Hessian in one tile kernel, and for the hand's ~30k flex dofs that "
                         "kernel did not finish compiling in 4 minutes on an H100 machine)")
    ap.add_argument("--physhand", action="store_true",
                    help="also run physhand_mj (Config default on --device) on the same cases and schedule, in the same run")
    ap.add_argument("--workers", type=int, default=0,
                    help="compile every loaded Warp module in this many parallel processes after put_model "
                         "(wp.force_load; 0: Warp's default, modules compiled one by one at first use)")
    ap.add_argument("--smoke", action="store_true", help="allow a CPU device: a check that the script runs, not a measurement")
    a = ap.parse_args()
    try:
        import mujoco_warp as mjw
        import warp as wp
    except ImportError as e:
        sys.exit(print(f"mujoco_warp unavailable ({e}); pip install mujoco-warp on a GPU machine", file=sys.stderr) or 2)
    if not wp.get_device(a.device).is_cuda and not a.smoke:
        sys.exit(print(f"device '{a.device}' is not a CUDA device; MuJoCo Warp is measured on the GPU", file=sys.stderr) or 2)
    asset = ph.load_asset()
    runs = []
    for case in cases(a.depth, a.start, a.press_frames):
        fr = FlexRun(asset, case, frames=a.frames, **VARIANTS[a.variant])
        import mujoco

        fr.model.opt.solver = {"cg": mujoco.mjtSolver.mjSOL_CG, "newton": mujoco.mjtSolver.mjSOL_NEWTON}[a.solver]
        print(f"{case.name} {case.site}: nv {fr.model.nv}, solver {a.solver}", flush=True)
        try:
            with wp.ScopedDevice(a.device):
                m = mjw.put_model(fr.model)
                d = mjw.put_data(fr.model, fr.data)
                if a.workers and not runs:
                    t0 = time.perf_counter()
                    wp.force_load(device=a.device, max_workers=a.workers)
                    print(f"compiled the loaded Warp modules in {time.perf_counter() - t0:.0f} s ({a.workers} workers)",
                          flush=True)
        except NotImplementedError as e:
            sys.exit(print(f"mujoco_warp cannot take the flex scene: {e}", file=sys.stderr) or 2)
        meas = Measure(asset, case)
        rows = {k: [] for k in KEYS}
        ms = []
        graph = None  # one mjw.step captured as a CUDA graph (after the first frame compiled it), as
        # mujoco_warp's own examples run it; the object's mocap position goes up before each step
        for k in range(a.frames):
            p0 = fr.start if k == 0 else fr.path[k - 1]
            if k == 1 and wp.get_device(a.device).is_cuda:
                with wp.ScopedDevice(a.device), wp.ScopedCapture() as cap:
                    mjw.step(m, d)
                graph = cap.graph
            wp.synchronize_device(a.device)
            t = time.perf_counter()
            for j in range(fr.steps):
                d.mocap_pos.assign((p0 + (j + 1) / fr.steps * (fr.path[k] - p0))[None, None].astype(np.float32))
                if graph is None:
                    mjw.step(m, d)
                else:
                    wp.capture_launch(graph)
            wp.synchronize_device(a.device)
            ms.append((time.perf_counter() - t) * 1e3)
            print(f"{case.name} {case.site} frame {k}: {ms[-1]:.1f} ms", flush=True)
            x = d.flexvert_xpos.numpy().reshape(-1, 3)
            for key, v in meas(x, fr.path[k], fr.quat).items():
                rows[key].append(v)
        runs.append(dict(object=case.name, site=case.site, solver=f"mujoco_warp flex ({a.variant}, {a.solver})",
                         **summary(rows, ms, skip=1)))
    if a.physhand:  # the same work for physhand_mj on the same device (cases.run_case: its own ms timing)
        from physhand_mj.bench.cases import run_case

        for case in cases(a.depth, a.start, a.press_frames):
            r = run_case(case, ph.Config(device=a.device), frames=a.frames, check_order=9, asset=asset)
            runs.append(dict(object=case.name, site=case.site, solver="physhand_mj",
                             **summary({k: r[k] for k in KEYS}, list(r["ms"]), skip=2)))
    result = dict(device=device_name(a.device), command="python benchmarks/peers/mujoco_warp_gpu.py " + " ".join(sys.argv[1:]),
                  frames=a.frames, depth_mm=a.depth * 1e3, variant=VARIANTS[a.variant], runs=runs)
    Path(a.out).write_text(json.dumps(result, indent=1) + "\n")
    print(table(result))


if __name__ == "__main__":
    main()
