"""The paper's cone experiment (section 4.2, Fig. 7e/f): a 2,400-vertex sheet (edge + smoothness
constraints) falls on an analytic cone for 30 steps of 5 ms x 10 substeps, once per decision-point
strategy; after every substep 21 samples per triangle are checked for penetration.

Run:  python examples/cone_experiment.py [OUT_DIR] [--device cuda]
Success looks like: a table with one row per strategy (vertex leaves tens of penetrating samples
millimetres deep; opt and multires end at 0) and OUT_DIR/cone_experiment.png with the penetration
count and mean depth after every substep, plus OUT_DIR/cone_<strategy>.csv logs.
"""

import csv
import sys
from pathlib import Path

import numpy as np

from physhand_mj.bench import bench_cone

STRATEGIES = ("vertex", "opt", "multires")


def main(out: Path, device: str = "cpu", steps: int = 30) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    print(f"{'strategy':9s} {'final':>6s} {'max':>5s} {'mean':>7s} {'avg um':>9s} {'max um':>9s} {'ms/step':>8s}")
    for name in STRATEGIES:
        summary, log = bench_cone(name, device, steps)
        results[name] = (summary, log)
        with open(out / f"cone_{name}.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(log[0]))
            w.writeheader()
            w.writerows(log)
        print(f"{name:9s} {summary['penetration_count_final']:6d} {summary['penetration_count_max']:5d} "
              f"{summary['penetration_count_mean']:7.2f} {summary['penetration_avg_um_final']:9.3f} "
              f"{summary['penetration_max_um_final']:9.3f} {summary['ms_per_step']:8.2f}")
    plot(results, out / "cone_experiment.png")
    return results


def plot(results: dict, path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    for name, (summary, log) in results.items():
        i = np.arange(len(log))
        a.plot(i, [r["penetration_count"] for r in log], label=f"{name} ({summary['queries']} queries)")
        b.plot(i, [r["penetration_avg_um"] for r in log], label=name)
    a.set_xlabel("substep")
    a.set_ylabel("penetrating samples (of 21 per triangle)")
    a.set_title("penetration count (Fig. 7e)")
    b.set_xlabel("substep")
    b.set_ylabel("mean depth of penetrating samples (um)")
    b.set_yscale("symlog", linthresh=1.0)
    b.set_title("average penetration depth (Fig. 7f)")
    a.legend()
    fig.suptitle(f"cone experiment, {next(iter(results.values()))[0]['device_name'].split(',')[0]}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def test_final(tmp_path=None):
    res = main(Path(tmp_path or "example_out"), steps=12)
    final = {k: v[0]["penetration_count_final"] for k, v in res.items()}
    mean = {k: v[0]["penetration_count_mean"] for k, v in res.items()}
    assert final["multires"] == 0, final
    assert mean["vertex"] > 5 * max(mean["multires"], 0.1), mean
    assert all(v[0]["finite"] for v in res.values())


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    dev = sys.argv[sys.argv.index("--device") + 1] if "--device" in sys.argv else "cpu"
    if dev in args:
        args.remove(dev)
    main(Path(args[0] if args else "example_out"), dev)
