"""Inverted tets under deep presses with and without the flesh following the contact
(``Config.tuning.flesh_carry``, solver/carry.py; docs/contact.md "Bones inside objects").

    python benchmarks/flesh_carry.py [--device cpu|cuda] [--shares 0,0.5] [--frames 16] [--out F.json]

Six feasible presses of physhand_mj/bench/cases.py (a 3 mm capsule 3 mm into the palm past its axis,
a 16 mm x 1 mm plate 4 mm deep at the palm from the start, a coarse icosphere 4 mm into the palm, a
1 mm plate edge first, a cone tip and a 30-degree knife 3 mm in), ``--frames`` frames each, and three
infeasible starts of benchmarks/bone_inside.py (a bone 5 mm inside a 30 mm sphere at the palm and
the fingertip, 15 mm at the palm; 12 frames, the hold on), once per share. Reported per run: the
inverted tets over the last 3 frames (the rest hand has none), the worst count over the last 4
frames of the four penetration measures (order-5 and order-9 skin samples inside the object, object
and check points inside the skin), the median frame time after the first two (ms; compilation
excluded) and finiteness; for the bones the skin inside, the largest displacement and the late move
as bone_inside.py reports them. Writes docs/benchmarks/flesh_carry_<device>.json (device named).
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import press_case, run_case, wall_case  # noqa: E402
from physhand_mj.solver import Solver  # noqa: E402

MEASURES = ("skin_count", "dense_count", "obj_count", "check_count")


def presses():
    return [press_case("capsule", site="palm", depth=0.003), wall_case(0.008, 0.001, 0.004),
            press_case("coarse", site="palm", depth=0.004), press_case("plate", site="palm", depth=0.003),
            press_case("cone_tip", site="palm", depth=0.003), press_case("knife", site="fingertip", depth=0.003)]


def press_row(case, share: float, device: str, frames: int, asset) -> dict:
    inverted = []
    orig = Solver.step

    def step(self, state, *a, **k):  # each frame's inverted-tet count
        out = orig(self, state, *a, **k)
        inverted.append(int(out["inverted"]))
        return out

    Solver.step = step
    try:
        # (wall_carry 0: the plates here are broad walls, whose default carry would make share 0 no "off")
        r = run_case(case, ph.Config(device=device, tuning=ph.Tuning(flesh_carry=share, wall_carry=0.0)),
                     frames=frames, asset=asset)
    finally:
        Solver.step = orig
    return dict(case=case.name, site=case.site, depth_mm=round(case.depth * 1e3, 2), flesh_carry=share,
                inverted_last3=inverted[-3:], worst_last4={k: int(r[k][-4:].max()) for k in MEASURES},
                ms_median=round(float(np.median(r["ms"][2:])), 3), finite=bool(r["finite"]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--shares", default="0,0.5", help="Tuning.flesh_carry values, comma-separated (shares 0-1)")
    ap.add_argument("--frames", type=int, default=16, help="frames per press (count; 5 ms each)")
    ap.add_argument("--out", default=None, help="JSON path (default: docs/benchmarks/flesh_carry_<device>.json)")
    args = ap.parse_args()
    from bone_inside import measure
    from tqdm import tqdm

    asset = ph.load_asset()
    shares = [float(s) for s in args.shares.split(",")]
    rows = []
    for case in tqdm(presses(), desc="presses", unit="case"):
        for share in shares:
            rows.append(press_row(case, share, args.device, args.frames, asset))
            print(rows[-1], flush=True)
    bones = []
    for site, depth in tqdm((("palm", 0.005), ("fingertip", 0.005), ("palm", 0.015)), desc="bones inside", unit="case"):
        for share in shares:
            bones.append(measure(asset, site, depth, 0.03, True, args.device, 12, share))
            print(bones[-1], flush=True)
    out = Path(args.out or Path(__file__).resolve().parents[1] / "docs" / "benchmarks"
               / f"flesh_carry_{args.device.split(':')[0]}.json")
    out.write_text(json.dumps(dict(device=device_name(args.device), frames=args.frames, presses=rows, bones=bones),
                              indent=1) + "\n")
    print(f"device: {device_name(args.device)}\n")
    print("| case | flesh_carry | inverted tets (last 3 frames) | worst of the 4 measures (last 4) | ms a frame |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} {r['site']} {r['depth_mm']} mm | {r['flesh_carry']} | {r['inverted_last3']} | "
              f"{max(r['worst_last4'].values())} | {r['ms_median']} |")
    for b in bones:
        print(f"| bone {b['site']} {b['depth_mm']:.0f} mm inside | {b['flesh_carry']} | {b['inverted']} | "
              f"skin inside {b['skin_count']} | late move {b['late_move_mm']} mm |")
    print(f"\n{out}")


if __name__ == "__main__":
    main()
