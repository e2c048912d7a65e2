"""Markdown of the hard-case table (docs/contact.md, "Hard cases") from a JSON that
benchmarks/hard_contact.py wrote with ``--methods vertex,opt,multires,default`` (printed).

    python benchmarks/hard_contact_md.py [docs/benchmarks/hard_contact_cpu.json]
"""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def cell(r, keys):
    out = []
    for k in keys:
        n, um = r[f"{k}_count"], r[f"{k}_max_um"]
        out.append("0" if n == 0 else f"{n} / {um:.1f}")
    return " ; ".join(out)


def main():
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "benchmarks" / "hard_contact_cpu.json"
    d = json.loads(path.read_text())
    by = {}
    for r in d["rows"]:
        by.setdefault((r["case"], r["site"], r["start_mm"]), {})[r["method"]] = r
    print(f"{d.get('device_name', d.get('device'))}; {d['frames']} frames; last frame; cells: count / max um ('0': none)\n")
    print("| case | site | start | vertex: order 9 ; object ; check | opt: order 9 ; object ; check | multires (paper): "
          "order 5 ; order 9 ; object ; check | default: order 5 ; order 9 ; object ; check | default, last 4 frames "
          "(worst count: order 5 / 9 / object / check) | max disp mm (paper / default) | ms (paper / default) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    clean = 0
    for (case, site, start), m in by.items():
        v, o, p, df = (m.get(k) for k in ("vertex", "opt", "multires", "default"))
        if df is None or p is None:
            continue
        dcell = cell(df, ("skin", "dense", "obj", "check"))
        zero = all(df[f"{k}_count"] == 0 for k in ("skin", "dense", "obj", "check"))
        clean += zero
        hold = f"{df['hold_skin']} / {df['hold_dense']} / {df['hold_obj']} / {df['hold_check']}"
        print(f"| {case} | {site} | {'deep' if start < 0 else 'press'} | "
              f"{cell(v, ('dense', 'obj', 'check')) if v else '-'} | {cell(o, ('dense', 'obj', 'check')) if o else '-'} | "
              f"{cell(p, ('skin', 'dense', 'obj', 'check'))} | {'**' + dcell + '**' if zero else dcell} | {hold} | "
              f"{p['max_disp_mm']:.1f} / {df['max_disp_mm']:.1f} | {p['ms_per_frame']:.0f} / {df['ms_per_frame']:.0f} |")
    print(f"\ndefault clean by all four at the last frame: {clean} of {len(by)}")


if __name__ == "__main__":
    main()
