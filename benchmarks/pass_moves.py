"""How far each contact pass moves the skin, and how many passes a stage runs (CPU, Warp's CPU kernels).

A contact stage runs passes until one moves no vertex (``Config.contact_passes`` at most; on CUDA
each pass that runs costs ~50 us, docs/activity.md). This probe records, for every pass that ran in
``--frames`` frames after ``--warmup`` frames of a shipped scene, the vertices it moved and the
largest move, then counts the passes a stage would run if a pass after one that moved no vertex by
more than a tolerance were skipped (the frame's last stage still running to the end): whether such
a tolerance could save passes.

    python benchmarks/pass_moves.py [--scene grasp_glass] [--key approach] [--warmup 45] [--frames 10]
"""

from __future__ import annotations

import argparse
import json
from collections import Counter

import mujoco
import numpy as np

import physhand_mj as ph
from physhand_mj.contact.contact import Contact

TOLERANCES_UM = (0.0, 1.0, 5.0, 20.0, 100.0)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="grasp_glass", help="shipped scene (physhand_mj.scene_path)")
    p.add_argument("--key", default="approach", help="keyframe to start from")
    p.add_argument("--warmup", type=int, default=45, help="5 ms frames before the probe (count)")
    p.add_argument("--frames", type=int, default=10, help="5 ms frames probed (count)")
    a = p.parse_args()
    log, frame = [], [0]
    record_pass = Contact._record_pass

    def probed(self, launch, ops, state, p, lst, skin, feat_count):  # a host op after each recorded pass
        stamp = self._slot
        out = record_pass(self, launch, ops, state, p, lst, skin, feat_count)
        stage = len(self._stage_slots) - 1

        def probe():
            moved = self.moved.numpy() == stamp
            d = self.disp.numpy()[moved]
            log.append((frame[0], stage, p, int(moved.sum()), float(d.max()) if len(d) else 0.0))

        ops.append(probe)
        return out

    Contact._record_pass = probed
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path(a.scene)))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key(a.key).id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device="cpu"))
    for _ in range(a.warmup):
        mujoco.mj_step(model, data)
        hand.step()
    log.clear()
    for _ in range(a.frames):
        mujoco.mj_step(model, data)
        hand.step()
        frame[0] += 1
    rows = np.array(log)
    stages = {}
    for f, s, _, _, d in rows:
        stages.setdefault((int(f), int(s)), []).append(d)
    last = max(s for _, s in stages)
    kept = {}
    for tol in TOLERANCES_UM:
        n = 0
        for (f, s), moves in stages.items():
            k = 1
            while k < len(moves) and (s == last or moves[k - 1] > tol * 1e-6):
                k += 1
            n += k
        kept[f"{tol:g}"] = round(n / a.frames, 2)
    print(json.dumps(dict(scene=a.scene, key=a.key, warmup=a.warmup, frames=a.frames,
                          passes_per_frame=round(len(rows) / a.frames, 2),
                          passes_per_stage=dict(sorted(Counter(len(v) for v in stages.values()).items())),
                          move_um_percentiles_10_50_90=np.percentile(rows[:, 4] * 1e6, [10, 50, 90]).round(1).tolist(),
                          passes_per_frame_with_tolerance_um=kept)))


if __name__ == "__main__":
    main()
