"""What the skin's winding-number BVH costs per frame against its leaf size (Warp's ``bvh_leaf_size``).

A batch of W hands refits one ``wp.Mesh`` with ``support_winding_number`` over every world's skin once
a frame (contact/inside.SkinVolume: the listed feature points' w_0, winding.py, and the object-side
measure). Its refit computes each BVH node's dipole data bottom up; a larger leaf holds more
triangles, so fewer nodes, while a query that opens a leaf sums more triangles exactly. For each leaf
size: the refit (ms), ``winding_number`` at feature-like points (``--points`` per world, 2 mm off the
skin, outside and inside), and whether the rounded answers equal leaf size 4's (Warp's default).

    python benchmarks/winding_leaf.py [--device cuda] [--worlds 1024] [--leaves 4,8,16,32] [--points 20]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import warp as wp

import physhand_mj as ph
from physhand_mj.contact.inside import winding_number

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _wn(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), accuracy: float, out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = winding_number(mesh, pts[i], accuracy)


def _timed(fn, device, reps: int) -> float:
    fn()
    wp.synchronize_device(device)
    t = time.perf_counter()
    for _ in range(reps):
        fn()
    wp.synchronize_device(device)
    return (time.perf_counter() - t) / reps * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--worlds", type=int, default=16, help="skins in the one mesh (1 m apart)")
    ap.add_argument("--leaves", default="4,8,16,32", help="bvh_leaf_size values (triangles a leaf)")
    ap.add_argument("--points", type=int, default=20, help="query points per world")
    ap.add_argument("--reps", type=int, default=10, help="timed repetitions")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/winding_leaf_<device>.json)")
    a = ap.parse_args()
    wp.init()
    d = wp.get_device(a.device)
    asset = ph.load_asset()
    x0 = asset.positions[: asset.n_skin].astype(np.float32)
    f0 = asset.skin_faces.astype(np.int32)
    w, n = a.worlds, len(x0)
    offs = np.zeros((w, 3), np.float32)
    offs[:, 0] = np.arange(w)  # 1 m apart, as the batch queries its worlds
    x = (x0[None] + offs[:, None]).reshape(-1, 3)
    faces = (f0[None] + (np.arange(w) * n)[:, None, None]).reshape(-1)
    rng = np.random.default_rng(0)
    # points 2 mm off the skin along the vertex normals, outside and inside (the features' range)
    import trimesh

    tm = trimesh.Trimesh(x0, f0, process=False)
    pick = rng.integers(0, n, size=(w, a.points))
    sign = np.where(rng.random((w, a.points)) < 0.5, 1.0, -1.0)[..., None]
    pts = (x0[pick] + sign * 2e-3 * tm.vertex_normals[pick] + offs[:, None]).reshape(-1, 3).astype(np.float32)
    xs = wp.array(x, dtype=wp.vec3, device=d)
    idx = wp.array(faces, dtype=wp.int32, device=d)
    pw = wp.array(pts, dtype=wp.vec3, device=d)
    out = wp.zeros(len(pts), dtype=float, device=d)
    rows, ref = [], None
    for leaf in [int(s) for s in a.leaves.split(",")]:
        mesh = wp.Mesh(points=xs, indices=idx, support_winding_number=True, bvh_constructor="sah",
                       bvh_leaf_size=leaf)
        refit = _timed(mesh.refit, d, a.reps)
        q1 = _timed(lambda: wp.launch(_wn, len(pts), inputs=[mesh.id, pw, 1.0], outputs=[out], device=d), d, a.reps)
        wn = np.rint(out.numpy())
        q2 = _timed(lambda: wp.launch(_wn, len(pts), inputs=[mesh.id, pw, 2.0], outputs=[out], device=d), d, a.reps)
        ref = wn if ref is None else ref
        row = dict(leaf=leaf, refit_ms=round(refit, 3), query_beta1_ms=round(q1, 3), query_beta2_ms=round(q2, 3),
                   rounded_equal_to_first=bool(np.array_equal(wn, ref)), inside=int((wn > 0.5).sum()))
        print(json.dumps(row), flush=True)
        rows.append(row)
        mesh = None  # (freed before the next leaf size is built)
    res = dict(device=f"{d} ({d.name})" if d.is_cuda else str(d), worlds=w, triangles=int(len(faces) // 3),
               points=len(pts), rows=rows, command="python benchmarks/winding_leaf.py " + " ".join(
                   f"--{k.replace('_', '-')} {v}" for k, v in vars(a).items() if k != "out"))
    path = Path(a.out or f"docs/benchmarks/winding_leaf_{'cuda' if d.is_cuda else 'cpu'}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
