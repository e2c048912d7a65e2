"""Penetration metrics as the paper measures them (section 4.2-4.3; DESIGN "Metrics").

Every skin triangle is sampled on the order-5 barycentric lattice (21 points: vertices, edge points,
interior); a sample with phi < 0 against any object is a penetration. Per evaluation the kernel adds,
into one row of ``out``: [penetrating samples, sum of their depths |phi| (m), max depth (m)].
Triangles with phi(centroid) > circumradius for every geom are skipped: SDFs are 1-Lipschitz, so
none of their samples can penetrate.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import triangle_bound
from physhand_mj.contact.query import scene_phi
from physhand_mj.contact.sdf import geom_sdf

ORDER = 5  # 21 samples per triangle


@wp.kernel
def penetration_samples(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    gtype: wp.array(dtype=int),
    size: wp.array(dtype=wp.vec3),
    inv_pose: wp.array(dtype=wp.transform),
    radius: wp.array(dtype=float),
    mesh: wp.array(dtype=wp.uint64),
    geom_count: wp.array(dtype=int),
    geom_obj: wp.array(dtype=int),
    obj_filter: int,
    row: int,
    out: wp.array2d(dtype=float),
):
    """obj_filter >= 0 restricts the samples' SDF to the geoms of that object."""
    t = wp.tid()
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    m, r = triangle_bound(a, b, c)
    n = geom_count[0]
    if obj_filter < 0 and scene_phi(m, gtype, size, inv_pose, radius, mesh, n, -1) > r:
        return
    count = float(0.0)
    total = float(0.0)
    deepest = float(0.0)
    for i in range(6):
        for j in range(6 - i):
            u = float(i) / 5.0
            v = float(j) / 5.0
            p = a * (1.0 - u - v) + b * u + c * v
            d = float(1.0e6)
            if obj_filter < 0:
                d = scene_phi(p, gtype, size, inv_pose, radius, mesh, n, -1)
            else:
                for g in range(n):
                    if geom_obj[g] == obj_filter:
                        d = wp.min(d, geom_sdf(gtype[g], wp.transform_point(inv_pose[g], p), size[g], mesh[g]))
            if d < 0.0:
                count += 1.0
                total += -d
                deepest = wp.max(deepest, -d)
    if count > 0.0:
        wp.atomic_add(out, row, 0, count)
        wp.atomic_add(out, row, 1, total)
        wp.atomic_max(out, row, 2, deepest)


def summarize(row: np.ndarray) -> dict:
    """[count, sum depth m, max depth m] -> penetration_count, penetration_max_um, penetration_avg_um."""
    count = int(round(float(row[0])))
    return dict(penetration_count=count, penetration_max_um=float(row[2]) * 1e6,
                penetration_avg_um=float(row[1]) / count * 1e6 if count else 0.0)


@wp.kernel
def lattice_phi(faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), gtype: wp.array(dtype=int),
                size: wp.array(dtype=wp.vec3), inv_pose: wp.array(dtype=wp.transform), radius: wp.array(dtype=float),
                mesh: wp.array(dtype=wp.uint64), geom_count: wp.array(dtype=int), points: wp.array2d(dtype=wp.vec3),
                phi: wp.array2d(dtype=float)):
    """The metric's 21 samples of every triangle and their phi (m), for pictures and checks."""
    t = wp.tid()
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    k = int(0)
    for i in range(6):
        for j in range(6 - i):
            p = a * (1.0 - float(i) / 5.0 - float(j) / 5.0) + b * (float(i) / 5.0) + c * (float(j) / 5.0)
            points[t, k] = p
            phi[t, k] = scene_phi(p, gtype, size, inv_pose, radius, mesh, geom_count[0], -1)
            k += 1
