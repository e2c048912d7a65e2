"""One hard contact case run many times: how often its held frames keep residue, by both families of
measures. On CUDA the atomics sum in no fixed order, so runs of one case differ by themselves; on the
CPU every run is the same, and ``--perturb`` moves run k's ``Config.tuning.contact_offset`` by a relative
k x perturb (1e-4: 0.4 nm on the default 4 um), which sends the chaotic held contact down another
path of the same physics: the CPU's rate of such frames, not one path's luck.

    python benchmarks/case_repeats.py [--device cuda] [--case mesh_cone] [--site palm] [--start -0.004]
                                      [--repeats 20] [--frames 40] [--perturb 0] [--config JSON] [--out PATH]

The case is benchmarks/hard_contact_hold.py's (``cases.press_case`` pressed 4 mm over 15 frames from
``--start`` m, then held). Per run: the held frames with anything inside (skin samples on the
order-5 and order-9 lattices, object points and the denser check points), the worst depth (um) and
whether the last frame is clean. Prints one line per run and a summary; writes JSON with ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.cases import press_case, run_case  # noqa: E402
from hard_contact_hold import PRESS_FRAMES, held_residue, path_config  # noqa: E402  (benchmarks/: the script's folder)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--case", default="mesh_cone", help="press_case kind (hard_contact_hold.KINDS)")
    ap.add_argument("--site", default="palm", choices=("fingertip", "palm"), help="where it presses")
    ap.add_argument("--start", type=float, default=-0.004, help="start offset (m; negative: inside the skin)")
    ap.add_argument("--repeats", type=int, default=20, help="runs of the case (count)")
    ap.add_argument("--frames", type=int, default=40, help="5 ms frames a run (held from 15 on)")
    ap.add_argument("--perturb", type=float, default=0.0, help="run k's contact_offset x (1 + k x this) (relative; "
                    "0: every run the same Config)")
    ap.add_argument("--config", default="{}", help="Config fields as JSON")
    ap.add_argument("--out", default=None, help="JSON path (none: print only)")
    a = ap.parse_args()
    if a.frames <= PRESS_FRAMES:
        ap.error(f"--frames must exceed {PRESS_FRAMES} (the press)")
    asset = ph.load_asset()
    over = json.loads(a.config)
    runs = []
    offset = path_config(a.device, over, 0, a.perturb).contact_offset
    for k in range(a.repeats):
        cfg = path_config(a.device, over, k, a.perturb)
        r = run_case(press_case(a.case, site=a.site, depth=0.004, start=a.start), cfg, frames=a.frames, asset=asset)
        skin, obj = held_residue(r, a.frames)
        bad = (skin > 0) | (obj > 0)
        row = dict(held_with_residue=int(bad.sum()), worst_um=round(float(max(skin.max(), obj.max())), 2),
                   clean_at_end=bool(skin[-1] == 0 and obj[-1] == 0), median_ms=round(float(np.median(r["ms"][1:])), 3))
        runs.append(row)
        print(json.dumps(dict(run=k, **row)), flush=True)
    dirty = [r for r in runs if r["held_with_residue"]]
    summary = dict(device=device_name(a.device if a.device != "cuda" else "cuda:0"), case=a.case, site=a.site,
                   start_m=a.start, config=dict(over, contact_offset=offset), perturb=a.perturb, repeats=a.repeats,
                   held_frames_a_run=a.frames - PRESS_FRAMES,
                   runs_with_residue=len(dirty), held_frames_with_residue=sum(r["held_with_residue"] for r in runs),
                   worst_um=max((r["worst_um"] for r in runs), default=0.0),
                   runs_dirty_at_end=sum(not r["clean_at_end"] for r in runs))
    print(json.dumps(summary), flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(dict(summary=summary, runs=runs), indent=1))


if __name__ == "__main__":
    main()
