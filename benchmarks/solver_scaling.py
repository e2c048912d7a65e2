"""How the XPBD frame time grows with the hand's mesh size (no contact, 10 substeps x 1 iteration).

Three MyoHand resolutions (2,500 / 5,000 embedded / 10,000 skin vertices; the non-embedded ones are
built once with the build extra and cached under $PHYSHAND_CACHE). Each result names its device.
Writes docs/benchmarks/solver_scaling_<device>.json; `--plot` draws docs/images/solver_scaling.png
from every such JSON present.
Run: python benchmarks/solver_scaling.py [--device cpu|cuda] [--steps N] [--plot]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from physhand_mj.bench import bench_solver

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks"
RESOLUTIONS = (2500, 5000, 10000)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    p.add_argument("--steps", type=int, default=100, help="timed frames per resolution")
    p.add_argument("--plot", action="store_true", help="only redraw the plot from the saved JSON files")
    args = p.parse_args()
    if not args.plot:
        rows = []
        for r in RESOLUTIONS:
            row = bench_solver(device=args.device, frames=args.steps, resolution=r)
            print(json.dumps(row), flush=True)
            rows.append(row)
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / f"solver_scaling_{args.device.split(':')[0]}.json").write_text(json.dumps(rows, indent=1))
    plot()


def plot() -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for f in sorted(OUT.glob("solver_scaling_*.json")):
        rows = json.loads(f.read_text())
        name = rows[0]["device_name"].split(",")[0].rstrip(")") + ")"
        ax.plot([r["vertices"] for r in rows], [r["ms_per_frame_median"] for r in rows], "o-",
                label=name + ": step()")
        if rows[0].get("graph_ms_per_frame"):
            ax.plot([r["vertices"] for r in rows], [r["graph_ms_per_frame"] for r in rows], "s--",
                    label=name + ": CUDA graph only")
        for r in rows:
            ax.annotate(f"{r['skin_vertices']} skin / {r['tets'] // 1000}k tets", (r["vertices"], r["ms_per_frame_median"]),
                        fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("vertices (skin + flesh + skeleton)")
    ax.set_ylabel("ms per 5 ms frame (median)")
    ax.set_title("XPBD frame, 10 substeps x 1 iteration, no contact")
    for target, text in ((25, "CPU target 25 ms"), (0.4, "GPU target 0.4 ms")):
        ax.axhline(target, color="grey", ls=":", lw=1)
        ax.annotate(text, (ax.get_xlim()[0], target), fontsize=7, color="grey", va="bottom")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "images" / "solver_scaling.png", dpi=110)


if __name__ == "__main__":
    main()
