"""Thin walls pressed face-first into the hand (docs/contact.md "Thin walls"), with and without the
flesh following the contact near a wall (``Config.tuning.wall_carry``, 0.5 by default; solver/carry.py).

    python benchmarks/thin_walls.py [--device cpu|cuda] [--shares 0,0.5] [--out F.json]

The plates of tests/test_thin_walls.py and the wide ones that fold round their rims (a box plate
thinner than the skin, ``physhand_mj/bench/cases.py`` ``wall_case``: embedded from frame 0 or pressed
in from outside over 10 frames, then held), each run for its frames once per share. Reported per run:
the order-5 skin samples inside the plate in every frame, the worst count over the last 4 frames of
the four penetration measures (order-5 and order-9 skin samples inside, object and check points
inside the skin), the first frame from which all four stay 0, the bones' clearance from the plate
(mm; the skeleton and a lattice on its triangles, physhand_mj/bench/heldout.py) and the median frame
time (ms, after the first two). Writes docs/benchmarks/thin_walls_default_<device>.json (device named).
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import run_case, wall_case  # noqa: E402
from physhand_mj.bench.heldout import clearance_mm  # noqa: E402

MEASURES = ("skin_count", "dense_count", "obj_count", "check_count")
# (name, wall_case keywords, frames)
WALLS = [
    ("8 mm, palm, 4 mm embedded", dict(half=0.004, thick=0.001, depth=0.004), 16),
    ("16 mm, palm, 4 mm embedded", dict(half=0.008, thick=0.001, depth=0.004), 16),
    ("24 mm, palm, 4 mm embedded", dict(half=0.012, thick=0.001, depth=0.004), 16),
    ("30 mm, palm, 4 mm embedded", dict(half=0.015, thick=0.001, depth=0.004), 16),
    ("24 mm, palm, pressed 4 mm from 2 mm out, held", dict(half=0.012, thick=0.001, depth=0.004, start=0.002), 20),
    ("30 mm, palm, pressed 4 mm from 5 mm out, held", dict(half=0.015, thick=0.001, depth=0.004, start=0.005), 20),
    ("16 mm slanted 25 degrees, palm, 3 mm embedded", dict(half=0.008, thick=0.001, depth=0.003, tilt=25.0), 16),
    ("30 mm slanted 20 degrees, palm, pressed 4 mm from 2 mm out", dict(half=0.015, thick=0.001, depth=0.004,
                                                                       start=0.002, tilt=20.0), 20),
    ("24 mm across three proximal phalanges, 1.5 mm embedded", dict(half=0.012, thick=0.001, depth=0.0015,
                                                                  site="fingers"), 16),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--shares", default="0,0.5", help="Tuning.wall_carry values, comma-separated (shares 0-1)")
    ap.add_argument("--out", default=None, help="JSON path (default: docs/benchmarks/thin_walls_default_<device>.json)")
    args = ap.parse_args()
    from tqdm import tqdm

    asset = ph.load_asset()
    rows = []
    for name, kw, frames in tqdm(WALLS, desc="walls", unit="wall"):
        case = wall_case(**kw)
        clear = round(clearance_mm(case, asset), 2)
        for share in (float(s) for s in args.shares.split(",")):
            r = run_case(case, ph.Config(device=args.device, tuning=ph.Tuning(wall_carry=share)), frames=frames,
                         asset=asset)
            dirty = [f for f in range(frames) if any(r[k][f] for k in MEASURES)]
            rows.append(dict(wall=name, wall_carry=share, frames=frames, bone_clearance_mm=clear,
                             skin5_per_frame=r["skin_count"].astype(int).tolist(),
                             worst_last4={k: int(r[k][-4:].max()) for k in MEASURES},
                             clean_from=None if dirty and dirty[-1] == frames - 1 else (dirty[-1] + 1 if dirty else 0),
                             ms_median=round(float(np.median(r["ms"][2:])), 3), finite=bool(r["finite"])))
            print(rows[-1], flush=True)
    out = Path(args.out or Path(__file__).resolve().parents[1] / "docs" / "benchmarks"
               / f"thin_walls_default_{args.device.split(':')[0]}.json")
    out.write_text(json.dumps(dict(device=device_name(args.device), rows=rows), indent=1) + "\n")
    print(f"device: {device_name(args.device)}\n")
    print("| wall | wall_carry | worst over the last 4 frames (order 5 / 9 / object / check) | all four 0 from frame | "
          "bones clear (mm) |")
    print("|---|---|---|---|---|")
    for r in rows:
        w = r["worst_last4"]
        print(f"| {r['wall']} | {r['wall_carry']} | {'/'.join(str(w[k]) for k in MEASURES)} | "
              f"{r['clean_from'] if r['clean_from'] is not None else 'never'} | {r['bone_clearance_mm']} |")
    print(f"\n{out}")


if __name__ == "__main__":
    main()
