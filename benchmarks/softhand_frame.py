"""Full frame of the soft hand in MuJoCo, split by stage: the grasp_glass scene (the demo), 80 frames.

Stages per 5 ms frame: MuJoCo step (mj_step), sync (bone and object poses in), solver (the XPBD frame
with contact and metrics), write-back (skin vertices and normals into the mesh). Also the solver
frame with contact switched off, to isolate the contact's share.
Writes docs/benchmarks/softhand_frame_<device>.json. Run: python benchmarks/softhand_frame.py [--device]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import mujoco

import physhand_mj as ph
from physhand_mj.bench import device_name
from physhand_mj.types import Strategy

ROOT = Path(__file__).resolve().parents[1]


def run(device: str, frames: int, contact: Strategy, **config) -> dict:
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device=device, contact=contact, **config))
    mj = 0.0
    for f in range(frames):
        t = time.perf_counter()
        mujoco.mj_step(model, data)
        mj += time.perf_counter() - t
        hand.step()
    m = hand.metrics()
    return dict(contact=contact.name.lower(), config=config, ms_mujoco=round(mj / frames * 1e3, 3), ms_sync=round(m["ms_sync"], 3),
                ms_solver=round(m["ms_solver"], 3), ms_writeback=round(m["ms_writeback"], 3),
                ms_total=round(mj / frames * 1e3 + m["ms_per_frame"], 3),
                penetration_count=m["penetration_count"], penetration_max_um=round(m["penetration_max_um"], 3),
                **{k: m.get(k) for k in ("objects_near", "triangles_tested", "features_listed", "ops_run",
                                         "contact_ops_run")})  # the last frame's work (activity.py)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=80)
    p.add_argument("--skip-margin", type=float, default=None,
                   help="physhand_mj.contact.metrics.SKIP_MARGIN (m) for the run: the skin measure's corner bound (0: off)")
    p.add_argument("--config", default="{}", help="Config fields as JSON for both rows (e.g. "
                   "'{\"contact_every\": 2, \"contact_linear\": true}')")
    p.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/softhand_frame_<device>.json)")
    args = p.parse_args()
    if args.skip_margin is not None:
        from physhand_mj.contact import metrics

        metrics.SKIP_MARGIN = args.skip_margin
    config = json.loads(args.config)
    if not isinstance(config, dict):
        p.error("--config takes a JSON object of Config fields")
    rows = [run(args.device, args.frames, s, **config) for s in (Strategy.NONE, Strategy.MULTIRES)]
    for r in rows:
        print(json.dumps(r), flush=True)
    dev = device_name(args.device if args.device != "cuda" else "cuda:0")
    out = Path(args.out) if args.out else ROOT / "docs" / "benchmarks" / f"softhand_frame_{args.device.split(':')[0]}.json"
    out.write_text(json.dumps(dict(device=dev, frames=args.frames, skip_margin=args.skip_margin, rows=rows), indent=1))


if __name__ == "__main__":
    main()
