"""The box grasp at W = 4,096 on an H100, change by change (issue 15's hardest analytic grasp), from
the batch_hoi JSONs under docs/benchmarks: hand-frames per second with multires contact, every row 0
inside by all four measures. Bars from different machines are not comparable to better than the
machines' spread (up to 1.7 x on the same code); the last three ran on one machine.

    python benchmarks/box_progress_plot.py   (writes docs/images/box_progress_4096.png)
"""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BARS = [  # (label, JSON under docs/benchmarks, machine group)
    ("float sum\n(11-26)", "batch_hoi_cuda_box_4096.json", "a"),
    ("fixed-point\nsubstep", "batch_hoi_cuda_box_block640.json", "b"),
    ("feature\nslack", "batch_hoi_cuda_box_slack_4096.json", "c"),
    ("one walk\nper patch", "batch_hoi_cuda_box_s37_4096.json", "d"),
    ("+ shifted\ncopy kept", "batch_hoi_cuda_box_s37c_4096.json", "e"),
    ("lists within\nthe slack", "batch_hoi_cuda_box_s38_4096_share1.json", "f"),
    ("within half\n(Config())", "batch_hoi_cuda_box_s38_4096.json", "f"),
    ("the same,\n30 frames", "batch_hoi_cuda_box_s38_4096_30.json", "f"),
]


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = []
    for label, name, group in BARS:
        d = json.loads((ROOT / "docs" / "benchmarks" / name).read_text())
        r = next(r for r in d["rows"] if r["worlds"] == 4096)
        inside = sum(int(r.get(k) or 0) for k in ("penetration_count_max", "order9_count_max",
                                                  "object_in_skin_count_max", "check_count_max"))
        rows.append((label, r["hand_frames_per_s"], group, inside))
    fig, ax = plt.subplots(figsize=(7.6, 3.6))
    colors = ["tab:green" if hz >= 10_000 else "tab:orange" for _, hz, _, _ in rows]
    ax.bar(range(len(rows)), [hz for _, hz, _, _ in rows], color=colors,
           edgecolor=["0.2" if g == "f" else "none" for _, _, g, _ in rows])
    for i, (_, hz, _, inside) in enumerate(rows):
        ax.text(i, hz * 1.01, f"{int(hz + 0.5):,}", ha="center", fontsize=7.5)
        ax.text(i, 400, f"inside: {inside}", ha="center", fontsize=6.5, color="white")
    ax.axhline(10_000, color="0.3", lw=0.8, ls=":")
    ax.text(-0.4, 10_150, "issue 15's target", fontsize=7, color="0.3", ha="left")
    ax.set_xticks(range(len(rows)), [label for label, _, _, _ in rows], fontsize=7)
    ax.set(ylabel="hand-frames per second", ylim=(0, 12_500))
    ax.set_title("hoi_box grasp, 4,096 worlds, an H100 per bar (the outlined three: one machine), 10 timed frames "
                 "unless said\ninside: skin and object points inside, all four measures, the worst world", fontsize=7.5)
    fig.tight_layout()
    out = ROOT / "docs" / "images" / "box_progress_4096.png"
    fig.savefig(out, dpi=130)
    plt.close(fig)
    print(out.relative_to(ROOT))


if __name__ == "__main__":
    main()
