"""Merge `physhand bench accuracy` runs of the same settings over different workloads into one result.

    python benchmarks/accuracy_merge.py OUT_DIR RUN.json [RUN.json ...]

A sweep split by workload (``--workloads W``, one run per call or per process: the H200's ten-minute
calls, a many-core host's cores) is one sweep: the rows are joined, the settings re-summarised
(``summarize_points``: mean ms over all workloads, the deepest residue of either measure, the
Pareto flags) and the plot redrawn. Writes ``OUT_DIR/accuracy_<device>.csv``, ``.json`` and ``.png``
as ``physhand bench accuracy`` writes them (``bench.runs.write_sweep``), and prints its summary line
(the front, ``Config()``'s place, the cheapest settings at zero). The runs must share the device,
frames and repeats.
"""

import json
import sys
from pathlib import Path

from physhand_mj.bench import accuracy as acc
from physhand_mj.bench.runs import write_sweep


def merge(paths) -> dict:
    """The runs' JSONs joined: (dev, device_label, frames, repeats, workloads in the sweep's order, heldout,
    points, rows)."""
    runs = [json.loads(Path(p).read_text()) for p in paths]
    keys = {(r["device"], r["device_name"], r["frames"], r["repeats"], r["hold_frames"]) for r in runs}
    if len(keys) != 1:
        raise ValueError(f"the runs differ in device, frames, repeats or held frames: {sorted(keys)}")
    workloads = [w for r in runs for w in r["workloads"]]
    if len(set(workloads)) != len(workloads):
        raise ValueError(f"a workload is in two runs: {sorted(w for w in workloads if workloads.count(w) > 1)}")
    order = {w: k for k, w in enumerate(acc.WORKLOADS)}  # the sweep's own order where it has them
    workloads.sort(key=lambda w: order.get(w, len(order)))
    points = acc.sweep_points()
    rank = {p.name: k for k, p in enumerate(points)}
    rows = sorted((row for r in runs for row in r["rows"]),
                  key=lambda row: (rank.get(row["point"], len(rank)), workloads.index(row["workload"])))
    missing = {row["point"] for row in rows} - set(rank)
    if missing:
        raise ValueError(f"settings not in this code's sweep: {sorted(missing)}")
    points = [p for p in points if any(row["point"] == p.name for row in rows)]
    first = runs[0]
    return dict(dev=first["device"], device_label=first["device_name"], frames=first["frames"], repeats=first["repeats"], workloads=workloads,
                heldout={k: v for r in runs for k, v in r.get("heldout", {}).items()}, points=points, rows=rows)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    print(json.dumps(write_sweep(sys.argv[1], **merge(sys.argv[2:]))))


if __name__ == "__main__":
    main()
