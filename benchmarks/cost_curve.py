"""What a soft-hand frame costs against how much of the hand is in contact and how fast it moves
(issue 13: the cost curve), with the split by stage.

    python benchmarks/cost_curve.py [--device cpu|cuda] [--frames 40] [--out docs/benchmarks/cost_curve_<device>.json]
    python benchmarks/cost_curve.py --plot docs/benchmarks/cost_curve_cpu.json [docs/benchmarks/cost_curve_cuda.json]

Cases (MuJoCo scenes as shipped, `SoftHand` with the default Config, position control holding or
moving the keyframe; 5 ms frames):
- contact share, hand held still: ``none`` (hand_only, open, no object), ``fingertip`` (hand_only,
  open, a 1 cm sphere pressed 2 mm into the index fingertip pad), ``pinch`` (hand_only, pinch, a
  sphere between the thumb and index pads pressed 1.5 mm into both), ``grasp`` (hoi_apple's grasp);
- motion: ``none`` and ``grasp`` with every actuator's target swinging about the keyframe by 5 %
  of its range at 0.5 Hz (``slow``) and by 15 % at 2 Hz (``fast``); the peak joint speed is reported.
Per case, the median over frames 6..N of: MuJoCo's ``mj_step``, and of ``SoftHand.step`` its sync
(bone poses in), solver and write-back (``SoftHand.metrics``); the solver's contact share is the
solver time minus that of the same case run with ``contact=NONE`` (same motion; 0 for ``none``,
which has no object and so runs no contact kernel either way). The share of the
hand in contact: the skin area of the vertices the contact moved in the last frame
(``SoftHand.contacts``) over the skin's area. Device named; the first frames (compilation,
recording) are excluded. ``--plot`` draws docs/images/cost_curve.png from one or two JSON files.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = [("none", "still"), ("fingertip", "still"), ("pinch", "still"), ("grasp", "still"),
         ("none", "slow"), ("none", "fast"), ("grasp", "slow"), ("grasp", "fast")]
MOTION = {"still": (0.0, 0.0), "slow": (0.05, 0.5), "fast": (0.15, 2.0)}  # (share of ctrl range, Hz)


def _pad(asset, hand, site):
    """World position and outward normal of the skin vertex at ``site`` (cases.site_point's) now."""
    import trimesh

    from physhand_mj.bench.cases import site_point

    p0, _ = site_point(asset, site)
    i = int(np.argmin(np.linalg.norm(asset.skin_vertices - p0, axis=1)))
    x = hand.skin_vertices.astype(float)
    n = trimesh.Trimesh(x, asset.skin_faces, process=False).vertex_normals[i]
    return x[i], n


def build(kind: str, device: str, contact: str):
    """(model, data, hand, keyframe ctrl) for case ``kind``."""
    import mujoco

    import physhand_mj as ph
    from physhand_mj.types import Strategy

    scene, key = {"none": ("hand_only", "open"), "fingertip": ("hand_only", "open"),
                  "pinch": ("hand_only", "pinch"), "grasp": ("hoi_apple", "grasp")}[kind]
    cfg = ph.Config(device=device, contact=Strategy[contact])
    spec = mujoco.MjSpec.from_file(str(ph.scene_path(scene)))
    if kind in ("fingertip", "pinch"):  # where the pads are at the keyframe: a first hand without objects
        m0 = spec.compile()
        d0 = mujoco.MjData(m0)
        mujoco.mj_resetDataKeyframe(m0, d0, m0.key(key).id)
        mujoco.mj_forward(m0, d0)
        h0 = ph.SoftHand(m0, d0, ph.Config(device=device))
        asset = h0.asset
        tip, n_tip = _pad(asset, h0, "fingertip")
        if kind == "fingertip":
            r, depth = 0.01, 0.002
            centre = tip + n_tip * (r - depth)
        else:  # the thumb's skin vertex nearest the index pad, and a ball between the two pressing both
            x = h0.skin_vertices.astype(float)
            thumb_body = list(asset.body_names).index("distal_thumb_r")
            on_thumb = np.flatnonzero(h0.solver.model.skin_body.numpy()[: asset.n_skin] == thumb_body)
            t = x[on_thumb[np.argmin(np.linalg.norm(x[on_thumb] - tip, axis=1))]]
            centre = 0.5 * (tip + t)
            r = 0.5 * float(np.linalg.norm(tip - t)) + 0.0015
        body = spec.worldbody.add_body(name="ball", pos=centre)
        body.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0], contype=0, conaffinity=0)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key(key).id)
    mujoco.mj_forward(model, data)
    geoms = ["ball"] if kind in ("fingertip", "pinch") else None
    hand = ph.SoftHand(model, data, cfg, object_geoms=geoms) if geoms else ph.SoftHand(model, data, cfg)
    return model, data, hand, data.ctrl.copy()


