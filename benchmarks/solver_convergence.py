"""Which parallel scheme for the XPBD constraint projection? Convergence per iteration and per ms.

Two measurements on the embedded hand (CPU here; pass --device cuda on a GPU machine):

1. One substep after a sudden pose jump (the bones leap from the open pose to 40 % of the power
   grasp, which violates the flesh constraints by millimetres): the dimensionless XPBD residual
   RMS(C + alpha~ lambda) after k iterations, for coloured Gauss-Seidel and Jacobi with relaxation
   1.0 and 1.5.
2. The default regime (10 substeps x 1 iteration per 5 ms frame) while the hand closes to the power
   grasp over 25 frames: the residual at the end of each frame, averaged.

Writes docs/benchmarks/solver_convergence[_DEVICE].json and docs/images/solver_convergence.png.
Run: python benchmarks/solver_convergence.py [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import physhand_mj as ph
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose
from physhand_mj.solver import Solver, make_model
from physhand_mj.solver.diagnostics import residuals
from physhand_mj.types import Config, Scheme

ROOT = Path(__file__).resolve().parents[1]
SCHEMES = {"gauss-seidel (coloured)": dict(scheme=Scheme.COLORED),
           "jacobi w=1.0": dict(scheme=Scheme.JACOBI, relaxation=1.0),
           "jacobi w=1.5": dict(scheme=Scheme.JACOBI, relaxation=1.5)}


def jump_residual(asset, model, data, ids, device, iterations, **kw) -> dict:
    cfg = Config(device=device, substeps=1, frame_dt=0.0005, iterations=iterations, **kw)
    solver = Solver(make_model(asset, cfg), cfg)
    q_open, q_power = model.key("open").qpos, model.key("power").qpos
    bone_poses_at(model, data, q_open, ids)
    state = solver.make_state(*mount_pose(model, data))
    solver.set_body_poses(state, *bone_poses_at(model, data, q_open + 0.4 * (q_power - q_open), ids))
    solver.step(state)
    return residuals(solver.model, state, cfg)


def motion(asset, model, data, ids, device, iterations, frames=25, **kw) -> tuple[float, float]:
    cfg = Config(device=device, iterations=iterations, **kw)
    solver = Solver(make_model(asset, cfg), cfg)
    q_open, q_power = model.key("open").qpos, model.key("power").qpos
    bone_poses_at(model, data, q_open, ids)
    state = solver.make_state(*mount_pose(model, data))
    solver.step(state)  # compile / capture outside the timing
    res, elapsed = [], 0.0
    for f in range(frames):
        solver.set_body_poses(state, *bone_poses_at(model, data, q_open + (f + 1) / frames * (q_power - q_open), ids))
        t = time.perf_counter()
        solver.step(state)
        elapsed += time.perf_counter() - t
        res.append(residuals(solver.model, state, cfg)["all"])
    return float(np.mean(res)), elapsed / frames * 1e3


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    args = p.parse_args()
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    iters = [1, 2, 4, 8, 16, 32]
    out = {"device": args.device, "jump": {}, "motion": {}}
    for name, kw in SCHEMES.items():
        out["jump"][name] = [jump_residual(asset, model, data, ids, args.device, k, **kw)["all"] for k in iters]
        out["motion"][name] = {k: motion(asset, model, data, ids, args.device, k, **kw) for k in (1, 2, 4)}
        print(name, out["jump"][name], out["motion"][name], flush=True)
    out["iterations"] = iters
    suffix = "" if args.device == "cpu" else f"_{args.device.split(':')[0]}"
    (ROOT / "docs" / "benchmarks").mkdir(parents=True, exist_ok=True)
    (ROOT / "docs" / "benchmarks" / f"solver_convergence{suffix}.json").write_text(json.dumps(out, indent=1))
    if args.device == "cpu":
        plot(out, ROOT / "docs" / "images" / "solver_convergence.png")


def plot(out: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for name, r in out["jump"].items():
        a.loglog(out["iterations"], r, "o-", label=name)
    a.set_xlabel("iterations in one substep")
    a.set_ylabel("RMS XPBD residual (dimensionless)")
    a.set_title("after a pose jump (open -> 40 % power)")
    a.legend()
    for name, m in out["motion"].items():
        ks = sorted(m, key=int)
        b.plot([m[k][1] for k in ks], [m[k][0] for k in ks], "o-", label=name)
        for k in ks:
            b.annotate(f"{k} it", (m[k][1], m[k][0]), fontsize=7)
    b.set_xlabel(f"ms per 5 ms frame (10 substeps, {out['device']})")
    b.set_ylabel("mean RMS residual while closing")
    b.set_yscale("log")
    b.set_title("cost vs accuracy while the hand closes")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
