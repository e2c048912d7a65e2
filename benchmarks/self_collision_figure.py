"""docs/self_collision.md's figure of the options table, from the stored results:
docs/images/self_collision_options.png, from docs/benchmarks/self_collision_options_cpu.json (written by
``benchmarks/self_collision.py --out``: each keyframe and HOI grasp without the option, with it, and with
every option). Per keyframe that has any count: the skin vertices whose 0.2 mm outward offset lies
inside the closed skin, those buried 0.2 mm deep (no normal involved), and the skin edges through
another skin triangle, on a log scale (a 0 drawn as a mark on the axis).

    python benchmarks/self_collision_figure.py [--data F.json] [--out F.png]
    python benchmarks/self_collision_figure.py --every   # docs/images/self_every.png

``--every``: Tuning.self_every's front instead, from docs/benchmarks/self_every_1203.json: the batched
H200 throughput (W = 4,096, pipelined) and the ``power`` keyframe's counts per k.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA, IMAGES = ROOT / "docs" / "benchmarks", ROOT / "docs" / "images"
MODES = (("off", "off", "#b0b0b0"), ("on", "self_collision", "#4c72b0"), ("all", "every option", "#55a868"))
COUNTS = (("inside_200um", "offset 0.2 mm inside"), ("buried_200um", "buried 0.2 mm deep"),
          ("crossing_edges", "skin edges through the skin"))


def mode(r: dict) -> str:
    return "off" if not r["self_collision"] else ("all" if r.get("self_edges") else "on")


def figure(path: Path = DATA / "self_collision_options_cpu.json", out: Path = IMAGES / "self_collision_options.png") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = json.loads(Path(path).read_text())
    at = {(r["key"] if r["scene"] == "hand_only" else r["scene"].removeprefix("hoi_"), mode(r)): r for r in rows}
    order = ("open", "pinch", "power", "apple", "box", "bowl", "glass1", "glass2", "phone", "toothpaste")
    names = sorted(dict.fromkeys(k for k, _ in at), key=lambda k: order.index(k) if k in order else len(order))
    keys = [k for k in names if any(at[(k, m)][c] for m, *_ in MODES for c, _ in COUNTS if (k, m) in at)]
    zero = [k for k in names if k not in keys]
    fig, axes = plt.subplots(1, len(COUNTS), figsize=(4.2 * len(COUNTS), 3.6), sharey=True)
    x = np.arange(len(keys))
    for ax, (count, title) in zip(axes, COUNTS):
        for i, (m, label, colour) in enumerate(MODES):
            v = np.array([at[(k, m)][count] if (k, m) in at else np.nan for k in keys], float)
            xs = x + (i - 1) * 0.27
            ax.bar(xs, np.where(v > 0, v, np.nan), 0.27, color=colour, label=label)
            ax.plot(xs[v == 0], np.full((v == 0).sum(), 0.8), "v", color=colour, ms=5)
            for xi, vi in zip(xs, v):
                if vi > 0:
                    ax.text(xi, vi * 1.1, f"{int(vi)}", ha="center", va="bottom", fontsize=6.5)
        ax.set_yscale("log")
        ax.set_ylim(0.7, 3000)
        ax.set_xticks(x, keys, rotation=30, ha="right")
        ax.set_title(title, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("skin vertices / edges (of 5,000 / 14,994)")
    axes[0].legend(fontsize=8, loc="upper right")
    fig.suptitle("After 36 frames (CPU); a triangle on the axis: 0" + (f"; 0 in every mode: {', '.join(zero)}" if zero else ""),
                 fontsize=10)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def every_figure(path: Path = DATA / "self_every_1203.json", out: Path = IMAGES / "self_every.png") -> Path:
    """Tuning.self_every: hand-frames/s (H200, W = 4,096 settled, pipelined; the first machine's rows) and
    ``power``'s counts after 36 frames (the option alone, CPU and H200) for k = 1, 2, 3."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = json.loads(Path(path).read_text())["rows"]
    batch = [r for r in rows if r["kind"].startswith("batched W=4096") and "runs" not in r]
    tput = {r["self_every"]: r["hand_frames_per_s_submit"] for r in batch}
    fig, (a, b) = plt.subplots(1, 2, figsize=(10.5, 3.6))
    labels = ["off", "k = 1", "k = 2", "k = 3"]
    v = [tput[None], tput[1], tput[2], tput[3]]
    a.bar(labels, v, color=["#b0b0b0", "#4c72b0", "#4c72b0", "#4c72b0"])
    for i, y in enumerate(v):
        a.text(i, y * 1.01, f"{y:,.0f}", ha="center", va="bottom", fontsize=8)
    a.axhline(50000, ls="--", color="#c44e52", lw=1)
    a.text(1.0, 50800, "the issue's 50,000", color="#c44e52", fontsize=8, ha="center")
    a.set_ylim(0, 68000)
    a.set_ylabel("hand-frames/s")
    a.set_title("H200, 4,096 worlds, settled, pipelined", fontsize=10)
    one = {(r["device"], r["self_every"]): r for r in rows if r.get("key") == "power" and r.get("options") == "option"}
    x = np.arange(len(COUNTS))
    for i, (dev, k, colour) in enumerate((("cpu", 1, "#4c72b0"), ("cpu", 2, "#8172b2"), ("cpu", 3, "#c44e52"),
                                          ("cuda", 1, "#64b5cd"), ("cuda", 2, "#b39ddb"), ("cuda", 3, "#f4a582"))):
        ys = [one[(dev, k)][c] for c, _ in COUNTS]
        b.bar(x + (i - 2.5) * 0.13, ys, 0.13, color=colour, label=f"{'CPU' if dev == 'cpu' else 'H200'}, k = {k}")
    b.set_xticks(x, [t for _, t in COUNTS], fontsize=8)
    b.set_ylabel("skin vertices / edges")
    b.set_title("power after 36 frames, self_collision", fontsize=10)
    b.legend(fontsize=7, ncol=2)
    b.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DATA / "self_collision_options_cpu.json"))
    ap.add_argument("--out", default=str(IMAGES / "self_collision_options.png"))
    ap.add_argument("--every", action="store_true", help="Tuning.self_every's figure (docs/images/self_every.png) instead")
    a = ap.parse_args()
    print(every_figure() if a.every else figure(Path(a.data), Path(a.out)))


if __name__ == "__main__":
    main()