def run_case(kind: str, motion: str, device: str, frames: int, contact: str = "MULTIRES") -> dict:
    import mujoco
    import trimesh

    model, data, hand, ctrl0 = build(kind, device, contact)
    amp, hz = MOTION[motion]
    span = model.actuator_ctrlrange[:, 1] - model.actuator_ctrlrange[:, 0]
    rows = {k: [] for k in ("mujoco", "sync", "solver", "writeback")}
    speed = 0.0
    for f in range(frames):
        t = data.time
        data.ctrl[:] = np.clip(ctrl0 + amp * span * np.sin(2 * np.pi * hz * t), model.actuator_ctrlrange[:, 0],
                               model.actuator_ctrlrange[:, 1])
        t0 = time.perf_counter()
        mujoco.mj_step(model, data)
        t1 = time.perf_counter()
        before = dict(hand._timing)
        hand.step()
        speed = max(speed, float(np.abs(data.qvel).max()))
        if f >= 5:
            rows["mujoco"].append((t1 - t0) * 1e3)
            for k in ("sync", "solver", "writeback"):
                rows[k].append((hand._timing[k] - before[k]) * 1e3)
    out = {k: round(float(np.median(v)), 3) for k, v in rows.items()}
    out["total"] = round(sum(out.values()), 3)
    area = trimesh.Trimesh(hand.skin_vertices.astype(float), hand.asset.skin_faces, process=False).area
    touched = sum(o["area_m2"] for o in hand.contacts()["objects"].values())
    m = hand.metrics()
    out.update(case=kind, motion=motion, contact=contact, contact_share=round(touched / area, 4),
               peak_joint_speed_rad_s=round(speed, 3), asleep=bool(m.get("asleep", False)),
               triangles_tested=m.get("triangles_tested"), ops_run=m.get("ops_run"))
    return out


def plot(files: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    docs = [json.loads(Path(f).read_text()) for f in files]
    fig, axes = plt.subplots(len(docs), 2, figsize=(11, 3.6 * len(docs)), squeeze=False)
    stages = [("mujoco", "MuJoCo mj_step"), ("sync", "sync in"), ("solver_rest", "solver (no contact)"),
              ("contact", "contact"), ("writeback", "write-back")]
    for row, doc in zip(axes, docs):
        for ax, group in zip(row, ("share", "motion")):
            sel = [r for r in doc["rows"] if (r["motion"] == "still") == (group == "share")
                   or (group == "motion" and r["case"] in ("none", "grasp"))]
            if group == "motion":
                sel = [r for r in doc["rows"] if r["case"] in ("none", "grasp")]
            labels = [f"{r['case']}\n{100 * r['contact_share']:.1f} %" if group == "share"
                      else f"{r['case']} {r['motion']}\n{r['peak_joint_speed_rad_s']:.1f} rad/s" for r in sel]
            bottom = np.zeros(len(sel))
            for key, name in stages:
                v = np.array([r[key] for r in sel])
                ax.bar(range(len(sel)), v, bottom=bottom, label=name)
                bottom += v
            ax.set_xticks(range(len(sel)))
            ax.set_xticklabels(labels, fontsize=7)
            ax.set_ylabel("ms per 5 ms frame")
            dev = doc["device"]
            short = "CPU (Warp CPU kernels)" if dev.startswith("cpu") else dev[dev.find("(") + 1: dev.rfind(")")] or dev
            ax.set_title(f"{short}: " + ("contact share of the skin (held still)" if group == "share"
                                         else "motion (peak joint speed)"), fontsize=9)
        row[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main():
    from physhand_mj.bench import device_name

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--frames", type=int, default=40, help="5 ms frames per case (the first 5 are not timed)")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/cost_curve_<device>.json)")
    ap.add_argument("--plot", nargs="+", default=None, help="draw docs/images/cost_curve.png from these JSON files")
    a = ap.parse_args()
    if a.plot:
        plot(a.plot, ROOT / "docs" / "images" / "cost_curve.png")
        return
    rows = []
    for kind, motion in CASES:
        r = run_case(kind, motion, a.device, a.frames)
        ref = run_case(kind, motion, a.device, a.frames, contact="NONE")
        r["solver_no_contact"] = ref["solver"]
        # no object in the scene: no contact kernel runs in either (the difference would be timing noise)
        r["contact"] = 0.0 if kind == "none" else round(max(r["solver"] - ref["solver"], 0.0), 3)
        r["solver_rest"] = round(r["solver"] - r["contact"], 3)
        rows.append(r)
        print(json.dumps(r), flush=True)
    doc = dict(device=device_name(a.device), frames=a.frames, rows=rows)
    out = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"cost_curve_{a.device.split(':')[0]}.json"
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
