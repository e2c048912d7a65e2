"""The GPU peers in one plot: Newton's VBD and XPBD (newton_gpu.py) and MuJoCo Warp's flex beside
physhand_mj (mujoco_warp_gpu.py --physhand), on the same work and device.

    python benchmarks/peers/plot_gpu.py   # reads docs/benchmarks/peers_{newton,mjwarp}_cuda.json, writes docs/images/peers_cuda.png
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from run_cpu import plot  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def main():
    newton = json.loads((ROOT / "docs/benchmarks/peers_newton_cuda.json").read_text())
    mjw = json.loads((ROOT / "docs/benchmarks/peers_mjwarp_cuda.json").read_text())
    if newton["device"] != mjw["device"] or newton["frames"] != mjw["frames"] or newton["depth_mm"] != mjw["depth_mm"]:
        raise SystemExit("the two GPU runs differ in device, frames or depth: re-run them on one machine")
    result = dict(mjw, runs=mjw["runs"] + newton["runs"])
    plot(result, ROOT / "docs/images/peers_cuda.png")
    print(ROOT / "docs/images/peers_cuda.png")


if __name__ == "__main__":
    main()
