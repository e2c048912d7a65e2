"""The decision points' mesh query: a BVH walk per lattice sample against the faces near the triangle
(sdf_mesh.mesh_near_faces, then sdf_mesh.sdf_mesh_near per sample; query.py's multires on a pseudo-normal mesh).

Skin-sized triangles (corners ~1.2 mm about their centre) about points 2 mm inside to 4 mm outside
random surface points of each mesh; each triangle is sampled on the order-5 lattice twice (multires's
two rounds: 42 samples), once with Warp's BVH query per sample (``geom_sdf``, no grid) and once over
the triangle's near faces. Reports ms per launch of N triangles each way (median of ``--repeats``
interleaved launches, compilation excluded), the share of triangles whose near faces fit the
capacity (sdf_mesh.MESH_NEAR_CAP; the rest take the BVH), the median / 90th percentile / largest count of
near faces, whether every sample's phi equals the BVH query's (bit for bit but at exact ties), and
whether ``Objects.add`` marks the mesh for the contact's decision points to take the near faces
(objects.near_faces_pay; unmarked meshes keep the BVH walk per sample).

    python benchmarks/mesh_near_faces.py [--device cpu|cuda] [--triangles 20000] [--repeats 5]
                                         [--out docs/benchmarks/mesh_near_faces_<device>.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh
import warp as wp

import physhand_mj as ph
from physhand_mj.bench import device_name
from physhand_mj.contact import Objects
from physhand_mj.contact.broadphase import triangle_bound
from physhand_mj.contact.sdf import geom_sdf
from physhand_mj.contact.sdf_mesh import (MESH_NEAR_CAP, MESH_SIGN_PSEUDO_NEAR, mesh_near_dist, mesh_near_faces,
                                          mesh_near_first, mesh_near_ids, sdf_mesh_near)
from physhand_mj.types import GeomType

ROOT = Path(__file__).resolve().parents[1]
ORDER = 5
SAMPLES = (ORDER + 1) * (ORDER + 2) // 2


@wp.kernel
def _lattice(size: wp.vec3, mesh: wp.uint64, tri: wp.array(dtype=wp.vec3), near_path: int,
             phi: wp.array2d(dtype=float), n_near: wp.array(dtype=int)):
    t = wp.tid()
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    ids = mesh_near_ids()
    dist = mesh_near_dist()
    m = wp.vec3(0.0)
    n = int(-1)
    if near_path != 0:
        m, r = triangle_bound(a, b, c)
        ids, dist, n = mesh_near_faces(mesh, m, r, size[0])
    first = mesh_near_first(dist, n)
    n_near[t] = n
    for rnd in range(2):
        k = int(0)
        for i in range(ORDER + 1):
            for j in range(ORDER + 1 - i):
                u = float(i) / float(ORDER)
                v = float(j) / float(ORDER)
                p = a * (1.0 - u - v) + b * u + c * v
                if n >= 0:
                    phi[t, k] = sdf_mesh_near(p, size, mesh, ids, dist, n, first, m)
                else:
                    phi[t, k] = geom_sdf(int(GeomType.MESH), p, size, wp.vec2ul(mesh, wp.uint64(0)))
                k += 1


def triangles(mesh: trimesh.Trimesh, n: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts, fi = trimesh.sample.sample_surface(mesh, n, seed=seed)
    centres = pts + mesh.face_normals[fi] * rng.uniform(-2e-3, 4e-3, (n, 1))
    return (centres[:, None, :] + rng.normal(size=(n, 3, 3)) * 1.2e-3).astype(np.float32)


def run_mesh(name: str, mesh: trimesh.Trimesh, device: str, n: int, repeats: int) -> dict:
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name=name, mesh_range=1.0)
    size = wp.vec3(*objs._host["size"][0])
    mid = wp.uint64(int(objs._host["mesh"][0][0]))
    tri = wp.array(triangles(mesh, n).reshape(-1, 3), dtype=wp.vec3, device=device)
    out = {k: (wp.zeros((n, SAMPLES), dtype=float, device=device), wp.zeros(n, dtype=int, device=device)) for k in (0, 1)}
    ms = {0: [], 1: []}
    for rep in range(repeats + 1):  # the first round compiles and warms up
        for k in (0, 1):
            wp.synchronize_device(device)
            t0 = time.perf_counter()
            wp.launch(_lattice, n, [size, mid, tri, k], [*out[k]], device=device)
            wp.synchronize_device(device)
            if rep:
                ms[k].append((time.perf_counter() - t0) * 1e3)
    faces = out[1][1].numpy()
    used = faces >= 0
    bvh, near = out[0][0].numpy(), out[1][0].numpy()
    marked = int(objs._host["size"][0][1]) == MESH_SIGN_PSEUDO_NEAR  # does the contact take the near faces?
    return dict(mesh=name, faces=int(len(mesh.faces)), triangles=n, samples_per_triangle=2 * SAMPLES,
                contact_uses_near_faces=marked,
                bvh_ms=round(float(np.median(ms[0])), 3), near_faces_ms=round(float(np.median(ms[1])), 3),
                speedup=round(float(np.median(ms[0]) / np.median(ms[1])), 2),
                near_share=round(float(used.mean()), 4),
                near_faces_median=float(np.median(faces[used])) if used.any() else None,
                near_faces_p90=float(np.percentile(faces[used], 90)) if used.any() else None,
                near_faces_max=int(faces[used].max()) if used.any() else None,
                bit_for_bit=bool(np.array_equal(bvh, near)), samples_differing=int((bvh != near).sum()),
                samples_compared=int(bvh.size), max_abs_diff_m=float(np.abs(bvh - near).max()))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--triangles", type=int, default=20000, help="skin-sized triangles per mesh (count)")
    p.add_argument("--repeats", type=int, default=5, help="timed launches each way (count)")
    p.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/mesh_near_faces_<device>.json)")
    a = p.parse_args()
    wp.init()
    meshes = {"hoi_bowl (1,408 faces, edges ~9 mm)": trimesh.load(ph.scene_path("hoi_bowl").parent / "assets" / "bowl.stl"),
              "icosphere(3), r 3 cm": trimesh.creation.icosphere(subdivisions=3, radius=0.03),
              "icosphere(5), r 3 cm": trimesh.creation.icosphere(subdivisions=5, radius=0.03),
              "box 6 x 4 x 2 cm": trimesh.creation.box(extents=[0.06, 0.04, 0.02])}
    rows = []
    for name, mesh in meshes.items():
        rows.append(run_mesh(name, mesh, a.device, a.triangles, a.repeats))
        print(json.dumps(rows[-1]), flush=True)
    out = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"mesh_near_faces_{a.device.split(':')[0]}.json"
    out.write_text(json.dumps(dict(device=device_name(a.device), capacity=MESH_NEAR_CAP, order=ORDER, rows=rows),
                              indent=1) + "\n")
    print(json.dumps(dict(out=str(out.relative_to(ROOT)) if out.is_relative_to(ROOT) else str(out))))


if __name__ == "__main__":
    main()
