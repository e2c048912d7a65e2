"""Pictures of sharp cases before and after: the paper's contact (multires, Eq. 9 only) against the
default (multires + the object's features + side-aware exits), after the same frames.

Each panel: the deformed skin (translucent), the object, red dots at object surface points inside
the skin (the second measure) and orange dots at order-9 skin samples inside the object (size ~ depth).
Writes docs/images/hard_contact_before_after.png (one row per case, columns: paper, default) and
prints both measures per panel.

Run: python benchmarks/hard_contact_figure.py [--frames 14] [--out docs/images/hard_contact_before_after.png]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402  (picks the GL backend before mujoco loads)
import mujoco  # noqa: E402
import trimesh  # noqa: E402

from physhand_mj.bench.cases import press_case, run_case, site_point  # noqa: E402
from physhand_mj.contact.metrics import summarize  # noqa: E402
from physhand_mj.render import look_at_camera, make_renderer, mesh_scene_spec, write_png  # noqa: E402
from physhand_mj.rotations import quat_to_mat  # noqa: E402
from physhand_mj.types import GeomType  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CASES = (("knife", "fingertip", -0.004), ("mesh_cone", "palm", 0.002), ("plate", "fingertip", -0.004))
METHODS = (("paper (multires, Eq. 9)", dict(feature_contact=False, side_aware=False, skin_tether=0.0)),
           ("default (+ features, side-aware)", {}))


def object_mesh(case, pos, quat):
    """The case's object as a world-frame triangle mesh."""
    if case.gtype == GeomType.MESH:
        m = trimesh.Trimesh(case.vertices, case.faces, process=False)
    elif case.gtype == GeomType.BOX:
        m = trimesh.creation.box(extents=2 * np.asarray(case.size))
    elif case.gtype == GeomType.CAPSULE:
        m = trimesh.creation.capsule(height=2 * case.size[1], radius=case.size[0])
    elif case.gtype == GeomType.SPHERE:
        m = trimesh.creation.icosphere(4, radius=case.size[0])
    else:  # the analytic cone: apex at the origin, opening toward -z
        r, h = case.size[0], case.size[1]
        m = trimesh.creation.cone(radius=r, height=h)
        m.apply_translation([0, 0, -h])
    v = np.asarray(m.vertices) @ quat_to_mat(np.asarray(quat)).T + pos
    return v, np.asarray(m.faces)


def inside_points(res, order=9):
    """(object points inside the skin, their depths), (order-``order`` skin samples inside the object, depths)."""
    c, state = res["solver"].contact, res["state"]
    return c.object_points_inside(state), c.penetrating_samples(state, order)


def panel(res, case, asset, width, height):
    skin = res["skin"]
    ov, of = object_mesh(case, res["object_pos"], res["object_quat"])
    spec = mesh_scene_spec([("skin", skin, asset.skin_faces, [0.93, 0.75, 0.65, 0.3]),
                            ("object", ov, of, [0.35, 0.45, 0.6, 1.0])])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    (obj, od), (smp, sd) = inside_points(res)
    p0, n = site_point(asset, case.site)
    r = make_renderer(model, width, height)
    try:
        side = np.cross(n, [0.0, 0.0, 1.0])
        side = side / (np.linalg.norm(side) + 1e-12)
        view = -(0.8 * side + 0.6 * n)  # camera forward: across the contact, a little from outside
        az = np.degrees(np.arctan2(view[1], view[0]))
        el = np.degrees(np.arcsin(np.clip(view[2] / np.linalg.norm(view), -1, 1)))
        r.update_scene(data, camera=look_at_camera(p0, 0.04, az, el))
        scn = r.scene
        for pts, dep, rgba in ((obj, od, [0.9, 0.05, 0.05, 1]), (smp, sd, [1.0, 0.55, 0.0, 1])):
            for p, d in zip(pts[:800], dep[:800]):
                if scn.ngeom >= scn.maxgeom:
                    break
                g = scn.geoms[scn.ngeom]
                size = 0.0004 + min(float(d), 0.002) * 0.4
                mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.array([size, 0, 0]), p, np.eye(3).ravel(),
                                    np.asarray(rgba, np.float32))
                scn.ngeom += 1
        return r.render()
    finally:
        r.close()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=14)
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--out", default=str(ROOT / "docs" / "images" / "hard_contact_before_after.png"))
    a = ap.parse_args()
    asset = ph.load_asset()
    rows = []
    for kind, site, start in CASES:
        case = press_case(kind, site=site, depth=0.004, start=start)
        row = []
        for label, over in METHODS:
            res = run_case(case, ph.Config(device="cpu", **over), frames=a.frames, asset=asset)
            m9 = summarize(res["solver"].contact.measure(res["state"], order=9))
            print(f"{kind} {site} {'deep' if start < 0 else 'press'} | {label}: order-9 skin samples "
                  f"{m9['penetration_count']} / {m9['penetration_max_um']:.1f} um, object points in skin "
                  f"{m9['object_in_skin_count']} / {m9['object_in_skin_max_um']:.1f} um", flush=True)
            row.append(panel(res, case, asset, a.width, a.height))
        rows.append(np.concatenate(row, axis=1))
    out = write_png(np.concatenate(rows, axis=0), a.out)
    print(out)


if __name__ == "__main__":
    main()
