"""Markdown tables of a `physhand bench accuracy` result (docs/accuracy.md).

    python benchmarks/accuracy_md.py [docs/benchmarks/accuracy_cpu.json]

Prints the held-out workloads (case, the bones' clearance), the cheapest settings at zero by every
measure, the Pareto points (on the front of either measure against ms per frame), then every setting,
then the per-workload figures of every setting.
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

    for w, h in d.get("heldout", {}).items():
        print(f"- `{w}`: {h['case']}; bones {h['clearance_mm']:.2f} mm clear ({'feasible' if h['feasible'] else 'infeasible'})")
    if d.get("heldout"):
        print()

    def zero(p):  # (results written before the zero column: from the depths)
        return p.get("zero", p["finite"] and p["skin_um"] == 0 and p["object_um"] == 0)

    for label, sel in (("all settings", lambda p: True),
                       ("10 substeps, 1 iteration", lambda p: p["substeps"] == 10 and p["iterations"] == 1)):
        z = [p for p in pts if zero(p) and sel(p)]
        print(f"Cheapest at zero by every measure ({label}): " + (f"{z[0]['point']}, {z[0]['ms_per_frame']:.1f} ms"
                                                               if z else "none"))
    print()

    def mark(p):
        return ", ".join(k for k, key in (("skin", "pareto_skin"), ("object", "pareto_object"), ("both", "pareto_both"))
                         if p[key]) or "-"

    def line(p):
        star = " (Config())" if p["default"] else ""
        return (f"| {p['point']}{star} | {p['ms_per_frame']:.1f} | {p['skin_um']:.4g} | {p['object_um']:.4g} | "
                f"{p['skin_count']} / {p['object_count']} | {'yes' if zero(p) else '-'} | {mark(p)} |")

    head = ("| setting | ms/frame | skin samples in object, max um | object points in skin, max um | "
            "counts at the end (skin / object) | zero | front |\n|---|---|---|---|---|---|---|")
    print("Pareto points\n\n" + head)
    for p in pts:
        if p["pareto_skin"] or p["pareto_object"]:
            print(line(p))
    print("\nAll settings\n\n" + head)
    for p in pts:
        print(line(p))
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
