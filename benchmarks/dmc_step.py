"""Cost of one env step of every physhand_dmc task, split into MuJoCo, the soft hand's stages and
observation building (ms per env step; an env step is control_timestep / 5 ms MuJoCo steps, each
followed by one solver frame).

    python benchmarks/dmc_step.py [--steps N] [--device cpu|cuda] [--out docs/benchmarks/dmc_step_cpu.json]

Kernel compilation and the first (recording) frame are excluded: each task runs 3 warm-up steps
after reset before the timed steps. The policy holds the reset's ctrl (a steady grasp / press).
Prints one JSON line per task on stderr and writes all of them as one JSON file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


import physhand_mj as ph
from physhand_mj.bench import device_name
from physhand_dmc import suite


def measure(domain: str, task: str, steps: int, device: str) -> dict:
    env = suite.load(domain, task, task_kwargs=dict(random=0, config=ph.Config(device=device)))
    env.reset()
    physics = env.physics
    action = env.task.normalise_ctrl(physics, physics.data.ctrl)
    for _ in range(3):
        env.step(action)
    hand = physics.soft
    physics.timing = dict(mujoco=0.0, soft=0.0, steps=0)
    hand._timing = dict(sync=0.0, solver=0.0, writeback=0.0, frames=0)
    hand.sensor.seconds, frames0 = 0.0, hand.sensor.frames
    env.task.obs_seconds, env.task.obs_calls = 0.0, 0
    t0 = time.perf_counter()
    for _ in range(steps):
        ts = env.step(action)
    wall = time.perf_counter() - t0
    tm, st = physics.timing, hand._timing
    per = 1e3 / steps
    sensor = hand.sensor.seconds
    out = dict(domain=domain, task=task, steps=steps, frames_per_step=tm["steps"] // steps,
               ms_env_step=wall * per, ms_mujoco=tm["mujoco"] * per, ms_soft_sync=st["sync"] * per,
               ms_soft_solver=st["solver"] * per, ms_soft_writeback=(st["writeback"] - sensor) * per,
               ms_soft_sensor=sensor * per, ms_observation=env.task.obs_seconds * per,
               sensor_launches=hand.sensor.frames - frames0, skin_vertices=hand.asset.n_skin,
               substeps=hand.config.substeps, final_reward=float(ts.reward),
               final_object_contact=[round(float(v), 4) for v in ts.observation["object_contact"]])
    out["ms_other"] = out["ms_env_step"] - sum(out[k] for k in ("ms_mujoco", "ms_soft_sync", "ms_soft_solver",
                                                                   "ms_soft_writeback", "ms_soft_sensor",
                                                                   "ms_observation"))
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in out.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=20, help="timed env steps per task")
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda")
    p.add_argument("--out", default=None, help="JSON file (default docs/benchmarks/dmc_step_<device>.json)")
    p.add_argument("--tasks", nargs="*", default=None, help="domain/task names (default: all)")
    a = p.parse_args(argv)
    if a.steps < 1:
        print("error: --steps must be >= 1", file=sys.stderr)
        return 2
    tasks = suite.ALL_TASKS if not a.tasks else [tuple(t.split("/", 1)) for t in a.tasks]
    rows = []
    for domain, task in tasks:
        row = measure(domain, task, a.steps, a.device)
        print(json.dumps(row), file=sys.stderr)
        rows.append(row)
    result = dict(device=device_name(a.device), warp_device=a.device, control_timestep_s=0.01,
                  frame_dt_s=0.005, tasks=rows)
    out = Path(a.out or f"docs/benchmarks/dmc_step_{'cpu' if a.device == 'cpu' else 'cuda'}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(dict(device=result["device"], out=str(out),
                          ms_env_step={f"{r['domain']}/{r['task']}": r["ms_env_step"] for r in rows})))
    return 0


if __name__ == "__main__":
    sys.exit(main())
