"""Markdown of Table 2 from docs/benchmarks/hoi_table2_{cpu,cuda}.json beside the paper's numbers
(printed; pasted into docs/hoi.md). Run after benchmarks/hoi_table2.py on each device."""

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# The paper's Table 2 (count / max um / avg um per strategy; contact ms per frame on their
# i7-12700 CPU and RTX 3080 Ti GPU: vertex CPU, opt CPU, multires CPU / GPU)
PAPER = {
    "glass1": [(46285, 459.1479, 114.9909), (156, 6.2744, 1.9033), (3, 0.2956, 0.2289), ("22", "246", "2,517", "27")],
    "glass2": [(63013, 442.6264, 206.9566), (158, 3.5655, 1.9978), (1, 0.0500, 0.0500), ("21", "243", "2,502", "27")],
    "toothpaste": [(27435, 2313.6602, 270.8561), (30, 7.4098, 1.7885), (1, 0.0139, 0.0139), ("21", "169", "2,462", "26")],
    "phone": [(164933, 1916.7412, 70.8230), (2, 1.3571, 0.7542), (1, 0.0103, 0.0103), ("15", "227", "1,095", "12")],
    "apple": [(37927, 189.9071, 78.8565), (268, 3.7722, 1.0504), (0, 0, 0), ("21", "220", "1,995", "24")],
    "bowl": [(32120, 3129.6544, 845.0303), (190, 260.9675, 35.4007), (11, 0.0427, 0.0093), ("18", "145", "1,480", "16")],
    "box": [(58827, 989.9247, 133.4961), (820, 0.4664, 0.0110), (7, 0.0050, 0.0016), ("17", "201", "1,073", "12")],
}
METHODS = ("vertex", "opt", "multires", "default")


def cell(r, a, b, c=None):
    if r is None:
        return "-"
    if c is None:
        return f"{r[a]} / {r[b]:.3g}"
    return f"{r[a]} / {r[b]:.3g} / {r[c]:.3g}"


def main():
    runs = {}
    for d in ("cpu", "cuda"):
        f = ROOT / "docs" / "benchmarks" / f"hoi_table2_{d}.json"
        if f.exists():
            run = json.loads(f.read_text())
            if run["rows"] and "dense_count" in run["rows"][0]:  # runs before both measures are left out
                runs[d] = run
    devs = list(runs)
    idx = {(d, r["scene"], r["contact"]): r for d, run in runs.items() for r in run["rows"]}
    print("; ".join(f"{d.upper()}: {run['device']}" for d, run in runs.items()) + ". Count / max um / avg um over "
          "the 10 substeps of frame 36 (the paper's way); order 9 and object points in the skin at the end of frame 36 "
          "(count / max um); check points: the denser object points the contact never uses "
          "(Contact.check_points; '-': not measured in that run); full frame ms (solver + contact + write-back) and, in brackets, the contact's share.\n")
    cols = [f"{d.upper()}: {c}" for d in devs for c in ("count / max / avg", "order 9", "object in skin", "check points",
                                                       "ms/frame (contact)")]
    print("| scene (initial, undeformed) | method | " + " | ".join(cols) + " | paper: count / max / avg | paper contact ms CPU / GPU |")
    print("|---|---|" + "---|" * len(cols) + "---|---|")
    for scene, paper in PAPER.items():
        for k, s in enumerate(METHODS):
            rows = [idx.get((d, scene, s)) for d in devs]
            if not rows or rows[0] is None:
                continue
            c = rows[0]
            head = (f"{scene} ({c['initial_count']} samples, {c['initial_max_um'] / 1e3:.2f} mm; "
                    f"{c.get('initial_obj_count', '-')} object points)") if k == 0 else ""
            t = paper[3]
            if s == "default":
                pcell, ptime = "-", "-"
            else:
                pc, pm, pa = paper[k]
                pcell = f"{pc} / {pm:.4g} / {pa:.4g}"
                ptime = {"vertex": f"{t[0]} / -", "opt": f"{t[1]} / -", "multires": f"{t[2]} / {t[3]}"}[s]
            cells = []
            for r in rows:
                cells += [cell(r, "count", "max_um", "avg_um"), cell(r, "dense_count", "dense_max_um"),
                          cell(r, "obj_count", "obj_max_um"),
                          cell(r, "check_count", "check_max_um") if r and "check_count" in r else "-",
                          f"{r['ms_per_frame']:.1f} ({r['contact_ms']:.1f})" if r else "-"]
            print(f"| {head} | {s} | " + " | ".join(cells) + f" | {pcell} | {ptime} |")


if __name__ == "__main__":
    main()
