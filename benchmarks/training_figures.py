"""docs/training.md's figures from the stored results (docs/benchmarks/):

- docs/images/training_throughput.png: env-steps/s of the batched environments against W
  (vector_env_cuda.json, from ``benchmarks/vector_env.py``), beside the rigid MuJoCo Warp step of
  the same scenes measured in the same run;
- docs/images/training_curve.png: PPO on fingertip_press (ppo_fingertip_press_cuda.csv, from
  ``examples/train_ppo.py``): the mean reward per step and the mean episode return against env
  steps and wall time.

    python benchmarks/training_figures.py
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA, IMAGES = ROOT / "docs" / "benchmarks", ROOT / "docs" / "images"


def throughput(path: Path = DATA / "vector_env_cuda.json", out: Path = IMAGES / "training_throughput.png") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = json.loads(path.read_text())
    fig, ax = plt.subplots(figsize=(6, 4))
    for task, colour in (("hand_hold", "C0"), ("fingertip_press", "C1")):
        rows = sorted((r for r in res["rows"] if r["task"] == task), key=lambda r: r["worlds"])
        w = [r["worlds"] for r in rows]
        ax.loglog(w, [r["env_steps_per_s"] for r in rows], "-o", color=colour, label=f"{task} (soft hand)")
        ax.loglog(w, [r["rigid_env_steps_per_s"] for r in rows], "--", color=colour, alpha=0.6,
                  label=f"{task}: rigid MuJoCo Warp alone")
    ax.axhline(5000, color="k", lw=0.8, ls=":")
    ax.text(1.1, 5600, "5,000 env-steps/s", fontsize=8)
    ax.set_xlabel("environments W")
    ax.set_ylabel("env steps / s")
    ax.set_title(f"Batched soft-hand environments, {res['device']}", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def curve(path: Path = DATA / "ppo_fingertip_press_cuda.csv", out: Path = IMAGES / "training_curve.png") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(path.open()))
    step = [int(r["global_step"]) for r in rows]
    wall = [float(r["wall_s"]) for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(step, [100 * float(r["reward_mean"]) for r in rows], "-", label="100 x mean reward per step (rollout)")
    ep = [(s, float(r["episode_return"])) for s, r in zip(step, rows) if not math.isnan(float(r["episode_return"]))]
    ax.plot(*zip(*ep), "o", label="mean episode return (episodes ended in the rollout)")
    top = ax.secondary_xaxis("top", functions=(lambda s: s * wall[-1] / step[-1], lambda t: t * step[-1] / wall[-1]))
    top.set_xlabel("wall time (s, H200 + host PPO)")
    ax.set_xlabel("env steps")
    ax.set_ylabel("return (episode: 100 steps, at most 100)")
    ax.set_title("PPO from scratch on fingertip_press/index, 512 envs", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main() -> int:
    for f in (throughput, curve):
        print(f())
    return 0


if __name__ == "__main__":
    sys.exit(main())
