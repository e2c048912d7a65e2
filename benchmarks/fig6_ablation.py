"""The paper's Fig. 6 ablation in numbers: (a) edge + tet, (b) + flesh attachment, (c) + skin smoothness.

Two settings, each 100 frames of 5 ms (10 substeps x 1 iteration, Jacobi, CPU):
  gravity: bones fixed in the open pose, palm down, 9.81 m/s^2 (the paper's Sec. 4.1 setting);
  grasp:   the bones close to 50 % of the power grasp over 50 frames, then hold.
Figures: flesh sag = mean / max displacement of flesh vertices from their rest position (mm, gravity
only); skin distortion = RMS and 99th percentile of the change of the skin dihedral angles (deg).
Writes docs/benchmarks/fig6_ablation.json and docs/images/fig6_ablation.png.
Run: python benchmarks/fig6_ablation.py
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import physhand_mj as ph
from physhand_mj.solver.model import signed_dihedral

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {"(a) edge + tet": dict(attachment=False, smoothness=False),
           "(b) + attachment": dict(smoothness=False),
           "(c) + smoothness": {}}


def run(asset, model, data, ids, setting: str, **kw) -> dict:
    cfg = ph.Config.from_dict(dict(device="cpu", **kw))  # (flat: the families are Tuning options)
    solver = ph.Solver(ph.make_model(asset, cfg), cfg)
    q_open, q_power = model.key("open").qpos, model.key("power").qpos
    poses = ph.bone_poses_at(model, data, q_open, ids)
    state = solver.make_state(*ph.mount_pose(model, data))
    x0 = state.x.numpy().astype(float)
    for f in range(100):
        if setting == "grasp":
            poses = ph.bone_poses_at(model, data, q_open + 0.5 * min(1.0, (f + 1) / 50) * (q_power - q_open), ids)
        solver.set_body_poses(state, *poses)
        solver.step(state)
    x = state.x.numpy().astype(float)
    flesh = asset.layer == ph.Layer.FLESH
    sag = np.linalg.norm(x - x0, axis=1)[flesh]
    dev = np.degrees(np.abs(signed_dihedral(x, asset.dihedral) - signed_dihedral(asset.positions, asset.dihedral)))
    return dict(flesh_sag_mean_mm=float(sag.mean() * 1e3), flesh_sag_max_mm=float(sag.max() * 1e3),
                dihedral_dev_rms_deg=float(np.sqrt(np.mean(dev ** 2))), dihedral_dev_p99_deg=float(np.percentile(dev, 99)))


def main():
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    ids = ph.body_ids(model, asset.body_names)
    out = {s: {name: run(asset, model, data, ids, s, **kw) for name, kw in CONFIGS.items()} for s in ("gravity", "grasp")}
    print(json.dumps(out, indent=1))
    (ROOT / "docs" / "benchmarks" / "fig6_ablation.json").write_text(json.dumps(out, indent=1))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
    names = list(CONFIGS)
    panels = [("gravity", "flesh_sag_mean_mm", "flesh sag, mean (mm)\npalm down, gravity"),
              ("gravity", "dihedral_dev_rms_deg", "skin dihedral change, RMS (deg)\npalm down, gravity"),
              ("grasp", "dihedral_dev_rms_deg", "skin dihedral change, RMS (deg)\n50 % power grasp")]
    for ax, (setting, key, title) in zip(axes, panels):
        vals = [out[setting][n][key] for n in names]
        ax.bar(range(3), vals, color=["#bbbbbb", "#88aadd", "#3366aa"])
        ax.set_xticks(range(3), [n.split(") ")[0] + ")" for n in names])
        ax.set_title(title, fontsize=9)
        for i, v in enumerate(vals):
            ax.annotate(f"{v:.3g}", (i, v), ha="center", va="bottom", fontsize=8)
    fig.suptitle("Fig. 6 ablation: (a) edge + tet, (b) + attachment (Eq. 4-5), (c) + smoothness (Eq. 6)", fontsize=10)
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "images" / "fig6_ablation.png", dpi=110)


if __name__ == "__main__":
    main()
