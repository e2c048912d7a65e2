"""Which skin triangles can touch an object this substep: so contact cost follows contact area.

A triangle with centroid c and circumradius r (largest centroid-vertex distance) cannot reach a
geom if phi(c) - r > margin: every SDF is 1-Lipschitz, so no point of the triangle is closer. The
cheap bound |c - o| - R (bounding sphere, centre o, radius R) is tried first, the exact phi(c)
(one query) only for triangles inside it. ``margin`` (m) covers the motion within one contact
stage. Surviving triangles are compacted into ``active`` with an atomic counter.
"""

import warp as wp

from physhand_mj.contact.sdf import geom_sdf


@wp.func
def triangle_bound(a: wp.vec3, b: wp.vec3, c: wp.vec3):
    """(centroid, circumradius about it): every point of the triangle lies within r of m."""
    m = (a + b + c) * (1.0 / 3.0)
    return m, wp.max(wp.length(a - m), wp.max(wp.length(b - m), wp.length(c - m)))


@wp.kernel
def find_active(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    gtype: wp.array(dtype=int),
    size: wp.array(dtype=wp.vec3),
    pose: wp.array(dtype=wp.transform),
    radius: wp.array(dtype=float),
    mesh: wp.array(dtype=wp.uint64),
    geom_count: wp.array(dtype=int),
    margin: float,
    active: wp.array(dtype=int),
    active_mask: wp.array(dtype=int),
    active_count: wp.array(dtype=int),
):
    """Append each triangle that can reach a geom, with the bit mask of those geoms (bits 0-30;
    later geoms are always queried), so decision points query only the geoms near their triangle."""
    t = wp.tid()
    m, r = triangle_bound(x[faces[t, 0]], x[faces[t, 1]], x[faces[t, 2]])
    mask = int(0)
    for g in range(geom_count[0]):
        tf = pose[g]
        if wp.length(m - wp.transform_get_translation(tf)) - radius[g] - r <= margin:
            if geom_sdf(gtype[g], wp.transform_point(wp.transform_inverse(tf), m), size[g], mesh[g]) - r <= margin:
                if g < 31:
                    mask = mask | (1 << g)
                else:
                    mask = mask | (1 << 30)  # any bit: the triangle is active; geoms >= 31 are always tried
    if mask != 0:
        slot = wp.atomic_add(active_count, 0, 1)
        active[slot] = t
        active_mask[slot] = mask


@wp.kernel
def keep_near(
    active_in: wp.array(dtype=int),
    mask_in: wp.array(dtype=int),
    count_in: wp.array(dtype=int),
    decision: wp.array(dtype=wp.vec4),
    threshold: float,
    active_out: wp.array(dtype=int),
    mask_out: wp.array(dtype=int),
    count_out: wp.array(dtype=int),
):
    """Next contact pass: only triangles whose decision point came within ``threshold`` (m) of an
    object (phi(x*) = decision[t].w) can still need a correction after their neighbours moved."""
    k = wp.tid()
    if k >= count_in[0]:
        return
    t = active_in[k]
    if decision[t][3] < threshold:
        slot = wp.atomic_add(count_out, 0, 1)
        active_out[slot] = t
        mask_out[slot] = mask_in[k]
