"""Infeasible starts: a bone 1-25 mm inside a large sphere at the fingertip and the palm, with the
bones' hold (contact/bones.py, ``Config.tuning.bone_hold``) and without it.

    python benchmarks/bone_inside.py [--device cpu|cuda] [--frames 12] [--flesh-carry SHARE] [--out docs/benchmarks/bone_inside_cpu.json]

Each placement (physhand_mj/bench/cases.py ``bone_case``): a sphere (radius 30 mm; 50 mm for 25 mm)
on the site's normal, embedded from frame 0 so that the skeleton vertex deepest inside it lies the
given depth inside, then held still. Reported after the last frame: the bones' least clearance
(mm, negative inside: the report's own figure, ``bone_report``), the skin vertices held, skin
samples inside the sphere (order 5) and sphere points inside the skin, the largest skin
displacement from rest (mm; the bones stay at rest, so rest is where they carry the skin), the
largest ratio of that displacement to the vertex's flesh thickness, the largest skin move within
one frame over the second half of the frames (mm: does the skin settle or keep moving), the
inverted tets (the rest hand has none) and whether every position is finite. Prints a markdown
table; writes JSON (device named). ``--flesh-carry SHARE``: the hold on only, with
``Config.tuning.flesh_carry`` = SHARE (solver/carry.py; the JSON's default name gains ``_carry``).
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import bone_case, run_case  # noqa: E402
from physhand_mj.contact.bones import bone_report  # noqa: E402
from physhand_mj.solver import Solver  # noqa: E402

PLACEMENTS = [(site, d, 0.05 if d >= 0.025 else 0.03) for site in ("fingertip", "palm") for d in (0.001, 0.005, 0.015, 0.025)]


def measure(asset, site: str, depth: float, radius: float, hold: bool, device: str, frames: int,
            carry: float = 0.0) -> dict:
    case, _, clear = bone_case(site, depth, radius, asset)
    steps, moves = [], []
    orig = Solver.step

    def step(self, state, *a, **k):  # each frame's summary and its largest skin move
        x0 = state.x.numpy()[: asset.n_skin].copy()
        out = orig(self, state, *a, **k)
        steps.append(out)
        moves.append(float(np.linalg.norm(state.x.numpy()[: asset.n_skin] - x0, axis=1).max()))
        return out

    Solver.step = step
    try:
        r = run_case(case, ph.Config(device=device, tuning=ph.Tuning(bone_hold=hold, flesh_carry=carry)), frames=frames, asset=asset)
    finally:
        Solver.step = orig
    m, c = r["solver"].model, r["solver"].contact
    thick = np.linalg.norm(m.skin_local.numpy() - m.skin_anchor.numpy(), axis=1)
    disp = np.linalg.norm(r["skin"] - asset.skin_vertices, axis=1)
    rep = bone_report(m, r["objects"], r["state"].x, 1, c.bone_hold.held if hold else None)
    return dict(site=site, depth_mm=depth * 1e3, radius_mm=radius * 1e3, hold=hold, flesh_carry=carry,
                bone_clearance_mm=round(rep["bone_clearance_m"] * 1e3, 2), skin_held=int(sum(
                    o["skin_held"] for o in rep["objects"].values())),
                skin_count=int(r["skin_count"][-1]), skin_max_um=round(float(r["skin_max_um"][-1]), 1),
                obj_count=int(r["obj_count"][-1]), obj_max_um=round(float(r["obj_max_um"][-1]), 1),
                max_disp_mm=round(float(disp.max()) * 1e3, 2), disp_per_thickness=round(float((disp / thick).max()), 2),
                late_move_mm=round(max(moves[frames // 2:]) * 1e3, 2), inverted=int(steps[-1]["inverted"]),
                tethered=int(steps[-1].get("tethered", 0)), finite=bool(r["finite"]),
                clearance_check_mm=round(clear * 1e3, 2))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--frames", type=int, default=12, help="frames per run (count; 5 ms each)")
    ap.add_argument("--flesh-carry", type=float, default=0.0,
                    help="Config.tuning.flesh_carry (share 0-1; above 0: the hold on only, with it)")
    ap.add_argument("--out", default=None, help="JSON path (default: docs/benchmarks/bone_inside_<device>.json)")
    args = ap.parse_args()
    from tqdm import tqdm

    asset = ph.load_asset()
    rows = []
    for site, depth, radius in tqdm(PLACEMENTS, desc="bone inside", unit="placement"):
        for hold in ((True,) if args.flesh_carry > 0 else (True, False)):
            rows.append(measure(asset, site, depth, radius, hold, args.device, args.frames, args.flesh_carry))
    tag = "_carry" if args.flesh_carry > 0 else ""
    out = Path(args.out or Path(__file__).resolve().parents[1] / "docs" / "benchmarks"
               / f"bone_inside_{args.device.split(':')[0]}{tag}.json")
    out.write_text(json.dumps(dict(device=device_name(args.device), frames=args.frames, rows=rows), indent=1) + "\n")
    print(f"device: {device_name(args.device)}; {args.frames} frames\n")
    print("| site | bone inside (mm) | hold | skin held | skin samples / max um | sphere points / max um | "
          "max disp mm (/ thickness) | late move mm | inverted tets | finite |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['site']} | {-r['bone_clearance_mm']:.1f} | {'on' if r['hold'] else 'off'} | {r['skin_held']} | "
              f"{r['skin_count']} / {r['skin_max_um']:.0f} | {r['obj_count']} / {r['obj_max_um']:.0f} | "
              f"{r['max_disp_mm']:.1f} ({r['disp_per_thickness']:.2f}) | {r['late_move_mm']:.1f} | {r['inverted']} | "
              f"{r['finite']} |")
    print(f"\n{out}")


if __name__ == "__main__":
    main()
