"""Cost of one MyoSuite env step with the soft skin (physhand_myosuite.SoftSkin), split by stage.

Per env step: the env's own step (MyoSuite: frame_skip MuJoCo steps, observation, reward), the soft
hand's sync (bone and object poses in), solver frame (XPBD with contact and the frame's metrics,
frame_dt = the env's step, 0.5 ms substeps), pooling (soft-contact signals per region and object on
the solver's device) and the rest of the write-back (skin positions to the host), and building the
info / opt-in observation from the pooled buffers. A random muscle policy (seeded), two envs per
bone naming; kernel compilation and env construction are excluded (2 warm-up steps after reset).
Also the one-off costs: wrapper construction (SoftHand set-up) and reset (settling), and the
alternative to the compiled-model path: add_skin on the env's MjSpec and a recompile.
Writes docs/benchmarks/myosuite_step_<device>.json. Run: python benchmarks/myosuite_step.py [--device cpu|cuda] [--steps N]
"""

from __future__ import annotations

import argparse
import copy
import json
import time
import warnings
from pathlib import Path

import numpy as np

import physhand_mj as ph
import physhand_myosuite as pm
from physhand_mj.bench import device_name

ROOT = Path(__file__).resolve().parents[1]
ENVS = ("myoHandReorient8-v0", "myoHandReorient100-v0", "myoHandObjHoldFixed-v0", "myoHandKeyTurnFixed-v0")


def run(env_id: str, device: str, steps: int, warm: int = 2) -> dict:
    t0 = time.perf_counter()
    env = pm.make(env_id, device=device, observe=True)
    t1 = time.perf_counter()
    env.reset(seed=0)
    t2 = time.perf_counter()
    env.action_space.seed(0)
    for _ in range(warm):
        env.step(env.action_space.sample())
    hand, sensor = env.hand, env.sensor
    hand._timing = dict(sync=0.0, solver=0.0, writeback=0.0, frames=0)  # drop the warm-up from the means
    sensor.seconds, env.log = 0.0, []
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            break
    n = len(env.log)
    m = hand.metrics()
    col = lambda k: float(np.mean([r[k] for r in env.log]))  # noqa: E731
    pool = 1e3 * sensor.seconds / n
    out = dict(env=env_id, naming=hand.naming.scheme, steps=n, env_dt_ms=1e3 * env.dt, substeps=env.config.substeps,
               objects=len(hand.object_geoms), ms_env=col("ms_env"), ms_sync=m["ms_sync"], ms_solver=m["ms_solver"],
               ms_pooling=pool, ms_writeback=m["ms_writeback"] - pool, ms_obs=col("ms_obs"),
               ms_soft=col("ms_soft"), ms_step=col("ms_env") + col("ms_soft") + col("ms_obs"),
               s_construct=t1 - t0, s_reset=t2 - t1,
               penetration_max_um=max(r["penetration_max_um"] for r in env.log),
               contact_area_cm2_max=max(r["contact_area_cm2"] for r in env.log))
    # the alternative: rebuild the env's model with the skin mesh geom (attach) -- a recompile per env
    spec = getattr(env.unwrapped, "_mj_spec", None)
    if spec is not None:
        spec = spec.copy() if hasattr(spec, "copy") else copy.deepcopy(spec)
        t = time.perf_counter()
        ph.add_skin(spec, "auto", hand.asset)
        spec.compile()
        out["s_add_skin_recompile"] = time.perf_counter() - t
    env.close()
    return {k: round(v, 3) if isinstance(v, float) else v for k, v in out.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--steps", type=int, default=10, help="timed env steps per env (after 2 warm-up steps)")
    a = p.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = [run(e, a.device, a.steps) for e in ENVS]
    res = dict(device=device_name(a.device), steps=a.steps, rows=rows)
    path = ROOT / "docs" / "benchmarks" / f"myosuite_step_{'cpu' if a.device == 'cpu' else 'cuda'}.json"
    path.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res))


if __name__ == "__main__":
    main()
