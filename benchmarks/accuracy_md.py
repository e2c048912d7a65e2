"""Markdown tables of a `physhand bench accuracy` result (docs/accuracy.md).

    python benchmarks/accuracy_md.py [docs/benchmarks/accuracy_cpu.json]

Prints the Pareto points (on the front of either measure against ms per frame), then every setting,
then the per-workload figures of the settings on a front.
"""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main():
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "benchmarks" / "accuracy_cpu.json"
    d = json.loads(path.read_text())
    pts = sorted(d["points"], key=lambda p: p["ms_per_frame"])
    print(f"{d['device_name']}; {len(pts)} settings x {len(d['workloads'])} workloads ({', '.join(d['workloads'])}), "
          f"{d['frames']} frames, {d['repeats']} timing passes; depths: worst of the last {d['hold_frames']} frames\n")

    def mark(p):
        return ", ".join(k for k, key in (("skin", "pareto_skin"), ("object", "pareto_object"), ("both", "pareto_both"))
                         if p[key]) or "-"

    head = ("| setting | ms/frame | skin samples in object, max um | object points in skin, max um | "
            "counts at the end (skin / object) | front |\n|---|---|---|---|---|---|")
    print("Pareto points\n\n" + head)
    for p in pts:
        if p["pareto_skin"] or p["pareto_object"]:
            star = " (Config())" if p["default"] else ""
            print(f"| {p['point']}{star} | {p['ms_per_frame']:.1f} | {p['skin_um']:.4g} | {p['object_um']:.4g} | "
                  f"{p['skin_count']} / {p['object_count']} | {mark(p)} |")
    print("\nAll settings\n\n" + head)
    for p in pts:
        star = " (Config())" if p["default"] else ""
        print(f"| {p['point']}{star} | {p['ms_per_frame']:.1f} | {p['skin_um']:.4g} | {p['object_um']:.4g} | "
              f"{p['skin_count']} / {p['object_count']} | {mark(p)} |")
    ws = d["workloads"]
    print("\nPer workload (ms / skin max um / object max um, worst of the held frames)\n")
    print("| setting | " + " | ".join(ws) + " |\n|---|" + "---|" * len(ws))
    rows = {(r["point"], r["workload"]): r for r in d["rows"]}
    for p in pts:
        cells = [rows[p["point"], w] for w in ws]
        print(f"| {p['point']} | " + " | ".join(f"{r['ms_per_frame']:.1f} / {r['hold_skin_max_um']:.3g} / "
                                                f"{r['hold_object_max_um']:.3g}" for r in cells) + " |")


if __name__ == "__main__":
    main()
