"""Peers side by side on the CPU, in one run: physhand_mj's solver and MuJoCo's native flex (dim 3).

    python benchmarks/peers/run_cpu.py [--frames 20] [--depth 0.003] [--out docs/benchmarks/peers_cpu.json]
    python benchmarks/peers/run_cpu.py --plot-only          # redraw docs/images/peers_cpu.png from the JSON

The same body (the embedded hand's tet mesh: 10,480 vertices, skeleton pinned) and the same
objects on the same path (common.py): a 10 mm sphere on the palm, the 30-degree cone mesh's tip at
the index fingertip, the 30-degree knife-edge mesh on the palm, each from ``start`` outside the skin
to ``depth`` into the rest skin over ``press-frames`` frames, then held. Per solver and object: ms per 5 ms frame
(median over frames; physhand_mj's first two frames, which compile its kernels, excluded; MuJoCo
compiles its model before the loop) and both penetration measures after every frame (order-5 and
order-9 skin samples inside the object, object surface points inside the closed skin), with their
final and largest values. MuJoCo runs with the settings of VARIANTS below. The committed JSON used
``--frames 8 --start 0 --press-frames 6`` (the object starts touching and is 3 mm in after 6 frames)
to keep MuJoCo's part short.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import Measure, cases, object_path, ph  # noqa: E402
from mujoco_flex import RADIUS, YOUNG, FlexRun  # noqa: E402

from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import run_case  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "benchmarks" / "peers_cpu.json"
PNG = ROOT / "docs" / "images" / "peers_cpu.png"
# MuJoCo settings. "discrete" is the matched one (poisson 0.495, 0.5 ms steps, flex elasticity
# implicit) but on the hand its steps with contact took minutes (docs/peers.md); "euler" runs:
# 0.1 ms steps, poisson 0.3 (Euler diverged at 0.25 ms), contact as stiff as the step allows.
VARIANTS = {"euler": dict(integrator="euler", steps=50, poisson=0.3, solref=(0.0002, 1.0)),
            "discrete": dict(integrator="discrete", steps=10, solref=(0.001, 1.0))}
KEYS = ("skin_count", "skin_max_um", "dense_count", "dense_max_um", "obj_count", "obj_max_um")


def summary(rows: dict, ms: list, skip: int) -> dict:
    """Final and largest of each measure over the frames, and the median ms per frame."""
    out = {"ms_per_frame": float(np.median(ms[skip:])), "ms_frames": [round(float(v), 2) for v in ms]}
    for k in KEYS:
        v = np.asarray(rows[k], float)
        out[k + "_final"] = float(v[-1]) if "count" not in k else int(v[-1])
        out[k + "_peak"] = float(v.max()) if "count" not in k else int(v.max())
    out["per_frame"] = {k: [round(float(x), 2) for x in rows[k]] for k in KEYS}
    return out


def run_physhand(asset, case, frames: int) -> dict:
    r = run_case(case, ph.Config(device="cpu"), frames=frames, check_order=9, asset=asset)
    pos, quat, _ = object_path(asset, case, frames)
    if not (np.allclose(pos[-1], r["object_pos"], atol=1e-9) and np.allclose(quat, r["object_quat"], atol=1e-9)):
        raise RuntimeError(f"{case.name}: common.object_path disagrees with run_case's object path")
    rows = {k: r[k] for k in KEYS}
    out = summary(rows, list(r["ms"]), skip=2)
    out.update(solver="physhand_mj", finite=bool(r["finite"]), max_disp_mm=float(r["max_disp_mm"][-1]))
    return out, r


def run_flex(asset, case, frames: int, meas: Measure, label: str, **kw) -> dict:
    fr = FlexRun(asset, case, frames=frames, **kw)
    rows = {k: [] for k in KEYS}
    ms, ncon, unstable, finite = [], [], False, True
    for k in range(frames):
        o = fr.frame(k)
        ms.append(o["ms"])
        ncon.append(o["ncon"])
        unstable |= o["unstable"]
        finite &= o["finite"]
        for key, v in meas(fr.x, fr.path[k], fr.quat).items():
            rows[key].append(v)
        print(f"  {label} frame {k}: {o['ms']:.0f} ms, {o['ncon']} contacts, skin {rows['skin_count'][-1]} / "
              f"{rows['skin_max_um'][-1]:.0f} um, object in skin {rows['obj_count'][-1]} / "
              f"{rows['obj_max_um'][-1]:.0f} um", file=sys.stderr, flush=True)
    out = summary(rows, ms, skip=0)
    disp = np.linalg.norm(fr.x - np.asarray(asset.positions), axis=1)
    out.update(solver=label, finite=finite, unstable_warning=unstable, compile_s=round(fr.compile_s, 2),
               contacts_final=ncon[-1], max_disp_mm=float(disp.max() * 1e3), timestep_s=float(fr.model.opt.timestep),
               steps_per_frame=fr.steps, solref=[float(v) for v in fr.model.flex_solref[0]])
    return out


def plot(result: dict, path: Path = PNG) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    runs = result["runs"]
    objects = list(dict.fromkeys(r["object"] for r in runs))
    solvers = list(dict.fromkeys(r["solver"] for r in runs))
    colors = {"sphere": "tab:blue", "mesh_cone": "tab:red", "knife": "tab:green"}
    marks = dict(zip(solvers, "o^sDvP"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharex=True)
    for ax, key, title in ((axes[0], "skin_max_um_final", "skin samples inside the object (order 5)"),
                           (axes[1], "obj_max_um_final", "object points inside the closed skin")):
        for r in runs:
            ax.scatter(r["ms_per_frame"], max(r[key], 0.5), color=colors.get(r["object"], "k"),
                       marker=marks[r["solver"]], s=60)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(f"ms per 5 ms frame ({result['device'].split(' (')[0]})")
        ax.set_ylabel("deepest penetration at the end, um (0 drawn at 0.5)")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    handles = [plt.Line2D([], [], color="gray", marker=marks[s], ls="", label=s) for s in solvers]
    handles += [plt.Line2D([], [], color=colors.get(o, "k"), marker="o", ls="", label=o) for o in objects]
    axes[1].legend(handles=handles, fontsize=8, loc="center right")
    fig.suptitle(f"Peers on the hand's tet mesh, {result['frames']} frames, {result['depth_mm']} mm press; "
                 f"{result['device']}", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def table(result: dict) -> str:
    lines = ["| object | solver | ms / frame | skin order 5 (count / max um) | skin order 9 | object in skin | "
             "largest over the run (order 5 / object) |", "|---|---|---|---|---|---|---|"]
    for r in result["runs"]:
        lines.append(f"| {r['object']} | {r['solver']} | {r['ms_per_frame']:.1f} | {r['skin_count_final']} / "
                     f"{r['skin_max_um_final']:.0f} | {r['dense_count_final']} / {r['dense_max_um_final']:.0f} | "
                     f"{r['obj_count_final']} / {r['obj_max_um_final']:.0f} | {r['skin_max_um_peak']:.0f} / "
                     f"{r['obj_max_um_peak']:.0f} um |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--depth", type=float, default=0.003)
    ap.add_argument("--start", type=float, default=0.002, help="m outside the skin at frame 0")
    ap.add_argument("--press-frames", type=int, default=15)
    ap.add_argument("--objects", default="sphere,mesh_cone,knife")
    ap.add_argument("--mujoco", default="euler", help="MuJoCo variants: euler (runs), discrete (hangs, see docs)")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--plot-only", action="store_true")
    a = ap.parse_args()
    if a.plot_only:
        result = json.loads(Path(a.out).read_text())
        plot(result)
        print(table(result))
        return
    import mujoco
    import warp as wp

    asset = ph.load_asset()
    runs = []
    t0 = time.time()
    for case in [c for c in cases(a.depth, a.start, a.press_frames) if c.name in a.objects.split(",")]:
        print(f"{case.name}: physhand_mj", file=sys.stderr, flush=True)
        row, r = run_physhand(asset, case, a.frames)
        meas = Measure(asset, case)
        pos, quat, _ = object_path(asset, case, a.frames)
        check = meas(r["state"].x.numpy(), pos[-1], quat)  # the harness's measure on physhand's own result
        row["harness_check"] = check
        runs.append(dict(object=case.name, site=case.site, **row))
        for variant in a.mujoco.split(","):
            kw = VARIANTS[variant]
            label = f"mujoco_flex ({variant})"
            print(f"{case.name}: {label}", file=sys.stderr, flush=True)
            runs.append(dict(object=case.name, site=case.site, **run_flex(asset, case, a.frames, meas, label, **kw)))
    result = dict(
        device=device_name("cpu"), command="python benchmarks/peers/run_cpu.py " + " ".join(sys.argv[1:]),
        frames=a.frames, depth_mm=a.depth * 1e3, press_frames=a.press_frames, start_mm=a.start * 1e3,
        body=dict(vertices=int(asset.n_vertices), tets=int(len(asset.tets)), skin_triangles=int(len(asset.skin_faces)),
                  pinned_skeleton_vertices=int(np.sum(np.asarray(asset.layer) == ph.Layer.SKELETON))),
        versions=dict(mujoco=mujoco.__version__, warp=wp.config.version, python=platform.python_version()),
        mujoco_flex=dict(young_pa=YOUNG, radius_m=RADIUS, damping=0.0, variants={k: VARIANTS[k] for k in a.mujoco.split(",")}),
        physhand_config="Config(device='cpu') defaults: 10 substeps x 1 iteration, multires 21 x 2, features, side-aware",
        wall_s=round(time.time() - t0, 1), runs=runs)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=1) + "\n")
    plot(result)
    print(table(result))


if __name__ == "__main__":
    main()
