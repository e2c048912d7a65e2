"""Two-way coupling's cost in BatchedHands: a two-way frame against a one-way frame of W worlds of the
soft slab, the same contact, the same device, the same run (issue 52 item 6, batched).

    python benchmarks/two_way_batch.py [--device cpu|cuda] [--worlds 1,64,1024] [--slab PATH] [--out JSON]

Each world is benchmarks/two_way.py's cost scene: the soft slab (physhand_mj/bench/slab.py) on its
table, a 30 x 30 x 20 mm box held 0.3 mm into its skin and sliding 3 mm to and fro (each world at
its own phase), kinematic (the skin does not move it: ``object_mass`` 0) with its sliding velocity
given, so the friction pass works. Timed: ``BatchedHands.step`` (poses in, the frame, the report;
with two_way also the objects' state packed and uploaded and the wrenches read back), median ms of
a frame after ``--skip`` frames, one-way and two-way alternating, twice each; the faster median of
each counts. ``--slab``: a slab saved with physhand_mj.asset.save_asset (a machine without TetGen);
``--save-slab PATH`` writes the one built here. Default JSON: docs/benchmarks/two_way_batch_<device>.json.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.types import GeomType  # noqa: E402

HALF = np.array([0.015, 0.015, 0.01])  # m: the box's half sizes
TABLE_Z = 0.1


def run(asset, device: str, worlds: int, two_way: bool, frames: int, skip: int) -> float:
    """Median ms of a frame of ``worlds`` worlds (after ``skip`` frames)."""
    top = float(asset.skin_vertices[:, 2].max())
    cfg = ph.Config(two_way=two_way, device=device)
    kw = dict(object_mass=np.zeros(1), object_friction=0.5) if two_way else {}
    hands = ph.BatchedHands(asset, worlds, cfg, pos=(0.0, 0.0, TABLE_Z),
                            objects=[dict(gtype=GeomType.BOX, size=HALF, name="box")], **kw)
    bone_pos = np.tile([0.0, 0.0, TABLE_Z], (worlds, 1, 1))
    bone_quat = np.tile([1.0, 0.0, 0.0, 0.0], (worlds, 1, 1))
    phase = np.linspace(0.0, 2 * np.pi, worlds, endpoint=False)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (worlds, 1, 1))
    hands.settle(bone_pos, bone_quat, frames=2)
    times = []
    try:
        for f in range(frames):
            y = 0.003 * np.cos(f * 0.05 + phase)
            pos = np.stack([np.zeros(worlds), y, np.full(worlds, TABLE_Z + top + HALF[2] - 3e-4)], 1)[:, None]
            extra = {}
            if two_way:
                vel = np.zeros((worlds, 1, 6))
                vel[:, 0, 1] = -0.003 * 0.05 / cfg.frame_dt * np.sin(f * 0.05 + phase)
                extra = dict(object_vel=vel)
            t0 = time.perf_counter()
            hands.step(bone_pos, bone_quat, pos, quat, **extra)
            times.append(time.perf_counter() - t0)
    finally:
        hands.close()
    return float(np.median(times[skip:])) * 1e3


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--worlds", default="1,64,1024", help="comma-separated world counts (default 1,64,1024)")
    ap.add_argument("--frames", type=int, default=40, help="frames per run (count, default 40)")
    ap.add_argument("--skip", type=int, default=10, help="first frames not timed (count, default 10)")
    ap.add_argument("--slab", default=None, help="a saved slab asset (.npz); default: built here (the build extra)")
    ap.add_argument("--save-slab", default=None, help="write the slab built here to this .npz and go on")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/two_way_batch_<device>.json)")
    args = ap.parse_args()
    from physhand_mj.asset import load_asset

    if args.slab:
        asset = load_asset(args.slab)
    else:
        from physhand_mj.bench.slab import soft_slab

        asset = soft_slab()
    if args.save_slab:
        from physhand_mj.asset import save_asset

        save_asset(asset, args.save_slab)
    out = dict(device=device_name(args.device), frames=args.frames, skip=args.skip, rows=[])
    for w in (int(x) for x in args.worlds.split(",")):
        res = {False: [], True: []}
        for _ in range(2):
            for two in (False, True):
                res[two].append(round(run(asset, args.device, w, two, args.frames, args.skip), 3))
        one, two = min(res[False]), min(res[True])
        row = dict(worlds=w, one_way_ms=one, two_way_ms=two, ratio=round(two / one, 3),
                   one_way_ms_per_world=round(one / w, 4), two_way_ms_per_world=round(two / w, 4), runs_ms=
                   {"one_way": res[False], "two_way": res[True]})
        out["rows"].append(row)
        print(json.dumps(row), flush=True)
    path = Path(args.out or Path(__file__).resolve().parents[1] / "docs" / "benchmarks"
                / f"two_way_batch_{args.device.split(':')[0]}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(path)


if __name__ == "__main__":
    main()
