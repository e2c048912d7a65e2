"""Contact cost on the embedded hand: an object pressed 3 mm into the palm, per strategy and shape.

The hand rests in its open pose (no gravity, so only contact moves the skin); a sphere (r 30 mm),
a box (30 mm cube) or a mesh (icosphere r 30 mm, 642 vertices) sits 3 mm deep in the palm. For each
strategy the frame time with the object minus the frame time without it is the contact cost;
the active triangle count and the end-of-frame penetration come with it.
Writes docs/benchmarks/contact_hand_<device>.json. Run: python benchmarks/contact_hand.py [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh

import physhand_mj as ph
from physhand_mj.bench import device_name
from physhand_mj.contact import Objects
from physhand_mj.rotations import quat_to_mat
from physhand_mj.types import GeomType, Strategy

ROOT = Path(__file__).resolve().parents[1]
DEPTH = 0.003  # m


def palm_contact_point(asset, model, data):
    """World position of the palm skin over the third metacarpal and the palm's outward normal."""
    n = np.asarray(asset.meta["palm_normal"], float)
    b = list(asset.body_names).index("thirdmc_r")
    c = asset.body_rest_pos[b]
    skin = asset.skin_vertices
    lateral = np.linalg.norm((skin - c) - np.outer((skin - c) @ n, n), axis=1)
    s = skin[lateral < 0.012][np.argmax((skin[lateral < 0.012] - c) @ n)]
    pos, quat = ph.mount_pose(model, data)
    rot = quat_to_mat(quat)
    return rot @ s + pos, rot @ n


def frame_ms(asset, pose, objects, device, frames, strategy):
    cfg = ph.Config(device=device, gravity=(0.0, 0.0, 0.0), contact=strategy)
    solver = ph.Solver(ph.make_model(asset, cfg), cfg, objects=objects)
    state = solver.make_state(*pose)
    for _ in range(3):
        out = solver.step(state)
    t = time.perf_counter()
    for _ in range(frames):
        out = solver.step(state)
    ms = (time.perf_counter() - t) / frames * 1e3
    active = int(solver.contact.active_count.numpy()[0]) if solver.contact is not None else 0
    return ms, out, active


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=30)
    args = p.parse_args()
    asset, model, data = ph.open_hand_scene("hand_only", "open")
    pose = ph.mount_pose(model, data)
    point, normal = palm_contact_point(asset, model, data)
    r = 0.03
    centre = point + normal * (r - DEPTH)
    ico = trimesh.creation.icosphere(subdivisions=3, radius=r)
    shapes = {
        "sphere": lambda o: o.add(GeomType.SPHERE, [r], pos=centre, name="sphere"),
        "box": lambda o: o.add(GeomType.BOX, [0.015] * 3, pos=point + normal * (0.015 - DEPTH), name="box"),
        "mesh": lambda o: o.add(GeomType.MESH, None, pos=centre, vertices=ico.vertices, faces=ico.faces,
                                name="icosphere", mesh_range=0.01),
    }
    base, _, _ = frame_ms(asset, pose, None, args.device, args.frames, Strategy.NONE)
    rows = []
    for shape, add in shapes.items():
        for strategy in (Strategy.VERTEX, Strategy.OPT, Strategy.MULTIRES):
            objs = Objects(args.device if args.device != "cuda" else "cuda:0", 1)
            add(objs)
            ms, out, active = frame_ms(asset, pose, objs, args.device, args.frames, strategy)
            row = dict(shape=shape, contact=strategy.name.lower(), frame_ms=round(ms, 3),
                       contact_ms=round(ms - base, 3), active_triangles=active, **{k: out[k] for k in (
                           "penetration_count", "penetration_max_um", "penetration_avg_um")})
            print(json.dumps(row), flush=True)
            rows.append(row)
    out = dict(device=device_name(args.device if args.device != "cuda" else "cuda:0"), solver_only_ms=round(base, 3),
               frames=args.frames, rows=rows)
    (ROOT / "docs" / "benchmarks").mkdir(parents=True, exist_ok=True)
    (ROOT / "docs" / "benchmarks" / f"contact_hand_{args.device.split(':')[0]}.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
