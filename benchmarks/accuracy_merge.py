"""Merge `physhand bench accuracy` runs of the same settings over different workloads into one result.

    python benchmarks/accuracy_merge.py OUT_DIR RUN.json [RUN.json ...]

A sweep split by workload (``--workloads W``, one run per call or per process: the H200's ten-minute
calls, a many-core host's cores) is one sweep: the rows are joined, the settings re-summarised
(``summarize_points``: mean ms over all workloads, the deepest residue of either measure, the
Pareto flags) and the plot redrawn. Writes ``OUT_DIR/accuracy_<device>.json`` and ``.png`` in the
shape ``physhand bench accuracy`` writes, and prints the summary line (the front, ``Config()``'s
place, the cheapest settings at zero). The runs must share the device, frames and repeats.
"""

import json
import sys
from pathlib import Path

from physhand_mj.bench import accuracy as acc
from physhand_mj.types import Config


def merge(paths) -> dict:
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
    names = set(rank)
    missing = {row["point"] for row in rows} - names
    if missing:
        raise ValueError(f"settings not in this code's sweep: {sorted(missing)}")
    points = [p for p in points if any(row["point"] == p.name for row in rows)]
    first = runs[0]
    return dict(device=first["device"], device_name=first["device_name"], frames=first["frames"],
                repeats=first["repeats"], workloads=workloads, hold_frames=first["hold_frames"],
                heldout={k: v for r in runs for k, v in r.get("heldout", {}).items()},
                points=acc.summarize_points(points, rows), rows=rows)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    d = merge(sys.argv[2:])
    tag = d["device"].split(":")[0]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"accuracy_{tag}.json").write_text(json.dumps(d, indent=1))
    table = d["points"]
    acc.plot_front(table, out / f"accuracy_{tag}.png",
                   f"physhand bench accuracy: {len(table)} settings x {len(d['workloads'])} workloads, "
                   f"{d['frames']} frames, {d['device_name']}")
    default = next((p for p in table if p["default"]), None)
    zero = {k: (None if p is None else dict(point=p["point"], ms_per_frame=p["ms_per_frame"]))
            for k, p in (("any", acc.cheapest_zero(table)),
                         ("default_substeps", acc.cheapest_zero(table, substeps=Config().substeps)))}
    print(json.dumps(dict(device=d["device"], workloads=d["workloads"], repeats=d["repeats"],
                          pareto=[p["point"] for p in sorted(table, key=lambda p: p["ms_per_frame"]) if p["pareto_both"]],
                          default_on_front=None if default is None else default["pareto_both"],
                          cheapest_zero=zero, json=str(out / f"accuracy_{tag}.json"))))


if __name__ == "__main__":
    main()
