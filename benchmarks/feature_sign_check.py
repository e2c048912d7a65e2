"""The feature push's inside test against the robust one, on the demo (grasp_glass, SoftHand.step).

The object's side of the contact (physhand_mj/contact/features.py) decides whether a feature point is
inside the skin by the sign of Warp's BVH query with angle-weighted pseudo normals
(``mesh_query_point_sign_normal``); the second measure decides it by the generalized winding number
(``mesh_query_point_sign_winding_number``). Both are exact on a closed, consistently wound surface
that does not cross itself. This prints, per frame, how many of the object's feature points within
2 mm of the skin the two classify differently, how many of those push_feature would act on (taken as
inside and behind their closest triangle's plane), and their signed distances (um; pseudo-normal
sign, winding sign). A ray-parity test (trimesh, 7 directions) sided with the winding number on
every point checked. Run: python benchmarks/feature_sign_check.py [--frames N]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent))


@wp.kernel
def _signs(mesh_n: wp.uint64, mesh_w: wp.uint64, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
           offset: float, p: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=float)):
    i = wp.tid()
    q = wp.mesh_query_point_sign_normal(mesh_n, p[i], 0.01)
    r = wp.mesh_query_point_sign_winding_number(mesh_w, p[i], 0.01)
    if q.result and r.result:
        c = wp.mesh_eval_position(mesh_n, q.face, q.u, q.v)
        out[i, 0] = q.sign * wp.length(p[i] - c)
        out[i, 1] = r.sign * wp.length(p[i] - wp.mesh_eval_position(mesh_w, r.face, r.u, r.v))
        a = x[faces[q.face, 0]]
        b = x[faces[q.face, 1]]
        d = x[faces[q.face, 2]]
        out[i, 2] = wp.dot(p[i] - c, -wp.normalize(wp.cross(b - a, d - a))) + offset  # push_feature's need


def _local_sign(c, state, pts):
    """Per object point (len(pts)): the local winding number's side (+1 outside, -1 inside; 0 for points
    not in the frame's feature list or without a patch) of the contact's last frame, with the skin now."""
    from physhand_mj.contact.closest import FOUR_PI

    out = np.zeros(len(pts), dtype=int)
    if not getattr(c.config, "feature_winding", False) or c.feat is None:
        return out
    n = int(c.feat_count.numpy()[0])
    feat = c.feat.numpy()[:n]
    start, length = c.patch_start.numpy()[:n], c.patch_len.numpy()[:n]
    far, pool = c.far_angle.numpy()[:n], c.patch_pool.numpy()
    x = state.x.numpy().astype(float)
    faces = c.model.skin_faces.numpy()
    pose = c.objects._host["pose"][pts.geom_host].astype(float)
    from physhand_mj.rotations import quat_to_mat

    rot = quat_to_mat(np.concatenate([pose[:, 6:], pose[:, 3:6]], axis=1)).reshape(-1, 3, 3)
    world = np.einsum("kij,kj->ki", rot, pts.pts_host) + pose[:, :3]
    for k, i in enumerate(feat):
        if length[k] < 0:
            continue
        tri = x[faces[pool[start[k]: start[k] + length[k]]]] - world[i]
        a, b, d = tri[:, 0], tri[:, 1], tri[:, 2]
        la, lb, ld = (np.linalg.norm(v, axis=1) for v in (a, b, d))
        num = np.einsum("ij,ij->i", a, np.cross(b, d))
        den = la * lb * ld + np.einsum("ij,ij->i", a, b) * ld + np.einsum("ij,ij->i", b, d) * la + \
            np.einsum("ij,ij->i", d, a) * lb
        out[i] = -1 if (2 * np.arctan2(num, den)).sum() + far[k] > 0.5 * FOUR_PI else 1
    return out


def main():
    from activity_frame import _glass_case

    from physhand_mj.rotations import quat_to_mat

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10, help="5 ms frames of the demo (count)")
    a = ap.parse_args()
    frame, solver, state, hand = _glass_case("cpu", "MULTIRES")
    c = solver.contact
    pts = c.points
    for f in range(a.frames):
        frame()
        pose = c.objects._host["pose"][pts.geom_host].astype(float)
        rot = quat_to_mat(np.concatenate([pose[:, 6:], pose[:, 3:6]], axis=1))
        world = np.einsum("kij,kj->ki", rot, pts.pts_host) + pose[:, :3]
        feat = world[pts.kind_host != 0].astype(np.float32)
        vn, vw = c.volume(state, winding=False), c.volume(state, winding=True)
        vn.mesh.refit()
        for op in vw.ops():
            op()
        out = wp.zeros((len(feat), 3), dtype=float, device="cpu")
        wp.launch(_signs, len(feat), [vn.mesh.id, vw.mesh.id, solver.model.skin_faces, state.x,
                                      float(solver.config.feature_offset),
                                      wp.array(feat, dtype=wp.vec3, device="cpu")], [out], device="cpu")
        o = out.numpy()
        near = (np.abs(o[:, 1]) > 0) & (np.abs(o[:, 1]) < 2e-3)
        bad = near & (np.sign(o[:, 0]) != np.sign(o[:, 1]))
        push = bad & (o[:, 0] < 0) & (o[:, 2] > 0)
        # the local winding number the contact decides with (Config.tuning.feature_winding): the patch's solid
        # angles now plus the far angle from the frame's start, against the full winding number
        local = _local_sign(c, state, pts)
        listed = np.flatnonzero(pts.kind_host != 0)
        lw = local[listed]
        have = near & (lw != 0)
        lbad = have & (lw != np.sign(o[:, 1]))
        print(f"frame {f}: {int(near.sum())} feature points within 2 mm of the skin, {int(bad.sum())} classified "
              f"differently, {int(push.sum())} of them outside but taken as inside with the point behind their "
              f"closest triangle's plane (push_feature would push the skin); (pseudo-normal, winding) um: "
              f"{np.round(o[bad][:4, :2] * 1e6, 1).tolist()}; local winding number: {int(have.sum())} of them "
              f"listed, {int(lbad.sum())} classified differently from the full one", flush=True)


if __name__ == "__main__":
    main()
