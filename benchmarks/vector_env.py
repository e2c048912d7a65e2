"""Throughput of the batched environments (physhand_dmc.vector, issue 54): env-steps/s of
``hand_hold`` (apple, gravity along the palm: two-way coupling, contact) and ``fingertip_press``
(contact, one-way) at several W, with the split of a step's wall time into MuJoCo Warp, the soft
frames and the host work (observations, rewards, exchange), and the rigid MuJoCo Warp step of the
same scene alone (the soft hand's cost over the rigid hand).

    python benchmarks/vector_env.py --device cuda:0 --worlds 1,64,256,1024,4096 --steps 20 --out r.json
    python benchmarks/vector_env.py --device cpu --worlds 1,4 --steps 3

Timings exclude kernel compilation and the reset (the first steps are warm-up); the action is the
reset's control held (the grasp held: contact in every frame).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "plugins")]

TASKS = {"hand_hold": ("hand_hold", "apple", {"gravity": "down"}), "fingertip_press": ("fingertip_press", "index", {})}


def device_name(device: str) -> str:
    import warp as wp

    d = wp.get_device(device)
    return d.name if d.is_cuda else f"CPU ({platform.processor() or platform.machine()})"


def measure(name: str, worlds: int, steps: int, warmup: int, device: str) -> dict:
    import warp as wp

    from physhand_dmc import vector

    domain, task, kwargs = TASKS[name]
    t0 = time.perf_counter()
    env = vector.make(domain, task, num_envs=worlds, task_kwargs=dict(kwargs, random=0), device=device)
    env.reset(seed=0)
    setup = time.perf_counter() - t0
    act = env.task.normalise_ctrl(env.physics.host("ctrl"))
    for _ in range(warmup):
        env.step(act)
    p = env.physics
    mj = soft = 0.0
    step_mj, frame = p.step_mujoco, p.soft_frame

    def timed_mj():
        nonlocal mj
        wp.synchronize_device(p.device)
        t = time.perf_counter()
        step_mj()
        wp.synchronize_device(p.device)
        mj += time.perf_counter() - t

    def timed_frame():
        nonlocal soft
        t = time.perf_counter()
        out = frame()
        soft += time.perf_counter() - t
        return out

    p.step_mujoco, p.soft_frame = timed_mj, timed_frame
    rewards = []
    wp.synchronize_device(p.device)
    t0 = time.perf_counter()
    for _ in range(steps):
        _, r, *_ = env.step(act)
        rewards.append(float(np.mean(r)))
    wp.synchronize_device(p.device)
    wall = time.perf_counter() - t0
    pen = p.penetration()[1]
    model = p.model
    env.close()
    rigid = rigid_step(model, worlds, steps, device, env.n_sub_steps)
    return dict(task=name, worlds=worlds, steps=steps, setup_s=round(setup, 2), ms_per_step=1e3 * wall / steps,
                env_steps_per_s=worlds * steps / wall, mujoco_ms=1e3 * mj / steps, soft_ms=1e3 * soft / steps,
                host_ms=1e3 * (wall - mj - soft) / steps, mean_reward=float(np.mean(rewards)),
                deepest_um=float(np.max(pen)), rigid_ms_per_step=rigid,
                rigid_env_steps_per_s=worlds / (rigid * 1e-3) if rigid else None)


def rigid_step(model, worlds, steps, device, n_sub) -> float:
    """ms per env step of MuJoCo Warp alone on the env's model from its keyframe 0 (n_sub physics
    steps; a CUDA graph on a GPU)."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    with wp.ScopedDevice(device):
        m = mjw.put_model(model)
        d = mjw.put_data(model, data, nworld=worlds)
        for _ in range(2):
            for _ in range(n_sub):
                mjw.step(m, d)
        graph = None
        if wp.get_device(device).is_cuda:
            with wp.ScopedCapture() as cap:
                for _ in range(n_sub):
                    mjw.step(m, d)
            graph = cap.graph
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        for _ in range(steps):
            if graph is not None:
                wp.capture_launch(graph)
            else:
                for _ in range(n_sub):
                    mjw.step(m, d)
        wp.synchronize_device(device)
    return 1e3 * (time.perf_counter() - t0) / steps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda:0")
    ap.add_argument("--worlds", default="1,4", help="comma-separated W (environments)")
    ap.add_argument("--tasks", default="hand_hold,fingertip_press")
    ap.add_argument("--steps", type=int, default=3, help="timed env steps")
    ap.add_argument("--warmup", type=int, default=2, help="untimed env steps after the reset (compilation)")
    ap.add_argument("--out", type=Path, default=None, help="JSON with the rows")
    a = ap.parse_args(argv)
    rows = []
    dev = device_name(a.device)
    print(f"device: {dev}")
    print(f"{'task':16s} {'W':>5s} {'ms/step':>9s} {'env-steps/s':>12s} {'mujoco':>8s} {'soft':>8s} {'host':>8s} "
          f"{'rigid ms':>9s} {'rigid steps/s':>14s}")
    for name in a.tasks.split(","):
        for w in (int(x) for x in a.worlds.split(",")):
            r = measure(name, w, a.steps, a.warmup, a.device)
            rows.append(r)
            print(f"{name:16s} {w:5d} {r['ms_per_step']:9.2f} {r['env_steps_per_s']:12.0f} {r['mujoco_ms']:8.2f} "
                  f"{r['soft_ms']:8.2f} {r['host_ms']:8.2f} {r['rigid_ms_per_step']:9.3f} {r['rigid_env_steps_per_s']:14.0f}",
                  flush=True)
    if a.out:
        a.out.write_text(json.dumps(dict(device=dev, rows=rows), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
