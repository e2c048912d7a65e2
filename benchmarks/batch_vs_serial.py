"""Batched worlds against serial solvers on one device: W hands (world 1 pressed by an object, the
others with theirs 10 cm away) stepped by one BatchedHands, and a serial Solver per world with its
own copy of the object; per world the largest skin/flesh position difference (um) and both
penetration measures of the batch.

    python benchmarks/batch_vs_serial.py [--device cuda] [--worlds 3] [--frames 4] [--object mesh|sphere]

On the CPU the worlds with an analytic object equal their serial runs bit for bit (tests/test_batch.py);
on CUDA float atomics make every run differ a little from the next, so the figure to read is the
size of the difference next to a serial run repeated (printed as 'serial vs serial').
"""

import argparse
import json

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--worlds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--object", choices=["mesh", "sphere"], default="mesh")
    a = ap.parse_args()
    import trimesh

    import physhand_mj as ph
    from physhand_mj.batch import BatchedHands
    from physhand_mj.contact import Objects
    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
    from physhand_mj.contact.metrics import summarize
    from physhand_mj.solver import Solver, make_model
    from physhand_mj.types import Config, GeomType

    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    ids, mount = body_ids(model, asset.body_names), mount_pose(model, data)
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = Config(device=a.device)
    if a.object == "mesh":
        ball = trimesh.creation.icosphere(subdivisions=2, radius=0.02)
        spec = dict(gtype=GeomType.MESH, name="ball", vertices=ball.vertices, faces=ball.faces, mesh_range=0.05)
        depth0 = float(np.linalg.norm(ball.vertices, axis=1).min())
    else:
        spec = dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")
        depth0 = 0.02
    W = a.worlds
    batch = BatchedHands(asset, W, cfg, *mount, objects=[spec])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = [top + [0.0, 0.1, 0.05]] * W
    where[1] = top + [0.0, 0.0, depth0 - 0.002]
    ident = np.array([[1.0, 0.0, 0.0, 0.0]] * W)

    def serial_run(w):
        o = Objects(a.device, 1)
        o.add(spec["gtype"], spec.get("size"), where[w], name="ball",
              **{k: spec[k] for k in ("vertices", "faces", "mesh_range") if k in spec})
        s = Solver(make_model(asset, cfg), cfg, objects=o)
        return s, s.make_state(*mount)

    serial = [serial_run(w) for w in range(W)] + [serial_run(1)]  # the last: world 1 again
    for _ in range(a.frames):
        batch.step(np.stack([poses[0]] * W), np.stack([poses[1]] * W), np.stack(where)[:, None], ident[:, None])
        for s, st in serial:
            s.set_body_poses(st, *poses)
            s.step(st)
    dense = summarize(batch.solver.contact.measure(batch.state, order=9, check=True))
    out = dict(device=str(a.device), worlds=W, frames=a.frames, object=a.object,
               max_diff_um={w: float(np.abs(batch.positions(w) - serial[w][1].x.numpy()).max() * 1e6) for w in range(W)},
               serial_vs_serial_um=float(np.abs(serial[1][1].x.numpy() - serial[W][1].x.numpy()).max() * 1e6),
               pressed_mm=float(np.abs(batch.skin(1) - serial[0][1].x.numpy()[: asset.n_skin]).max() * 1e3),
               order9_count=dense["penetration_count"], check_points_in_skin=dense["object_in_skin_count"])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
