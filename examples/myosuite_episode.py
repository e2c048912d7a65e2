"""A MyoSuite hand episode with the soft skin: a random muscle policy in one of MyoSuite 3's hand
envs, the skin solved after every env step, soft contact and penetration logged per step, and a
picture strip of the episode.

Run:  python examples/myosuite_episode.py [OUT_DIR] [ENV_ID] [STEPS]
      (default myoHandObjHoldFixed-v0, MyoHand's older bone names; myoHandReorient8-v0 uses the
      asset's names; needs the myosuite extra: pip install -e ".[myosuite]")
Success looks like: a line per step (reward, contact area cm^2, force N, penetration um, ms of the
env / soft hand), penetration 0 um, a finite skin, and OUT_DIR/myosuite_episode.png (a strip of 4
frames: the deformed skin on the hand, the env's object in the scene) and OUT_DIR/myosuite_log.csv.
"""

import sys
import warnings
from pathlib import Path

import numpy as np

import physhand_mj  # noqa: F401  (before mujoco: it picks MuJoCo's offscreen GL backend)
import physhand_myosuite as pm
from physhand_mj.render import write_png


def main(out: Path, env_id: str = "myoHandObjHoldFixed-v0", steps: int = 24, frames: int = 4, seed: int = 0) -> dict:
    with warnings.catch_warnings():  # MyoSuite's deprecation chatter
        warnings.simplefilter("ignore")
        env = pm.make(env_id, width=400, height=300)
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    shots = {int(round(k)) for k in np.linspace(1, steps, frames)}
    strip = []
    print("step  reward  area_cm2  force_n  penetration_um  ms_env  ms_soft")
    for t in range(1, steps + 1):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        row = env.log[-1]
        print(f"{t:4d}  {reward:6.2f}  {row['contact_area_cm2']:8.2f}  {row['contact_force_n']:7.3f}  "
              f"{row['penetration_max_um']:14.1f}  {row['ms_env']:6.1f}  {row['ms_soft']:7.1f}")
        if t in shots:
            strip.append(env.render())
        if terminated or truncated:
            break
    png = write_png(np.concatenate(strip, axis=1), out / "myosuite_episode.png")
    log = env.write_log(out / "myosuite_log.csv")
    rows = list(env.log)
    env.close()
    return dict(picture=png, log=log, rows=rows, env=env, strip=strip)


def test_final(tmp_path=None):
    res = main(Path(tmp_path or "example_out"), steps=3, frames=2)
    rows = res["rows"]
    assert len(rows) == 3 and all(r["finite"] for r in rows)
    assert max(r["penetration_max_um"] for r in rows) < 50.0, rows  # the skin stays out of the object
    assert len(res["strip"]) == 2 and res["picture"].stat().st_size > 20_000
    assert res["env"].hand.naming.scheme == "myosuite_old"


if __name__ == "__main__":
    args = sys.argv[1:]
    res = main(Path(args[0] if args else "example_out"), *(args[1:2]), *([int(args[2])] if len(args) > 2 else []))
    print(res["picture"], res["log"])
