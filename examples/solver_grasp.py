"""The XPBD solver on the embedded hand: MuJoCo closes the bones to the power grasp, the soft layers
follow, and the deformed skin goes back into the MuJoCo model for a picture.

Run:  python examples/solver_grasp.py [OUT_DIR]
Success looks like: a table of flexion / flesh volume change / inverted tets every 10 frames (volume
within about 3 %, no non-finite vertices) and OUT_DIR/solver_grasp.png, the hand in the fist with the
deformed skin over the bones.
"""

import sys
from pathlib import Path

import numpy as np

import physhand_mj as ph
from physhand_mj.figures import render_layers


def main(out: Path, frames: int = 60, closing_frames: int = 50) -> dict:
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    bones = ph.body_ids(model, asset.body_names)
    config = ph.Config()  # 5 ms frames, 10 substeps, gravity, Jacobi; device: Warp's default
    solver = ph.Solver(ph.make_model(asset, config), config)
    state = solver.make_state(*ph.mount_pose(model, data))  # rest shape at the hand mount
    q_open, q_fist = model.key("open").qpos.copy(), model.key("power").qpos.copy()
    v_rest = asset.tet_rest_volume.sum()
    print("frame  flexion  volume change  inverted tets")
    for f in range(frames):
        a = min(1.0, (f + 1) / closing_frames)
        solver.set_body_poses(state, *ph.bone_poses_at(model, data, q_open + a * (q_fist - q_open), bones))
        guard = solver.step(state)
        x = state.x.numpy().astype(float)
        tets = asset.tets
        volume = np.einsum("ij,ij->i", np.cross(x[tets[:, 1]] - x[tets[:, 0]], x[tets[:, 2]] - x[tets[:, 0]]),
                           x[tets[:, 3]] - x[tets[:, 0]]).sum() / 6
        if f % 10 == 9 or f == frames - 1:
            print(f"{f + 1:5d}  {a:7.2f}  {100 * (volume / v_rest - 1):+12.2f} %  {guard['inverted']:13d}")
    skin = x[: asset.n_skin]
    ph.set_skin_vertices(model, data, skin)  # the deformed skin, world frame, into the MuJoCo mesh
    picture = render_layers(model, data, out / "solver_grasp.png")
    return dict(picture=picture, volume_change=volume / v_rest - 1, guard=guard, skin=skin, model=model)


def test_final(tmp_path=None):
    out = main(Path(tmp_path or "example_out"), frames=12, closing_frames=30)
    assert abs(out["volume_change"]) < 0.03, out["volume_change"]
    assert out["guard"]["nonfinite"] == 0
    model = out["model"]
    from physhand_mj.hand_mjcf import skin_geom_id
    mesh = model.geom_dataid[skin_geom_id(model)]
    assert model.mesh_vertnum[mesh] == len(out["skin"])
    assert out["picture"].stat().st_size > 20_000


if __name__ == "__main__":
    result = main(Path(sys.argv[1] if len(sys.argv) > 1 else "example_out"))
    print(result["picture"])
