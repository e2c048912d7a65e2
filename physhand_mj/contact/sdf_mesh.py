"""Signed distances to mesh geoms, as ``wp.func`` (paper section 3.3; :mod:`physhand_mj.contact.sdf`
dispatches to them by geom type).

A mesh geom's ``size`` and id (contact/objects.py sets them):
- mesh: ``size[0]`` is the query range (m; beyond it phi = FAR), ``size[1]`` the sign method
  (:data:`MESH_SIGN_PSEUDO`, :data:`MESH_SIGN_PSEUDO_NEAR` or :data:`MESH_SIGN_WINDING`, chosen by
  ``Objects.add``; the first two sign alike, the second marks a mesh whose faces are few near a
  skin triangle, whose decision points then search them: :func:`mesh_near_faces`). The distance
  is exact (a BVH closest-point query). The sign of a closed, consistently wound mesh is the
  angle-weighted pseudo normal (Baerentzen and Aanaes 2005) of the closest point's own feature
  (face, edge or vertex: the faces sharing it, found by index), which is exact at edges and tips;
  the walks that find those faces run once per mesh, into a table (:func:`pseudo_normal_table`);
  Warp's ``mesh_query_point_sign_normal`` instead gathers every face within 1e-3 average edge lengths of the closest distance and gets knife edges wrong
  (docs/contact.md). An open or overlapping mesh takes the generalised winding number (> 1/2 is
  inside: holes are closed over), 2-4x dearer. Cost O(log F) per query against O(1) for the
  analytic shapes. A mesh geom's id is a ``wp.vec2ul``: (wp.Mesh id, grid id or 0). The grid
  (``objects.mesh_grid``, a ``wp.Volume`` of the exact signed distance at its nodes) answers only
  points provably farther than :data:`GRID_BAND` outside the mesh in :func:`geom_sdf` (values only),
  with a lower bound of their distance (the nearest node's distance minus the way to it: a
  distance is 1-Lipschitz); every point closer than that or inside, and every gradient query
  (:func:`geom_sdf_grad`), gets the exact BVH query. The broadphase
  (which re-asks exactly where a bound keeps a triangle) and the metrics use it; the decision
  points and Eq. 9 query ``Objects.mesh_exact`` (no grid), so the contact's results are those of
  the exact distance (docs/contact.md). A grid that interpolated near the surface would cap the accuracy at its cell size,
  while the paper's point is sub-micrometre contact.
"""

import warp as wp

from physhand_mj.contact.closest import closest_on_triangle

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

FAR = wp.constant(1.0e6)  # phi reported where a mesh query finds nothing within its range (m)
MESH_SIGN_PSEUDO = wp.constant(0)  # size[1] of a mesh geom: sign by the closest feature's pseudo normal
MESH_SIGN_WINDING = wp.constant(1)  # ... by the generalised winding number (open / overlapping meshes)
MESH_SIGN_PSEUDO_NEAR = wp.constant(2)  # ... by the pseudo normal, and few faces near a skin triangle (mesh_near_faces)
WINDING_ACCURACY = wp.constant(2.0)  # Barill et al.'s beta: far clusters by their dipole expansion
BARY_EPS = wp.constant(1.0e-5)  # barycentric coordinate below which the closest point is on an edge
GRID_BAND = wp.constant(1.0e-3)  # m: a mesh grid answers only points provably farther than this outside
GRID_PAD = wp.constant(1.5e-2)  # m: a mesh grid covers the mesh's box grown by this (the frame margin, 1 cm, and more)
GRID_OFF = wp.constant(-1.0e30)  # a mesh grid's background: what a lookup off its nodes returns


