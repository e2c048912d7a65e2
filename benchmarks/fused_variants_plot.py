"""docs/images/fused_variants.png from benchmarks/fused_variants.py's JSONs (no GPU needed).

Left: each step of the fused kernel as a ratio to the step before, measured in the same process
(the machines lent on 2026-11-27 differed by up to 1.7 x, so only ratios within one run are drawn;
the branch-free clamp, measured across machines only, is left out, and the steps' product is not a
measurement: the old and the shipped kernel in one run, 2.58 x, is).
Right: hand-frames/s against threads a block at W = 4,096 (the shipped variant, one machine).

    python benchmarks/fused_variants_plot.py
"""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "docs" / "benchmarks"

# (label, file, worlds, variant, reference variant): each step against the one before, same run
STEPS = [
    ("fixed-point sum\n+ row masses", "fused_variants_cuda_4096.json", 4096, "fixed_row", "base"),
    ("rest data\npinned", "fused_variants_cuda_pinned_4096.json", 4096, "pinned", "fixed_row"),
    ("vector\nloads", "fused_variants_cuda_vec_4096.json", 4096, "vec", "pinned"),
    ("frame in\none launch", "fused_variants_cuda_frame_4096.json", 4096, "frame", "vec"),
    ("640 threads\n(was 1,024)", None, 4096, "frame", "frame"),
]
BLOCKS = {384: "fused_variants_cuda_block384_4096.json", 512: "fused_variants_cuda_block512_4096.json",
          576: "fused_variants_cuda_block576b_4096.json", 640: "fused_variants_cuda_block640_4096.json",
          704: "fused_variants_cuda_block704b_4096.json", 768: "fused_variants_cuda_block768_4096.json",
          896: "fused_variants_cuda_block896_4096.json", 1024: "fused_variants_cuda_block1024_4096.json"}


def row(name: str, worlds: int) -> dict:
    rows = json.loads((DATA / name).read_text())["rows"]
    return next(r for r in rows if r["worlds"] == worlds)


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    blocks = {b: row(f, 4096)["frame"]["hand_frames_per_s"] for b, f in BLOCKS.items()}
    ratios = []
    for label, name, w, var, ref in STEPS:
        if name is None:  # (the block change: 640 against 1,024 threads, one machine, separate processes)
            ratios.append((label, blocks[640] / blocks[1024]))
        else:
            r = row(name, w)
            ratios.append((label, r[var]["hand_frames_per_s"] / r[ref]["hand_frames_per_s"]))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    a.bar(range(len(ratios)), [x for _, x in ratios], color="#4c72b0")
    a.axhline(1.0, color="k", lw=0.8)
    a.set_xticks(range(len(ratios)), [lab for lab, _ in ratios], fontsize=8)
    for i, (_, x) in enumerate(ratios):
        a.text(i, x + 0.02, f"{x:.2f} x", ha="center", fontsize=9)
    total = 1.0
    for _, x in ratios:
        total *= x
    a.set_ylabel("hand-frames/s against the step before (same machine)")
    a.set_title("fused substep, W = 4,096, H100: each step against the one before", fontsize=10)
    a.set_ylim(0.0, 2.05)
    a.text(0.98, 0.97, "ratios from different machines (their product is not a measurement);\n"
           "the old and the shipped kernel in one run: 2.58 x (a slow machine)",
           transform=a.transAxes, va="top", ha="right", fontsize=7.5)
    xs = sorted(blocks)
    b.plot(xs, [blocks[k] / 1e3 for k in xs], "o-", color="#dd8452")
    b.set_xlabel("threads a block (one world a block)")
    b.set_ylabel("thousand hand-frames/s, W = 4,096")
    b.set_title("the shipped variant against the block size (one H100)", fontsize=10)
    b.grid(alpha=0.3)
    fig.tight_layout()
    out = ROOT / "docs" / "images" / "fused_variants.png"
    fig.savefig(out, dpi=110)
    print(json.dumps(dict(out=str(out.relative_to(ROOT)), steps=[(lab.replace("\n", " "), round(x, 3))
                                                                 for lab, x in ratios], product=round(total, 2))))


if __name__ == "__main__":
    main()
