"""Held-out contact: random objects at random skin sites and depths, pass rate by four measures (issue 51).

    python benchmarks/heldout.py [--device cpu|cuda] [--seed 0] [--cases 40] [--frames 20] [--config JSON]

The cases are physhand_mj/bench/heldout.py's (convex and non-convex meshes, 1 and 0.5 mm plates,
1.5-3 mm rods, 1 mm shells, sharp cones and wedges; any skin vertex, tilted up to 30 degrees,
0.5-4 mm deep, pressed in over half the frames or starting there, then held), run with
``Config(device, **config)``. A case passes when it stays finite and all four measures are zero at
the last frame and in every held frame; a case with a bone inside the object or closer than 0.5 mm
to it is infeasible (no penetration-free skin) and counted apart. Prints one line per case and
writes docs/benchmarks/heldout_<device>.json and .md (the markdown: the pass rate, the failures by
kind and every failing or infeasible case).
"""

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import run_case  # noqa: E402
from physhand_mj.bench.heldout import CLEARANCE_MM, KINDS, generate, verdict  # noqa: E402


def row_of(h, v: dict, ms: float) -> dict:
    return dict(case=h.case.name, kind=h.kind, shape=h.shape, body=h.body, vertex=h.vertex,
                depth_mm=round(h.case.depth * 1e3, 2), start="embedded" if h.embedded else "pressed",
                clearance_mm=round(h.clearance_mm, 2), feasible=h.feasible, median_ms=round(ms, 1), **v)


def worst(v: dict) -> str:
    """'skin5 3 / 41.2 um, object 1 / 12.0 um': the failing measures' held-frame worst count / depth."""
    parts = [f"{k} {m['held_count']} / {m['held_max_um']:.1f} um" for k, m in v["measures"].items() if m["held_count"]]
    return ", ".join(parts + ([] if v["finite"] else ["not finite"])) or "0"


def markdown(res: dict) -> str:
    s = res["summary"]
    options = json.dumps(res["config"]) if res["config"] else "none: Config()"
    lines = [f"Held-out contact ({res['device']}; seed {res['seed']}, {res['cases']} cases, {res['frames']} frames, "
             f"held from frame {res['held_from']}; Config options {options})", "",
             f"**Pass rate: {s['passed']} / {s['feasible']} feasible cases** ({s['pass_rate'] * 100:.0f} %); "
             f"{s['infeasible']} infeasible (a bone within {CLEARANCE_MM} mm of the object), "
             f"{s['infeasible_passed']} of them at zero anyway.", "",
             "| kind | feasible | passed | failed measures (cases) |", "|---|---|---|---|"]
    for k in KINDS:
        rows = [r for r in res["rows"] if r["kind"] == k and r["feasible"]]
        fails = Counter(m for r in rows for m in r["failed"])
        lines.append(f"| {k} | {len(rows)} | {sum(r['passed'] for r in rows)} | "
                     f"{', '.join(f'{m} {c}' for m, c in sorted(fails.items())) or '-'} |")
    bad = [r for r in res["rows"] if not r["passed"] or not r["feasible"]]
    if bad:
        lines += ["", "| case | shape | site | depth mm | start | bone clearance mm | held-frame worst (count / depth) "
                  "| max disp mm |", "|---|---|---|---|---|---|---|---|"]
        for r in bad:
            lines.append(f"| {r['case']}{'' if r['feasible'] else ' (infeasible)'} | {r['shape']} | {r['body']} "
                         f"v{r['vertex']} | {r['depth_mm']} | {r['start']} | {r['clearance_mm']} | {worst(r)} | "
                         f"{r['max_disp_mm']} |")
    return "\n".join(lines) + "\n"


def _commit() -> str | None:
    """The checkout's commit (short hash, "+" if it has local changes), or None outside git."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+" if dirty else "")


def dump(res: dict) -> str:
    """The results as JSON, one line per case."""
    head = json.dumps({k: v for k, v in res.items() if k != "rows"}, indent=1)
    return head[:-2] + ',\n "rows": [\n' + ",\n".join("  " + json.dumps(r) for r in res["rows"]) + "\n ]\n}\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--seed", type=int, default=0, help="generator seed (integer; case i draws from [seed, i])")
    ap.add_argument("--cases", type=int, default=40, help="number of cases (count; kinds in turn)")
    ap.add_argument("--frames", type=int, default=20, help="5 ms frames per case; the press takes the first half, "
                    "the rest are held frames")
    ap.add_argument("--config", default="{}", help="Config options as JSON, any group's keys flat "
                    "(Config.from_dict; default: the shipped Config())")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/heldout_<device>.json; "
                    "the markdown beside it, .md)")
    a = ap.parse_args()
    if a.frames < 4:
        ap.error("--frames must be at least 4 (a press and held frames)")
    from tqdm import tqdm

    over = json.loads(a.config)
    cfg = ph.Config.from_dict(dict(over, device=a.device))
    asset = ph.load_asset()
    press = a.frames // 2
    cases = generate(a.seed, a.cases, asset, press_frames=press)
    rows, t0 = [], time.perf_counter()
    for h in tqdm(cases, desc="held-out cases", file=sys.stderr):
        r = run_case(h.case, cfg, frames=a.frames, asset=asset)
        v = verdict(h, r)
        rows.append(row_of(h, v, float(np.median(r["ms"][1:]))))
        tqdm.write(f"{h.label}: clearance {h.clearance_mm:.2f} mm, "
                   f"{'pass' if v['passed'] else 'FAIL ' + worst(v)}{'' if h.feasible else ' (infeasible)'}",
                   file=sys.stderr)
        del r
    feasible = [r for r in rows if r["feasible"]]
    passed = sum(r["passed"] for r in feasible)
    summary = dict(feasible=len(feasible), passed=passed, pass_rate=round(passed / max(len(feasible), 1), 4),
                   infeasible=len(rows) - len(feasible),
                   infeasible_passed=sum(r["passed"] for r in rows if not r["feasible"]),
                   failed_by_measure=dict(Counter(m for r in feasible for m in r["failed"])),
                   failed_by_kind=dict(Counter(r["kind"] for r in feasible if not r["passed"])),
                   all_finite=all(r["finite"] for r in rows), wall_s=round(time.perf_counter() - t0, 1))
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    res = dict(device=dev, commit=_commit(), seed=a.seed, cases=a.cases, frames=a.frames, held_from=press, config=over,
               clearance_mm=CLEARANCE_MM, summary=summary, rows=rows)
    out = Path(a.out) if a.out else Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / \
        f"heldout_{a.device.split(':')[0]}.json"
    out.write_text(dump(res))
    out.with_suffix(".md").write_text(markdown(res))
    print(markdown(res))
    print(f"{dev}; wrote {out} and {out.with_suffix('.md').name}")


if __name__ == "__main__":
    main()