@wp.func
def grid_node(grid: wp.uint64, p: wp.vec3):
    """(dc, s): the exact phi at the grid node nearest p, p's distance to it: dc -+ s bound phi(p)."""
    uvw = wp.volume_world_to_index(grid, p)
    i = int(wp.floor(uvw[0] + 0.5))
    j = int(wp.floor(uvw[1] + 0.5))
    k = int(wp.floor(uvw[2] + 0.5))
    dc = wp.volume_lookup_f(grid, i, j, k)
    if dc < 0.5 * GRID_OFF:
        return dc, 0.0
    c = wp.volume_index_to_world(grid, wp.vec3(float(i), float(j), float(k)))
    return dc, wp.length(p - c)


@wp.func
def grid_lower(dc: float, s: float):
    """A lower bound (m) of p's distance outside the mesh from :func:`grid_node`'s (dc, s) at p (a node
    outside with distance d has no surface within d); -1 where that node is inside or on the surface.
    Off the grid (dc = GRID_OFF) p lies more than GRID_PAD outside the mesh's box, so GRID_PAD bounds
    its distance (the skin's far side around a large object, which would otherwise walk the BVH)."""
    if dc < 0.5 * GRID_OFF:
        return GRID_PAD
    if dc <= 0.0:
        return -1.0
    return dc - s


@wp.func
def _corner_angle(a: wp.vec3, b: wp.vec3):
    """Angle (rad) between edge vectors ``a`` and ``b`` (atan2: accurate at needle-sharp corners)."""
    return wp.atan2(wp.length(wp.cross(a, b)), wp.dot(a, b))


@wp.func
def _has(i0: int, i1: int, i2: int, k: int):
    return i0 == k or i1 == k or i2 == k


@wp.func
def mesh_feature(u: float, v: float):
    """The closest point's feature on its face, from its barycentrics (u, v, 1-u-v): -1 inside the
    face; 0-2 the vertex of that slot (two coordinates ~0); 3 + j the edge opposite slot j (one ~0)."""
    w = 1.0 - u - v
    on_u = u <= BARY_EPS
    on_v = v <= BARY_EPS
    on_w = w <= BARY_EPS
    n_on = int(on_u) + int(on_v) + int(on_w)
    if n_on == 0:
        return -1
    if n_on >= 2:
        if not on_v:
            return 1
        elif not on_w:
            return 2
        return 0
    if on_u:
        return 3
    if on_v:
        return 4
    return 5


@wp.func
def mesh_feature_normal(mesh: wp.uint64, face: int, feature: int):
    """Angle-weighted pseudo normal (not normalised) of ``feature`` (:func:`mesh_feature`, >= 0) of
    ``face``: on an edge, the sum of its two faces' normals; at a vertex, the sum of its faces'
    normals weighted by their corner angles there. The faces sharing the feature come from an AABB
    query over it, matched by vertex index: the mesh's duplicate vertices must be merged (Objects.add
    does). What :func:`mesh_pseudo_normal` reads from the mesh's table where it has one."""
    ka = int(0)
    kb = int(-1)
    if feature < 3:
        ka = feature
    elif feature == 3:
        ka = 1
        kb = 2
    elif feature == 4:
        kb = 2
    else:
        kb = 1
    f3 = face * 3
    a = wp.mesh_get_index(mesh, f3 + ka)
    pa = wp.mesh_get_point(mesh, f3 + ka)
    b = int(-1)
    lo = pa
    hi = pa
    if kb >= 0:
        b = wp.mesh_get_index(mesh, f3 + kb)
        pb = wp.mesh_get_point(mesh, f3 + kb)
        lo = wp.min(pa, pb)
        hi = wp.max(pa, pb)
    acc = wp.vec3(0.0)
    query = wp.mesh_query_aabb(mesh, lo, hi)  # inclusive: every face holding the feature overlaps it
    g = int(0)
    while wp.mesh_query_aabb_next(query, g):
        i0 = wp.mesh_get_index(mesh, 3 * g)
        i1 = wp.mesh_get_index(mesh, 3 * g + 1)
        i2 = wp.mesh_get_index(mesh, 3 * g + 2)
        if _has(i0, i1, i2, a) and (b < 0 or _has(i0, i1, i2, b)):
            x0 = wp.mesh_get_point(mesh, 3 * g)
            x1 = wp.mesh_get_point(mesh, 3 * g + 1)
            x2 = wp.mesh_get_point(mesh, 3 * g + 2)
            c = wp.cross(x1 - x0, x2 - x0)
            scale = wp.length_sq(x1 - x0) + wp.length_sq(x2 - x0) + wp.length_sq(x2 - x1)
            if wp.length(c) > 1.0e-6 * scale:  # slivers have no reliable normal (Warp skips them too)
                weight = 1.0
                if b < 0:
                    if i0 == a:
                        weight = _corner_angle(x1 - x0, x2 - x0)
                    elif i1 == a:
                        weight = _corner_angle(x2 - x1, x0 - x1)
                    else:
                        weight = _corner_angle(x0 - x2, x1 - x2)
                acc += wp.normalize(c) * weight
    return acc


