"""A random-policy episode of a physhand_dmc task (dm_control API) rendered to a picture strip.

Run:  python examples/dmc_random_policy.py [OUT_DIR] [DOMAIN TASK]      (default: hand_hold apple)
Success looks like: one line per env step (reward in [0, 1], the object's soft-contact area / force /
penetration), then OUT_DIR/dmc_<domain>_<task>.png, a strip of frames from ``physics.render`` in
which the skin deforms and follows the random finger motion (and an .mp4 of every step when imageio
is installed: ``pip install -e ".[video]"``). About 40-80 ms per step on a 2-core CPU.
"""

import sys
from pathlib import Path

import numpy as np

import physhand_mj as ph  # noqa: F401  (picks MuJoCo's offscreen GL backend before mujoco loads)
from physhand_dmc import suite
from physhand_mj.render import write_png


def main(out: Path, domain: str = "hand_hold", task: str = "apple", steps: int = 40, strip: int = 5,
         seed: int = 0, task_kwargs: dict | None = None) -> dict:
    kwargs = dict(random=seed, time_limit=steps * 0.01)
    kwargs.update(task_kwargs or {})
    env = suite.load(domain, task, task_kwargs=kwargs)
    policy = np.random.RandomState(seed)
    spec = env.action_spec()
    ts = env.reset()
    frames, rewards = [env.physics.render(240, 320, camera_id="side")], []
    print("step  reward  area cm^2  force N  penetrating samples")
    while not ts.last():
        ts = env.step(policy.uniform(spec.minimum, spec.maximum, spec.shape))
        rewards.append(ts.reward)
        area, force, count, _ = ts.observation["object_contact"]
        print(f"{len(rewards):4d}  {ts.reward:6.3f}  {area:9.2f}  {force:7.3f}  {int(count):19d}")
        frames.append(env.physics.render(240, 320, camera_id="side"))
    keep = np.linspace(0, len(frames) - 1, strip).round().astype(int)
    png = write_png(np.concatenate([frames[i] for i in keep], axis=1), out / f"dmc_{domain}_{task}.png")
    video = None
    try:
        import imageio.v2 as imageio

        video = out / f"dmc_{domain}_{task}.mp4"
        imageio.mimwrite(video, frames, fps=20, macro_block_size=None)
    except ImportError:
        pass
    return dict(picture=png, video=video, frames=frames, rewards=rewards, env=env)


def test_final(tmp_path=None):
    from physhand_mj import Config

    res = main(Path(tmp_path or "example_out"), steps=4, strip=3,
               task_kwargs=dict(settle_frames=3, config=Config(substeps=3)))
    assert len(res["rewards"]) == 4 and all(0.0 <= r <= 1.0 for r in res["rewards"])
    first, last = res["frames"][0], res["frames"][-1]
    assert np.mean(np.any(first != last, axis=2)) > 0.001  # the hand moved on screen
    assert res["picture"].stat().st_size > 10_000
    res["env"].physics.free()


if __name__ == "__main__":
    args = sys.argv[1:]
    out = Path(args[0]) if args else Path("example_out")
    dom, tsk = (args[1], args[2]) if len(args) >= 3 else ("hand_hold", "apple")
    r = main(out, dom, tsk)
    print(r["picture"], r["video"] or "")
    # free the render context now: left to dm_control's exit hook it is freed after Python has shut
    # down the thread it must be freed on (tracebacks at exit)
    r["env"].physics.free()
