"""The still hand's frame once asleep (issue 13's 0.15 ms on the H100), and where its host time goes.

The open hand with a 2 cm sphere 1 m away settles and falls asleep (Config.sleep_speed); then
``--frames`` asleep frames (``set_body_poses`` + ``step``) are timed one by one: median, mean, 90th
and 99th percentiles (ms). ``--profile`` adds Python's cProfile over as many frames again (its top
functions by own time), to show the host work left in a frame that launches one graph.

    python benchmarks/asleep_frame.py [--device cuda] [--frames 2000] [--profile] [--out PATH]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def main():
    from activity_frame import _solver_case

    import warp as wp

    from physhand_mj.bench import device_name

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--frames", type=int, default=2000, help="timed asleep frames (count)")
    p.add_argument("--profile", action="store_true", help="cProfile over as many frames again (top 20 by own time)")
    p.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/asleep_frame_<device>.json)")
    a = p.parse_args()
    wp.init()
    frame, _, _ = _solver_case(a.device, "far", sleep=True)
    for _ in range(20):  # warm: the sleeping frame's graph captured
        if not frame()["asleep"]:
            raise RuntimeError("the hand woke up")
    ms = np.empty(a.frames)
    for i in range(a.frames):
        t = time.perf_counter()
        frame()
        ms[i] = (time.perf_counter() - t) * 1e3
    import physhand_mj

    row = dict(device=device_name(a.device if a.device != "cuda" else "cuda:0"), frames=a.frames,
               package=str(Path(physhand_mj.__file__).parent.relative_to(ROOT)),
               ms_median=round(float(np.median(ms)), 4), ms_mean=round(float(ms.mean()), 4),
               ms_p90=round(float(np.percentile(ms, 90)), 4), ms_p99=round(float(np.percentile(ms, 99)), 4))
    if a.profile:
        prof = cProfile.Profile()
        prof.enable()
        for _ in range(a.frames):
            frame()
        prof.disable()
        s = io.StringIO()
        pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(20)
        row["profile"] = s.getvalue()
    print(json.dumps({k: v for k, v in row.items() if k != "profile"}), flush=True)
    if a.profile:
        print(row["profile"])
    out = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"asleep_frame_{a.device.split(':')[0]}.json"
    out.write_text(json.dumps(row, indent=1))


if __name__ == "__main__":
    main()