FEATURES_PER_FACE = wp.constant(7)  # a face's entries in a mesh's pseudo-normal table: 3 vertices, 3 edges, itself


@wp.func
def mesh_pseudo_normal(mesh: wp.uint64, face: int, u: float, v: float):
    """Angle-weighted pseudo normal (not normalised) at the point with barycentrics (u, v, 1-u-v)
    of ``face``: the face normal inside the face, else its feature's (:func:`mesh_feature_normal`).
    The sign of dot(p - c, N) at p's closest point c is then exact for a closed, consistently wound
    mesh (Baerentzen and Aanaes 2005). A mesh made by ``objects.prepare_mesh`` keeps every face's six
    feature normals and its own in its ``velocities`` array (:func:`pseudo_normal_table`: the same
    functions' values, so the same bits), read here instead of an AABB walk per query; a mesh whose
    velocities are anything else (not 7 per face) walks."""
    feature = mesh_feature(u, v)
    held = wp.mesh_get(mesh)
    table = held.velocities
    if table.shape[0] == FEATURES_PER_FACE * (held.indices.shape[0] // 3):
        return table[face * FEATURES_PER_FACE + wp.where(feature < 0, FEATURES_PER_FACE - 1, feature)]
    if feature < 0:
        return wp.mesh_eval_face_normal(mesh, face)
    return mesh_feature_normal(mesh, face, feature)


@wp.kernel
def pseudo_normal_table(mesh: wp.uint64, out: wp.array(dtype=wp.vec3)):
    """Every face's six feature normals (:func:`mesh_feature_normal`) and its face normal
    (``wp.mesh_eval_face_normal``) into ``out`` (7 F long), the table :func:`mesh_pseudo_normal`
    reads from a mesh's ``velocities``."""
    k = wp.tid()
    face = k // FEATURES_PER_FACE
    feature = k % FEATURES_PER_FACE
    if feature == FEATURES_PER_FACE - 1:
        out[k] = wp.mesh_eval_face_normal(mesh, face)
    else:
        out[k] = mesh_feature_normal(mesh, face, feature)


@wp.func
def mesh_signed(p: wp.vec3, mesh: wp.uint64, face: int, u: float, v: float, winding: bool, sign: float):
    """(phi, unit gradient) at ``p`` from its closest point on ``mesh`` (``face``, barycentrics u, v):
    the distance signed by the closest feature's pseudo normal (or by ``sign``, the winding number's,
    when ``winding``); the gradient sign (p - c) / |p - c|, on the surface (closer than 1e-6 of the
    coordinates' size) the unit pseudo normal (winding sign: the face normal)."""
    normal = wp.vec3(0.0, 0.0, 1.0)
    if winding:
        normal = wp.mesh_eval_face_normal(mesh, face)
    else:
        normal = mesh_pseudo_normal(mesh, face, u, v)
    c = wp.mesh_eval_position(mesh, face, u, v)
    d = p - c
    if not winding and wp.dot(d, normal) < 0.0:
        sign = -1.0
    n = wp.length(d)
    # within float32 rounding of the coordinates p - c has no reliable direction: the normal then
    if n > 1.0e-9 + 1.0e-6 * wp.max(wp.abs(c)):
        return sign * n, d * (sign / n)
    if wp.length(normal) > 0.0:
        normal = wp.normalize(normal)
    else:
        normal = wp.mesh_eval_face_normal(mesh, face)
    return sign * n, normal


@wp.func
def sdf_mesh_grad(p: wp.vec3, size: wp.vec3, ids: wp.vec2ul):
    """(phi, unit gradient) of a mesh (``ids``: its wp.Mesh id, its grid's id or 0; the gradient
    path never uses the grid): exact distance to the closest point c, signed by the method in
    ``size[1]`` (:func:`mesh_signed`)."""
    mesh = ids[0]
    if size[1] > 0.5 and size[1] < 1.5:  # MESH_SIGN_WINDING
        hit = wp.mesh_query_point_sign_winding_number(mesh, p, size[0], WINDING_ACCURACY, 0.5)
        if not hit.result:
            return FAR, wp.vec3(0.0, 0.0, 1.0)
        return mesh_signed(p, mesh, hit.face, hit.u, hit.v, True, hit.sign)
    hit = wp.mesh_query_point_no_sign(mesh, p, size[0])
    if not hit.result:
        return FAR, wp.vec3(0.0, 0.0, 1.0)
    return mesh_signed(p, mesh, hit.face, hit.u, hit.v, False, 1.0)


# A mesh's faces near one skin triangle (the decision points' lattice, query.py): every point p of
# the triangle (within r of its centroid m) has its closest face within d(m) + 2 r of m (d(p) <=
# d(m) + |p - m|, and that face's closest point lies within d(p) of p), so the lattice's closest
# points are searched among those faces alone, by Warp's own leaf test, instead of a BVH walk per
# sample: the same face, barycentrics and phi, but where two faces are equally close in exact
# arithmetic (points across a shared edge): there either code may keep the other one (the BVH's
# order, or its float box distances pruning a face a few ulps closer), whose closest point rounds a
# few nm apart. More faces than
# MESH_NEAR_CAP: the BVH walk per sample, as before (16 chosen on benchmarks/mesh_near_faces.py: the
# HOI bowl, 1,408 faces, keeps 96 % of its triangles under it; a 20k-face sphere none, at ~8 % extra
# cost for the search that overflows). Only meshes marked MESH_SIGN_PSEUDO_NEAR take it: Objects.add
# marks a closed mesh when most skin-sized triangles about its surface find at most
# objects.NEAR_FACES_MEDIAN faces near (objects.near_faces_pay).
MESH_NEAR_CAP = 16
mesh_near_ids = wp.types.vector(length=MESH_NEAR_CAP, dtype=wp.int32)
mesh_near_dist = wp.types.vector(length=MESH_NEAR_CAP, dtype=wp.float32)


@wp.func
def face_shape(mesh: wp.uint64, f: int):
    """(q, L) of face ``f``: sliver ratio q = |e0 x e1| / sum |e|^2 (Warp skips < 1e-6), longest edge L."""
    x0 = wp.mesh_get_point(mesh, 3 * f)
    x1 = wp.mesh_get_point(mesh, 3 * f + 1)
    x2 = wp.mesh_get_point(mesh, 3 * f + 2)
    e0 = x1 - x0
    e1 = x2 - x0
    e2 = x2 - x1
    q = wp.length(wp.cross(e0, e1)) / (wp.dot(e0, e0) + wp.dot(e1, e1) + wp.dot(e2, e2))
    return q, wp.sqrt(wp.max(wp.dot(e0, e0), wp.max(wp.dot(e1, e1), wp.dot(e2, e2))))


@wp.func
def mesh_face_closest(mesh: wp.uint64, f: int, p: wp.vec3):
    """(squared distance, u, v) from ``p`` to face ``f`` of ``mesh`` exactly as Warp's
    mesh_query_point_no_sign tests a BVH leaf's face (warp/native/mesh.h: its closest point, its
    squared distance, its returned u = 1 - v - w); slivers (|e0 x e1| / sum |e|^2 < 1e-6, which
    Warp skips) return a negative distance."""
    q, longest = face_shape(mesh, f)
    if q < 1.0e-6:
        return -1.0, 0.0, 0.0
    return mesh_face_closest_kept(mesh, f, p)


@wp.func
def mesh_face_closest_kept(mesh: wp.uint64, f: int, p: wp.vec3):
    """:func:`mesh_face_closest` for a face known not to be a sliver (:func:`mesh_faces_within`
    keeps no sliver): the same (squared distance, u, v) without the sliver test."""
    x0 = wp.mesh_get_point(mesh, 3 * f)
    x1 = wp.mesh_get_point(mesh, 3 * f + 1)
    x2 = wp.mesh_get_point(mesh, 3 * f + 2)
    bc = closest_on_triangle(x0, x1, x2, p)
    v = bc[1]
    w = 1.0 - bc[0] - v
    c = x0 * bc[0] + x1 * v + x2 * w
    return wp.length_sq(c - p), 1.0 - v - w, v


NEAR_ROUNDING = wp.constant(1.0e-7)  # m^-1: a listed face's rounding allowance per (longest edge / sliver ratio^2)


@wp.func
def face_rounding(mesh: wp.uint64, f: int):
    """An upper bound (m) of the float32 rounding in two closest-point distances to face ``f``
    (mesh_face_closest's, at two points within a few cm of it): NEAR_ROUNDING x L / q^2, L the
    longest edge, q = |e0 x e1| / sum |e|^2 the sliver ratio (> 1e-6 for a listed face). The
    barycentric solve loses precision as a face thins: on random points near faces 10 cm long,
    5 cm to 1 m from the origin, the error reached 3e-8, 3e-6 and 3e-5 m at aspect ratios 0.1, 0.03
    and 0.01 (this allows 4e-6, 4e-5 and 4e-4 m); a well-shaped face of 1 cm gets ~1e-8 m."""
    q, longest = face_shape(mesh, f)
    return NEAR_ROUNDING * longest / (q * q)


@wp.func
def mesh_faces_within(mesh: wp.uint64, m: wp.vec3, dm: float, r: float):
    """(ids, dist, n): the faces of ``mesh`` within ``dm`` + 2 r of ``m`` (mesh frame, m; ``dm``: m's
    distance from the mesh), n of them in ids[:n]; dist[:n] a lower bound of each one's distance
    from m (m; its computed distance less :func:`face_rounding`, for :func:`sdf_mesh_near`'s
    skips); n = -1 when they are more than MESH_NEAR_CAP. No sliver is listed (mesh_face_closest
    refuses them). Float rounding of the points' transforms is covered by a slack of 1e-6 |m| + 1e-7 m."""
    ids = mesh_near_ids()
    dist = mesh_near_dist()
    reach = (dm + 2.0 * r) * (1.0 + 1.0e-5) + 1.0e-7 + 1.0e-6 * wp.max(wp.abs(m))
    n = int(0)
    query = wp.mesh_query_aabb(mesh, m - wp.vec3(reach), m + wp.vec3(reach))
    f = int(0)
    while wp.mesh_query_aabb_next(query, f):
        d2, u, v = mesh_face_closest(mesh, f, m)
        if d2 >= 0.0 and d2 <= reach * reach:
            if n == MESH_NEAR_CAP:
                return ids, dist, -1
            ids[n] = f
            dist[n] = wp.sqrt(d2) - face_rounding(mesh, f)
            n += 1
    return ids, dist, n


@wp.func
def mesh_near_faces(mesh: wp.uint64, m: wp.vec3, r: float, query_range: float):
    """(ids, dist, n): the faces of ``mesh`` within d(m) + 2 r of ``m`` (mesh frame, m), n of them in
    ids[:n], lower bounds of their distances from m (m) in dist[:n] (:func:`mesh_faces_within`); n = -1
    when more than MESH_NEAR_CAP or nothing within ``query_range`` of m (query each point as usual)."""
    hit = wp.mesh_query_point_no_sign(mesh, m, query_range)
    if not hit.result:
        return mesh_near_ids(), mesh_near_dist(), -1
    dm = wp.length(m - wp.mesh_eval_position(mesh, hit.face, hit.u, hit.v))
    return mesh_faces_within(mesh, m, dm, r)


@wp.func
def mesh_near_first(dist: mesh_near_dist, n: int):
    """The face :func:`mesh_near_closest` tests first: the lowest dist[:n] (the earliest of equals;
    0 when n <= 0), found once per list rather than per sample."""
    first = int(0)
    for k in range(1, n):
        if dist[k] < dist[first]:
            first = k
    return first


@wp.func
def mesh_near_closest(p: wp.vec3, size: wp.vec3, mesh: wp.uint64, ids: mesh_near_ids, dist: mesh_near_dist, n: int,
                      first: int, m: wp.vec3):
    """(face or -1, u, v, squared distance) of ``p``'s closest face among ids[:n] (mesh frame;
    :func:`mesh_faces_within` about ``m``), within ``size[0]``: what testing every listed face in
    order gives (the first strictly closest), with fewer tests. Face ``first``
    (:func:`mesh_near_first`, the face nearest m) goes first; face k is skipped when dist[k] (a
    lower bound of its distance from m) less |p - m| (and a slack of 1e-6 |m| + 1e-7 m) exceeds the
    best distance so far: a distance is 1-Lipschitz, so it cannot be closer. A tie goes to the face
    earlier in ids, as in the plain loop."""
    face = int(-1)
    best = size[0] * size[0]
    bu = float(0.0)
    bv = float(0.0)
    if n <= 0:
        return face, bu, bv, best
    rho = wp.length(p - m) + 1.0e-7 + 1.0e-6 * wp.max(wp.abs(m))
    pos = int(-1)
    for j in range(n + 1):
        k = first
        if j > 0:
            k = j - 1
            if k == first:
                continue
            lb = dist[k] - rho
            if lb > 0.0 and lb * lb * (1.0 - 1.0e-5) > best:
                continue
        d2, u, v = mesh_face_closest_kept(mesh, ids[k], p)
        if d2 < best or (d2 == best and k < pos):
            best = d2
            face = ids[k]
            pos = k
            bu = u
            bv = v
    return face, bu, bv, best


@wp.func
def sdf_mesh_near(p: wp.vec3, size: wp.vec3, mesh: wp.uint64, ids: mesh_near_ids, dist: mesh_near_dist, n: int,
                  first: int, m: wp.vec3):
    """phi (m) of a pseudo-normal-signed mesh at ``p`` (mesh frame) whose closest face is among
    ids[:n] (:func:`mesh_near_faces` about ``m``; ``first``: :func:`mesh_near_first`):
    :func:`sdf_mesh_grad`'s value without the BVH walk, the closest face found by
    :func:`mesh_near_closest` and signed as :func:`mesh_signed` signs it (its value alone: the same
    closest point, ``wp.mesh_eval_position``'s, the same bits on CUDA too)."""
    face, bu, bv, best = mesh_near_closest(p, size, mesh, ids, dist, n, first, m)
    if face < 0:
        return FAR
    d = p - wp.mesh_eval_position(mesh, face, bu, bv)
    if wp.dot(d, mesh_pseudo_normal(mesh, face, bu, bv)) < 0.0:
        return -wp.length(d)
    return wp.length(d)
