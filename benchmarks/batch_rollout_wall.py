"""Where a batched rollout's wall time goes: ``rollout_batched`` over W copies of one scene, profiled.

    python benchmarks/batch_rollout_wall.py [--device cuda] [--worlds 256,1024] [--steps 36] [--scene hoi_apple]
                                            [--config '{"reuse_outside": false}'] [--measure-every K]

One batch of W worlds (W copies of the scene's ``grasp`` keyframe), whole: loading the runs, the
batch's set-up and settling, the frames (MuJoCo, the solver, both penetration measures for the
logs, the log rows), the skins written at the end. Run under cProfile (which adds a few percent);
prints one JSON line per W: the wall time and the cumulative seconds of the parts named in PARTS.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.batch_rollout import rollout_batched  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402

# part -> (file suffix, function name) in the profile
PARTS = {
    "load_runs": ("rollout.py", "load_rollout_scene"),
    "batch_setup": ("batch.py", "__init__"),
    "settle": ("batch.py", "settle"),
    "mujoco_step": ("~", "<built-in method mujoco._functions.mj_step>"),
    "solver_frames": ("batch.py", "step"),  # (before 2026-11-27's tenth session: the frames by step)
    "solver_submit": ("batch.py", "submit"),  # (since: pipelined, the frames queued by submit ...
    "solver_wait": ("batch.py", "wait"),  # ... and their reports waited for)
    "measures_per_frame": ("batch.py", "penetration"),
    "log_rows": ("rollout.py", "frame_rows"),
    "skins_out": ("batch.py", "skins"),
    "skin_per_world": ("batch.py", "skin"),
    "ply_export": ("base.py", "export"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--worlds", default="4,16", help="comma-separated worlds per batch (count)")
    ap.add_argument("--steps", type=int, default=36, help="5 ms frames per run (count)")
    ap.add_argument("--scene", default="hoi_apple", help="shipped scene with a grasp keyframe")
    ap.add_argument("--config", default="{}", help="Config fields as JSON, e.g. '{\"reuse_outside\": false}'")
    ap.add_argument("--measure-every", type=int, default=1,
                    help="the object-side measure every K-th frame (count; 0: the last frame only)")
    a = ap.parse_args()
    scene = ph.scene_path(a.scene)
    for w in (int(x) for x in a.worlds.split(",")):
        prof = cProfile.Profile()
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            prof.enable()
            rows = rollout_batched([(scene, "grasp")] * w, tmp, worlds=w, steps=a.steps, device=a.device,
                                   config=json.loads(a.config), progress=False, measure_every=a.measure_every)
            prof.disable()
            wall = time.perf_counter() - t
        stats = pstats.Stats(prof).stats  # (file, line, name) -> (cc, nc, tt, ct, callers)
        parts = {}
        for part, (suffix, name) in PARTS.items():
            parts[part] = round(sum(v[3] for k, v in stats.items() if k[2] == name and k[0].endswith(suffix)), 2)
        print(json.dumps(dict(device=device_name(a.device), scene=a.scene, worlds=w, steps=a.steps, config=a.config,
                              measure_every=a.measure_every,
                              wall_s=round(wall, 2), failed=sum(1 for r in rows if r.get("error")),
                              seconds=parts)), flush=True)


if __name__ == "__main__":
    main()
