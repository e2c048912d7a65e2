"""Per-region sleeping (Config.region_sleep, physhand_mj/solver/regions.py): what it saves and how far it moves the skin.

The open hand (hand_only) settles under gravity for ``--settle`` frames with its bones still, then its
index finger bends (MCP flexion, 0.3 rad amplitude, 0.1 rad per frame phase) for ``--frames`` frames;
with Config(region_sleep=True), with the default (the whole hand sleeps, which it does not while a
finger bends) and with nothing ever sleeping (sleep_speed 0). Reported: the median solver ms per
frame of the bending phase (device named, compilation excluded) and of it the region decisions'
host time, the regions asleep and the soft vertices and constraints they take out, and each run's
largest skin/flesh difference from the one in which nothing sleeps (the measure the sleeping does
not share).

    python benchmarks/region_sleep.py [--device cpu|cuda] [--settle 100] [--frames 40]

Writes docs/benchmarks/region_sleep_<device>.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    import physhand_mj as ph
    from physhand_mj.bench import device_name
    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
    from physhand_mj.solver import Solver, make_model

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--settle", type=int, default=100, help="frames with the bones still first (count)")
    p.add_argument("--frames", type=int, default=40, help="timed frames of the index bending (count)")
    a = p.parse_args()
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    mount = mount_pose(model, data)
    q0 = model.key("open").qpos.copy()
    adr = model.jnt_qposadr[model.joint("mcp2_flexion_r").id]
    rows, finals = [], {}
    # region sleep on; off (the default whole-hand sleep only, which does not act while a finger
    # bends); nothing ever sleeps (the reference of the difference)
    for name, regions, speed in (("regions", True, 3e-3), ("default", False, 3e-3), ("never", False, 0.0)):
        cfg = ph.Config(device=a.device, region_sleep=regions, sleep_speed=speed, tuning=ph.Tuning(sleep_frames=10))
        solver = Solver(make_model(asset, cfg), cfg)
        host = [0.0]
        if solver.regions is not None:  # the region decisions' host time (numpy, per frame)
            for fn in ("before_frame", "after_frame", "apply"):
                f0 = getattr(solver.regions, fn)

                def timed(*args, f0=f0):
                    t0 = time.perf_counter()
                    f0(*args)
                    host[0] += time.perf_counter() - t0

                setattr(solver.regions, fn, timed)
        state = solver.make_state(*mount)
        still = bone_poses_at(model, data, q0, ids)
        for _ in range(a.settle):
            solver.set_body_poses(state, *still)
            solver.step(state)
        times, out = [], {}
        host[0] = 0.0
        for k in range(a.frames):
            q = q0.copy()
            q[adr] += 0.3 * np.sin(0.1 * (k + 1))
            solver.set_body_poses(state, *bone_poses_at(model, data, q, ids))
            t = time.perf_counter()
            out = solver.step(state)
            times.append(time.perf_counter() - t)
        finals[name] = state.x.numpy().astype(float)
        m = solver.model
        total = int(m.edge_ids.shape[0] + m.tet_ids.shape[0] + m.dih_ids.shape[0])
        rows.append(dict(run=name, region_sleep=regions, sleep_speed=speed,
                         ms_per_frame=round(float(np.median(times[2:])) * 1e3, 3),
                         ms_region_host=round(host[0] / a.frames * 1e3, 3),
                         regions_asleep=out.get("regions_asleep", []), vertices_asleep=out.get("vertices_asleep", 0),
                         constraints_solved=out.get("constraints_solved", total), constraints=total,
                         soft_vertices=int((m.inv_mass.numpy() > 0).sum())))
        print(json.dumps(rows[-1]), flush=True)
    diff = {}
    for name in ("regions", "default"):
        d = np.linalg.norm(finals[name] - finals["never"], axis=1)
        diff[name] = dict(max_mm=round(float(d.max()) * 1e3, 4), p99_mm=round(float(np.percentile(d, 99)) * 1e3, 4))
    res = dict(device=device_name(a.device if a.device != "cuda" else "cuda:0"), settle=a.settle, frames=a.frames,
               rows=rows, diff_from_never=diff,
               command="python benchmarks/region_sleep.py " + " ".join(sys.argv[1:]))
    out_path = ROOT / "docs" / "benchmarks" / f"region_sleep_{a.device.split(':')[0]}.json"
    out_path.write_text(json.dumps(res, indent=1))
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}))


if __name__ == "__main__":
    main()
