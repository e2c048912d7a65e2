"""World k of a batched environment against the single environment with the same seed and actions
(issue 54, docs/training.md): the largest difference of each observation part and of the reward
over the compared steps, per world.

    python benchmarks/vector_vs_single.py --device cpu --task hand_hold --worlds 2 --steps 6
    python benchmarks/vector_vs_single.py --device cuda:0 --task fingertip_press --worlds 3 --steps 20

With ``--perturb`` (default 6e-8) each world's single environment also runs against itself with
every qpos scaled by 1 + 6e-8 N(0, 1) after the reset: how far the task carries a difference of
float32's rounding, the scale of the batched side's.

The actions: each world holds its reset's control plus a slow 0.05 sinusoid per actuator (a smooth
policy); the batched side runs MuJoCo Warp (float32), the single side MuJoCo's C step (float64).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "plugins")]

TASKS = {"hand_hold": ("hand_hold", "apple", {"gravity": "down"}), "fingertip_press": ("fingertip_press", "index", {})}


def actions(base: np.ndarray, steps: int) -> np.ndarray:
    """(steps, W, nu): the reset's normalised control plus 0.05 sin(0.3 k + i) on actuator i."""
    nu = base.shape[1]
    return np.array([np.clip(base + 0.05 * np.sin(0.3 * k + np.arange(nu))[None], -1, 1) for k in range(steps)])


def single_run(domain, name, kw, acts, perturb: float = 0.0, seed: int = 0):
    """The single environment's flat observations (steps + 1, dim) and rewards (steps,) under ``acts``
    (steps, nu); ``perturb``: every qpos after the reset scaled by 1 + perturb * N(0, 1) (float32's
    rounding is ~6e-8: how far the task itself carries a rounding difference)."""
    from physhand_dmc import suite

    single = suite.load(domain, name, task_kwargs=kw, environment_kwargs={"flat_observation": True})
    ts = single.reset()
    if perturb:
        d = single.physics.data
        d.qpos[:] *= 1 + perturb * np.random.default_rng(seed).standard_normal(d.qpos.shape)
    o, rr = [ts.observation["observations"]], []
    for a in acts:
        ts = single.step(a)
        o.append(ts.observation["observations"])
        rr.append(ts.reward)
    return np.array(o), np.array(rr)


def compare(task: str, worlds: int, steps: int, device: str, seed: int = 3, perturb: float = 6e-8,
            extra: dict | None = None) -> dict:
    import physhand_mj as ph
    from physhand_dmc import vector

    domain, name, kwargs = TASKS[task]
    cfg = ph.Config(frame_dt=0.005, device=device, two_way=domain == "hand_hold")
    kw = dict(kwargs, config=cfg, **(extra or {}))
    env = vector.make(domain, name, num_envs=worlds, task_kwargs=kw, device=device)
    obs, _ = env.reset(seed=seed)
    acts = actions(env.task.normalise_ctrl(env.physics.host("ctrl")), steps)
    batch_obs, batch_rew = [obs], []
    for k in range(steps):
        obs, r, *_ = env.step(acts[k])
        batch_obs.append(obs)
        batch_rew.append(r)
    batch_obs, batch_rew = np.array(batch_obs), np.array(batch_rew)
    rows = []
    for w in range(worlds):
        kw_w = dict(kw, random=seed + w)
        o, rr = single_run(domain, name, kw_w, acts[:, w])
        row = dict(world=w, reward=float(np.abs(rr - batch_rew[:, w]).max()))
        for key, s in env.obs_slices.items():
            row[key] = float(np.abs(o[:, s] - batch_obs[:, w, s]).max())
        rows.append(row)
        if perturb:  # the single environment against itself with its qpos rounded differently
            o2, rr2 = single_run(domain, name, kw_w, acts[:, w], perturb, seed=w)
            row = dict(world=f"{w} (single vs single, qpos x (1 + {perturb:g} N))", reward=float(np.abs(rr - rr2).max()))
            for key, s in env.obs_slices.items():
                row[key] = float(np.abs(o[:, s] - o2[:, s]).max())
            rows.append(row)
    env.close()
    return dict(task=task, device=device, worlds=worlds, steps=steps, rows=rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--task", default="fingertip_press", choices=sorted(TASKS))
    ap.add_argument("--worlds", type=int, default=2)
    ap.add_argument("--steps", type=int, default=6, help="env steps compared")
    ap.add_argument("--perturb", type=float, default=6e-8,
                    help="also the single env against itself with qpos x (1 + perturb N(0, 1)) (0: not)")
    ap.add_argument("--task-kwargs", default="{}", help='JSON, e.g. \'{"mass_range": [0.08, 0.3], "float_frames": 0}\'')
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    res = compare(a.task, a.worlds, a.steps, a.device, perturb=a.perturb, extra=json.loads(a.task_kwargs))
    for row in res["rows"]:
        print(" ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
    if a.out:
        a.out.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
