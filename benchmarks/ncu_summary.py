"""Per-launch figures from Nsight Compute's raw CSV (``ncu --import R.ncu-rep --page raw --csv``), as
one JSON document: duration, warp instructions, threads active per warp instruction (SIMT
efficiency = that / 32), issue slots used, eligible and active warps, registers, and the largest
stall reasons (cycles a warp waits per issued instruction). ``benchmarks/gpu_session.sh s43_c``
writes the CSV for one timed frame of the bowl batch's decision-point launches.

    python benchmarks/ncu_summary.py RAW.csv [--out docs/benchmarks/ncu_decide_bowl_1024.json] [--note TEXT]
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

FIELDS = {  # key: ncu metric (the duration scaled to ms by its unit row)
    "duration_ms": "gpu__time_duration.sum",
    "warp_instructions": "smsp__inst_executed.sum",
    "threads_per_warp_instruction": "smsp__thread_inst_executed_per_inst_executed.ratio",
    "issue_active_pct": "smsp__issue_active.avg.pct_of_peak_sustained_active",
    "eligible_warps_per_scheduler": "smsp__warps_eligible.avg.per_cycle_active",
    "active_warps_pct": "sm__warps_active.avg.pct_of_peak_sustained_active",
    "registers": "launch__registers_per_thread",
    "local_frame_bytes": "launch__stack_size",
    "shared_bytes_per_block": "launch__shared_mem_per_block_static",
}
TO_MS = {"ns": 1e-6, "nsecond": 1e-6, "us": 1e-3, "usecond": 1e-3, "ms": 1.0, "msecond": 1.0, "s": 1e3, "second": 1e3}
STALL = "smsp__average_warps_issue_stalled_"


def _num(s: str) -> float:
    s = s.replace(",", "").strip()
    return float(s) if s else float("nan")


def summarise(path: Path) -> list[dict]:
    rows = list(csv.reader(path.open()))
    head, units = rows[0], rows[1]
    out = []
    for r in rows[2:]:
        row = {"kernel": r[head.index("Kernel Name")] if "Kernel Name" in head else ""}
        for key, name in FIELDS.items():
            if name in head:
                v = _num(r[head.index(name)])
                if key == "duration_ms":
                    unit = units[head.index(name)].strip().lower()
                    if unit not in TO_MS:
                        raise ValueError(f"{name}: unknown unit {unit!r} in {path}")
                    v *= TO_MS[unit]
                if key == "shared_bytes_per_block" and units[head.index(name)].lower().startswith("k"):
                    v *= 1024
                row[key] = round(v, 4)
        stalls = {n[len(STALL):].replace("_per_issue_active.ratio", ""): _num(r[i]) for i, n in enumerate(head)
                  if n.startswith(STALL) and n.endswith("_per_issue_active.ratio") and r[i].strip()}
        row["stalls_per_issue"] = {k: round(v, 3) for k, v in sorted(stalls.items(), key=lambda kv: -kv[1])[:6]}
        out.append(row)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("csv", help="ncu --page raw --csv output")
    p.add_argument("--out", default=None, help="JSON to write (default: print)")
    p.add_argument("--note", default="", help="what was profiled (kept in the JSON)")
    a = p.parse_args()
    rows = summarise(Path(a.csv))
    heavy = [r for r in rows if r.get("duration_ms", 0) > 0.5]
    doc = dict(note=a.note, launches=len(rows), heavy_launches=len(heavy),
               heavy_ms=round(sum(r["duration_ms"] for r in heavy), 3),
               all_ms=round(sum(r.get("duration_ms", 0) for r in rows), 3), rows=rows)
    text = json.dumps(doc, indent=1)
    if a.out:
        Path(a.out).write_text(text + "\n")
        print(f"wrote {a.out}")
    for r in rows:
        print(r.get("duration_ms"), r.get("warp_instructions"), r.get("threads_per_warp_instruction"),
              r.get("issue_active_pct"), list(r["stalls_per_issue"].items())[:3])


if __name__ == "__main__":
    main()
