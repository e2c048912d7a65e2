"""Where the tet mesh inverts: the hand closes from open to the power fist over 50 frames, holds 20,
and opens again over 50; default solver (Jacobi, 10 substeps x 1 iteration, CPU).

Per 10 frames: flexion fraction, inverted solver tets (at least one movable vertex), inverted
bone-gap tets (four skeleton vertices: they follow the bones and no solver can right them), flesh
volume change, and the largest displacement from the rest shape once open again.
Writes docs/benchmarks/grasp_inversions.json. Run: python benchmarks/grasp_inversions.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import physhand_mj as ph
from physhand_mj.solver.diagnostics import signed_volumes6

ROOT = Path(__file__).resolve().parents[1]


def main():
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    ids = ph.body_ids(model, asset.body_names)
    cfg = ph.Config(device="cpu")
    solver = ph.Solver(ph.make_model(asset, cfg), cfg)
    q_open, q_power = model.key("open").qpos, model.key("power").qpos
    ph.bone_poses_at(model, data, q_open, ids)
    state = solver.make_state(*ph.mount_pose(model, data))
    x0 = state.x.numpy().astype(float)
    fixed4 = (asset.layer[asset.tets] == ph.Layer.SKELETON).all(axis=1)
    v0 = asset.tet_rest_volume[~fixed4].sum()
    rows = []
    for f in range(170):
        a = min(1.0, (f + 1) / 50) if f < 70 else max(0.0, 1 - (f - 69) / 50)
        solver.set_body_poses(state, *ph.bone_poses_at(model, data, q_open + a * (q_power - q_open), ids))
        guard = solver.step(state)
        if f % 10 == 9:
            x = state.x.numpy().astype(float)
            v6 = signed_volumes6(x, asset.tets)
            rows.append(dict(frame=f + 1, flexion=round(a, 2), inverted_solver_tets=guard["inverted"],
                             inverted_bone_gap_tets=int((v6[fixed4] <= 0).sum()),
                             volume_change_pct=round(float((v6[~fixed4].sum() / 6 / v0 - 1) * 100), 3),
                             max_offset_mm=round(float(np.abs(x - x0).max() * 1e3), 3)))
            print(rows[-1], flush=True)
    out = dict(solver_tets=int(solver.model.guard_tets.shape[0]), bone_gap_tets=int(fixed4.sum()), rows=rows)
    (ROOT / "docs" / "benchmarks" / "grasp_inversions.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
