"""The paper's Table 2 (section 4.3): seven generated grasps x contact methods, 36 frames of 10
substeps each, the bones held at the keyframe (gravity compensation); metrics over the 10 substeps
of the last frame, as the paper computes them: count = penetrating samples summed over those
substeps, max = deepest, avg = mean depth of the penetrating samples (um); and, as independent
checks at the last frame's end, skin samples on an order-9 lattice inside the object, object
surface points inside the closed skin and the denser check points that the contact never uses
(Contact.check_points) (count, max um); plus the initial (undeformed) penetration,
ms per full frame and the contact's share (frame time minus the same scene's frame without
objects, measured just before). Methods: vertex, opt, multires (the paper's: Eq. 9 only) and
default (multires + the object's features + side-aware exits, ``Config()``).

Writes docs/benchmarks/hoi_table2_<device>.json and prints a markdown table.
Run: python benchmarks/hoi_table2.py [--device cpu|cuda] [--steps 36]
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

import physhand_mj as ph
from physhand_mj.bench import device_name
from physhand_mj.build.hoi import SCENES
from physhand_mj.rollout import load_scene, rollout

ROOT = Path(__file__).resolve().parents[1]
PAPER = {"feature_contact": False, "side_aware": False, "skin_tether": 0.0}  # the paper's contact, no tether
METHODS = (("vertex", "vertex", PAPER), ("opt", "opt", PAPER), ("multires", "multires", PAPER), ("default", "multires", {}))
# asked by name only (--methods default,pseudo): the default with the feature push's side from the
# pseudo normals alone (Config.tuning.feature_winding off), for the local winding number's cost in one run
EXTRA = (("pseudo", "multires", {"feature_winding": False}),)


def no_contact_ms(scene: Path, device: str, frames: int = 20) -> float:
    model, data, _ = load_scene(scene, "grasp")
    hand = ph.SoftHand(model, data, ph.Config(frame_dt=float(model.opt.timestep), device=device), object_geoms=[])
    times = []
    for _ in range(frames):
        mujoco.mj_step(model, data)
        t = time.perf_counter()
        hand.step()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.mean(times[1:]))


def last_frame(log: Path, substeps: int) -> dict:
    with open(log, newline="") as f:
        rows = list(csv.DictReader(f))[-substeps:]
    count = np.array([int(r["penetration_count"]) for r in rows])
    avg = np.array([float(r["penetration_avg_um"]) for r in rows])
    total = int(count.sum())
    return dict(count=total, max_um=max(float(r["penetration_max_um"]) for r in rows),
                avg_um=float((count * avg).sum() / total) if total else 0.0)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--steps", type=int, default=36)
    p.add_argument("--methods", default=",".join(m[0] for m in METHODS))
    p.add_argument("--scenes", default=",".join(SCENES))
    args = p.parse_args()
    dense = {}

    def at_end(hand, model, data):
        dense.update(hand.penetration(order=9, check=True))

    rows, bases = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            base = no_contact_ms(ph.scene_path(f"hoi_{name}"), args.device)  # paired: the host's speed drifts
            bases.append(base)
            for method, c, over in [m for m in METHODS + EXTRA if m[0] in args.methods.split(",")]:
                res = rollout(ph.scene_path(f"hoi_{name}"), "grasp", steps=args.steps, contact=c, device=args.device,
                              out=Path(tmp) / f"{name}-{method}", progress=False, config=over, on_end=at_end)
                row = dict(scene=name, contact=method, initial_count=res["initial_penetration_count"],
                           initial_max_um=res["initial_penetration_max_um"],
                           initial_obj_count=res["initial_object_in_skin_count"],
                           initial_obj_max_um=res["initial_object_in_skin_max_um"], **last_frame(Path(res["log"]), 10),
                           final_count=res["penetration_count"], dense_count=int(dense["penetration_count"]),
                           dense_max_um=round(float(dense["penetration_max_um"]), 2),
                           obj_count=res["object_in_skin_count"], obj_max_um=res["object_in_skin_max_um"],
                           check_count=int(dense["object_in_skin_count"]),
                           check_max_um=round(float(dense["object_in_skin_max_um"]), 2),
                           ms_per_frame=res["ms_per_frame"],
                           no_contact_ms=round(base, 3), contact_ms=round(res["ms_per_frame"] - base, 3),
                           finite=res["finite"])
                rows.append(row)
                print(json.dumps(row), flush=True)
    dev = device_name(args.device if args.device != "cuda" else "cuda:0")
    out = ROOT / "docs" / "benchmarks" / f"hoi_table2_{args.device.split(':')[0]}.json"
    if out.exists() and (args.methods != p.get_default("methods") or args.scenes != p.get_default("scenes")):
        # a partial run replaces its own rows and keeps the file's others (marked with their device)
        ran = {(r["scene"], r["contact"]) for r in rows}
        old = json.loads(out.read_text())
        kept = [dict(r, device=r.get("device", old.get("device"))) for r in old["rows"]
                if (r["scene"], r["contact"]) not in ran]
        rows = [dict(r, device=dev) for r in rows] + kept
        rows.sort(key=lambda r: (list(SCENES).index(r["scene"]) if r["scene"] in SCENES else 99,
                                 [m[0] for m in METHODS + EXTRA].index(r["contact"])))
    out.write_text(json.dumps(dict(device=dev, steps=args.steps, rows=rows), indent=1))
    print(f"\n{dev}; frame without contact {min(bases):.2f}-{max(bases):.2f} ms\n")
    print("| scene | method | initial count / max (mm) | count | max (um) | avg (um) | order 9: count / max (um) | "
          "object in skin: count / max (um) | check points: count / max (um) | ms/frame | contact ms |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['contact']} | {r['initial_count']} / {r['initial_max_um'] / 1e3:.2f} | {r['count']} | "
              f"{r['max_um']:.4g} | {r['avg_um']:.4g} | {r['dense_count']} / {r['dense_max_um']:.4g} | "
              f"{r['obj_count']} / {r['obj_max_um']:.4g} | {r.get('check_count', '-')} / {r.get('check_max_um', '-')} | "
              f"{r['ms_per_frame']:.1f} | {r['contact_ms']:.1f} |")


if __name__ == "__main__":
    main()
