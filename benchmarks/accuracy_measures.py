"""Every measure, per measure, for a few settings on the accuracy sweep's workloads (docs/accuracy.md).

    python benchmarks/accuracy_measures.py [--device cpu] [--frames 20] [--out FILE.json] [POINT ...]

POINT: a sweep point's name (``physhand_mj.bench.accuracy.sweep_points``), e.g.
``"multires 21x2+feat+side p8 s10 e2+hold"``; default: ``Config()``'s and the paper's Algorithm 1
contact (a stage every substep). The sweep keeps, per workload, the deepest skin sample (order 5 or
9) and the deepest check point; this gives each of the four measures apart (skin samples on the
order-5 and order-9 lattices, the contact's own object points, the denser check points), worst
count and depth over the held frames (the sweep's last ``HOLD``), the bones' clearance from the
object (mm; negative: a bone inside it, so no penetration-free skin exists; the HOI grasps: the
least over the frames, from ``SoftHand.contacts``) and, for the cases, the largest skin
displacement from the rest shape (mm). The open sheet of ``cone:paper`` has no inside and no bones:
the skin lattices only. Prints a markdown table; ``--out`` writes the JSON.
"""

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

MEASURES = ("skin5", "skin9", "object", "check")


def _worst(hold):
    """{measure: (worst count, worst um)} of a (frames, 8) array: count, um per MEASURES."""
    h = np.asarray(hold, float)
    return {m: (int(h[:, 2 * k].max()), round(float(h[:, 2 * k + 1].max()), 2)) for k, m in enumerate(MEASURES)}


def hoi(scene, pt, device, frames, hold):
    import mujoco

    import physhand_mj as ph
    from physhand_mj.rollout import load_scene

    model, data, _ = load_scene(ph.scene_path(f"hoi_{scene}"), "grasp")
    cfg = dataclasses.replace(pt.config(device), frame_dt=float(model.opt.timestep))
    hand = ph.SoftHand(model, data, cfg, settle_contact=False)
    rows, clear = [], np.inf
    for f in range(frames):
        mujoco.mj_step(model, data)
        hand.step()
        clear = min(clear, float(hand.contacts().get("bone_clearance_mm", np.inf)))
        if f >= frames - hold:
            p5, p9 = hand.penetration(order=5), hand.penetration(order=9, check=True)
            rows.append((p5["penetration_count"], p5["penetration_max_um"], p9["penetration_count"],
                         p9["penetration_max_um"], p5["object_in_skin_count"], p5["object_in_skin_max_um"],
                         p9["object_in_skin_count"], p9["object_in_skin_max_um"]))
    return dict(measures=_worst(rows), bone_clearance_mm=round(clear, 2), max_disp_mm=None,
                finite=bool(np.all(np.isfinite(hand.skin_vertices))))


def case(c, pt, device, frames, hold, asset):
    from physhand_mj.bench.cases import run_case
    from physhand_mj.bench.heldout import clearance_mm

    r = run_case(c, pt.config(device), frames=frames, asset=asset)
    keys = ("skin_count", "skin_max_um", "dense_count", "dense_max_um", "obj_count", "obj_max_um", "check_count",
            "check_max_um")
    h = np.stack([np.asarray(r[k][-hold:], float) for k in keys], axis=1)
    return dict(measures=_worst(h), bone_clearance_mm=round(clearance_mm(c, asset), 2),
                max_disp_mm=round(float(np.nanmax(r["max_disp_mm"])), 2), finite=bool(r["finite"]))


def cone(pt, device, frames, hold):
    from physhand_mj.bench.accuracy import _cone_run

    r = _cone_run(pt, device, frames, hold)
    h = np.c_[r["hold"][:, :4], np.zeros((len(r["hold"]), 4))]
    return dict(measures=_worst(h), bone_clearance_mm=None, max_disp_mm=None, finite=r["finite"])


def main():
    import physhand_mj as ph
    from physhand_mj.bench import accuracy as acc
    from physhand_mj.bench.cases import press_case

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("points", nargs="*")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--workloads", default=",".join(acc.WORKLOADS))
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    by_name = {p.name: p for p in acc.sweep_points()}
    names = a.points or [next(p.name for p in by_name.values() if p.is_default()),
                         acc.SweepPoint().name if not acc.SweepPoint().is_default() else acc.SweepPoint(every=2, linear=True).name]
    unknown = [n for n in names if n not in by_name]
    if unknown:
        ap.error(f"not sweep points: {unknown}")
    workloads = a.workloads.split(",")
    acc.check_workloads(workloads)
    asset = ph.load_asset()
    hold = min(acc.HOLD, a.frames)
    out = dict(device=a.device, frames=a.frames, hold_frames=hold, workloads=workloads, results={})
    for name in names:
        pt = by_name[name]
        res = {}
        for w in workloads:
            kind, spec = w.split(":", 1)
            if kind == "hoi":
                res[w] = hoi(spec, pt, a.device, a.frames, hold)
            elif kind == "cone":
                res[w] = cone(pt, a.device, a.frames, hold)
            else:
                c = (press_case(spec.split("@")[0], site=spec.split("@")[1], depth=0.004, start=0.002) if kind == "case"
                     else acc.heldout_case(spec, asset).case)
                res[w] = case(c, pt, a.device, a.frames, hold, asset)
            print(f"{name} | {w}: {res[w]}", file=sys.stderr, flush=True)
        out["results"][name] = res
    print(f"worst over the last {hold} of {a.frames} frames: count / um per measure; bones' clearance mm; "
          f"largest skin displacement mm\n")
    print("| setting | workload | skin order 5 | skin order 9 | object points | check points | bones clear, mm | "
          "max disp, mm |\n|---|---|---|---|---|---|---|---|")
    for name, res in out["results"].items():
        for w, r in res.items():
            cells = " | ".join(f"{c} / {d:g}" if (c or d) else "0" for c, d in (r["measures"][m] for m in MEASURES))
            fmt = lambda v: "-" if v is None else f"{v:g}"  # noqa: E731
            print(f"| {name} | {w} | {cells} | {fmt(r['bone_clearance_mm'])} | {fmt(r['max_disp_mm'])} |")
    if a.out:
        a.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
