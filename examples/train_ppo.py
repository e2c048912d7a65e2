"""Train a policy with PPO on a batched soft-hand task (or any gymnasium vector env), from scratch.

Run:  python examples/train_ppo.py --domain fingertip_press --task index --num-envs 64 \\
          --total-steps 1000000 --device cuda --out runs/press
      python examples/train_ppo.py --gym Pendulum-v1 --num-envs 8 --total-steps 200000 --out runs/pendulum
The environment is ``physhand_dmc.vector.make(domain, task, num_envs=N, task_kwargs=..., device=...)``
(a gymnasium VectorEnv with flat Box observations), or ``gymnasium.make_vec(ID, N)`` with ``--gym``.
The algorithm is physhand_dmc.ppo (NumPy only, cleanrl's continuous-action defaults; every
PPOConfig field is a flag here, e.g. ``--num-minibatches 32 --no-norm-reward``); ``--num-steps``
defaults to 2048 // num_envs (at least 16), so a rollout holds about cleanrl's 2,048 env steps.
Success looks like: a progress bar with the mean episode return climbing; OUT/history.csv (a row per
update: physhand_dmc.ppo.HISTORY_FIELDS), OUT/learning_curve.png (episode return against env steps
and wall time; skipped, with a message, without matplotlib) and OUT/agent.npz (the networks and the
observation normaliser's mean and variance).
"""

import argparse
import csv
import json
import math
import sys
from dataclasses import fields
from pathlib import Path

from physhand_dmc.ppo import HISTORY_FIELDS, Agent, PPOConfig, train


def make_env(args):
    """The vector env the flags name: a gymnasium id with --gym, else the soft-hand suite task."""
    if args.gym:
        import gymnasium as gym

        return gym.make_vec(args.gym, num_envs=args.num_envs, vectorization_mode="sync"), args.gym
    try:
        from physhand_dmc import vector
    except ImportError as e:
        sys.exit(f"physhand_dmc.vector is not importable ({e}); use --gym ID for a gymnasium env")
    env = vector.make(args.domain, args.task, num_envs=args.num_envs, task_kwargs=json.loads(args.task_kwargs),
                      device=args.device)
    return env, f"{args.domain}/{args.task}"


def plot(history: list[dict], path: Path, title: str) -> Path | None:
    """Episode return against env steps (and wall seconds on the top axis); None without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no learning-curve plot (pip install matplotlib)")
        return None
    pts = [(h["global_step"], h["episode_return"], h["wall_s"]) for h in history if not math.isnan(h["episode_return"])]
    fig, ax = plt.subplots(figsize=(6, 4))
    if pts:
        steps, returns, walls = zip(*pts)
        ax.plot(steps, returns, "-o", ms=2)
        top = ax.secondary_xaxis("top", functions=(lambda s: s * walls[-1] / steps[-1],
                                                   lambda w: w * steps[-1] / walls[-1]))
        top.set_xlabel("wall time (s, at the run's mean rate)")
    ax.set_xlabel("env steps")
    ax.set_ylabel("mean episode return")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--domain", default="fingertip_press")
    p.add_argument("--task", default="index")
    p.add_argument("--task-kwargs", default="{}", help="JSON for physhand_dmc.vector.make's task_kwargs")
    p.add_argument("--gym", metavar="ID", help="train on gymnasium.make_vec(ID) instead (e.g. Pendulum-v1)")
    p.add_argument("--num-envs", type=int, default=8)
    p.add_argument("--total-steps", type=int, default=200_000, help="env steps summed over the envs")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", help="where the env steps (cpu|cuda); the policy runs on the host")
    p.add_argument("--out", type=Path, default=Path("runs/ppo"))
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    for f in fields(PPOConfig):  # every hyperparameter as a flag, defaulting to PPOConfig's
        flag = "--" + f.name.replace("_", "-")
        if isinstance(f.default, bool):
            p.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default)
        elif f.name == "num_steps":
            p.add_argument(flag, type=int, default=None, help="per env per rollout (default 2048 // num_envs, >= 16)")
        else:
            p.add_argument(flag, type=float if f.default is None else type(f.default), default=f.default)
    args = p.parse_args(argv)
    cfg = PPOConfig(**{f.name: getattr(args, f.name) for f in fields(PPOConfig)})
    cfg.num_steps = cfg.num_steps or max(16, 2048 // args.num_envs)

    env, name = make_env(args)
    obs_dim, act_dim = env.single_observation_space.shape[0], env.single_action_space.shape[0]
    agent = Agent(obs_dim, act_dim, seed=args.seed, hidden=cfg.hidden)
    args.out.mkdir(parents=True, exist_ok=True)
    batch = cfg.num_steps * args.num_envs
    from tqdm import tqdm

    bar = tqdm(total=max(1, args.total_steps // batch) * batch, unit="step", disable=args.quiet)
    with open(args.out / "history.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=HISTORY_FIELDS)
        writer.writeheader()

        def log(rec):
            writer.writerow(rec)
            fh.flush()  # a run stopped early keeps its rows
            bar.update(batch)
            bar.set_postfix(ret=f"{rec['episode_return']:.3g}", kl=f"{rec['approx_kl']:.3f}")

        history = train(env, args.total_steps, seed=args.seed, config=cfg, agent=agent, log=log)
    bar.close()
    env.close()
    agent.save(args.out / "agent.npz")
    wall = history[-1]["wall_s"]
    title = f"PPO on {name}, {args.num_envs} envs ({args.device}), {wall:.0f} s"
    png = plot(history, args.out / "learning_curve.png", title)
    last = [h["episode_return"] for h in history[-5:] if not math.isnan(h["episode_return"])]
    print(f"{name}: {history[-1]['global_step']} env steps in {wall:.1f} s "
          f"({history[-1]['global_step'] / wall:.0f} steps/s); last mean episode return "
          f"{sum(last) / len(last) if last else float('nan'):.3g}; {args.out / 'history.csv'}"
          + (f", {png}" if png else ""))
    return {"history": history, "agent": agent, "csv": args.out / "history.csv", "plot": png}


def test_final(tmp_path=None):
    # the soft-hand task itself on the CPU: two updates of 2 envs x 8 steps, episodes of 4 steps
    # (time_limit 0.04 s), so both updates finish episodes: losses finite, returns finite and moving
    out = Path(tmp_path or "example_out") / "ppo"
    res = main(["--domain", "fingertip_press", "--task", "index", "--num-envs", "2", "--total-steps", "32",
                "--num-steps", "8", "--num-minibatches", "2", "--update-epochs", "2", "--device", "cpu",
                "--task-kwargs", '{"time_limit": 0.04}', "--out", str(out), "--quiet"])
    with open(res["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 and all(math.isfinite(float(r[k])) for r in rows for k in ("policy_loss", "value_loss")), rows
    returns = [float(r["episode_return"]) for r in rows]
    assert all(math.isfinite(x) for x in returns) and returns[0] != returns[1], returns
    assert res["plot"] is None or res["plot"].stat().st_size > 5_000
    assert (out / "agent.npz").exists()


if __name__ == "__main__":
    main()
