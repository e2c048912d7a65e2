"""Which skin triangles can touch an object this substep: so contact cost follows contact area.

A triangle with centroid c and circumradius r (largest centroid-vertex distance) cannot reach a geom
whose bounding sphere (centre o, radius R) satisfies |c - o| - R - r > margin: every SDF is
1-Lipschitz, so no point of the triangle is closer than that. ``margin`` (m) covers the motion
within one contact pass. Surviving triangles are compacted into ``active`` with an atomic counter.
"""

import warp as wp


@wp.kernel
def find_active(
    faces: wp.array2d(dtype=int),
    x: wp.array(dtype=wp.vec3),
    pose: wp.array(dtype=wp.transform),
    radius: wp.array(dtype=float),
    geom_count: wp.array(dtype=int),
    margin: float,
    active: wp.array(dtype=int),
    active_count: wp.array(dtype=int),
):
    t = wp.tid()
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    m = (a + b + c) * (1.0 / 3.0)
    r = wp.max(wp.length(a - m), wp.max(wp.length(b - m), wp.length(c - m)))
    for g in range(geom_count[0]):
        if wp.length(m - wp.transform_get_translation(pose[g])) - radius[g] - r <= margin:
            slot = wp.atomic_add(active_count, 0, 1)
            active[slot] = t
            return


@wp.kernel
def reset_counter(counter: wp.array(dtype=int)):
    counter[0] = 0
