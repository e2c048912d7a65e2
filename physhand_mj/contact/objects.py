"""Object geoms as device arrays: what the contact kernels query, refreshed every frame.

An :class:`Objects` holds up to ``capacity`` geoms (type, size, world pose, bounding radius, mesh
id, object index); poses change per frame without reallocation, so a CUDA graph stays valid.
Geoms of one object form a union (the minimum of their SDFs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import triangle_bound
from physhand_mj.contact.sdf import GeomSet
from physhand_mj.contact.sdf_mesh import (FEATURES_PER_FACE, GRID_OFF, GRID_PAD, MESH_SIGN_PSEUDO,
                                          MESH_SIGN_PSEUDO_NEAR, MESH_SIGN_WINDING, WINDING_ACCURACY, mesh_near_faces,
                                          pseudo_normal_table, sdf_mesh_grad)
from physhand_mj.types import GeomType

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

# mujoco.mjtGeom values of the geoms the skin can collide with (height fields and SDF plugins are not)
MJ_GEOM_TYPES = {0: GeomType.PLANE, 2: GeomType.SPHERE, 3: GeomType.CAPSULE, 4: GeomType.ELLIPSOID,
                 5: GeomType.CYLINDER, 6: GeomType.BOX, 7: GeomType.MESH}
PLANE_RADIUS = 1.0e6  # bounding radius of the unbounded plane (m)


def bounding_radius(gtype: GeomType, size) -> float:
    """Radius (m) of a sphere about the geom origin that contains the geom (planes: unbounded)."""
    s = np.asarray(size, float)
    if gtype == GeomType.PLANE:
        return PLANE_RADIUS
    if gtype == GeomType.SPHERE:
        return float(s[0])
    if gtype in (GeomType.CAPSULE,):
        return float(s[0] + s[1])
    if gtype == GeomType.CYLINDER:
        return float(np.hypot(s[0], s[1]))
    if gtype in (GeomType.BOX,):
        return float(np.linalg.norm(s))
    if gtype == GeomType.ELLIPSOID:
        return float(s.max())
    if gtype == GeomType.CONE:
        return float(np.hypot(s[0], s[1]))
    raise ValueError(f"no bounding radius rule for {gtype!r}")


def _mesh_key(vertices, faces, sign: str) -> tuple:
    """A key for a mesh's exact vertices, faces and sign mode (equal keys: the same wp.Mesh)."""
    import hashlib

    v = np.ascontiguousarray(np.asarray(vertices, np.float64))
    f = np.ascontiguousarray(np.asarray(faces, np.int64))
    return (v.shape, f.shape, sign, hashlib.sha1(v.tobytes() + f.tobytes()).hexdigest())


def invert_transforms(tf: np.ndarray) -> np.ndarray:
    """(n, 7) Warp transforms [p, q x y z w] -> their inverses [-(q^-1 p), q^-1]."""
    p, q = tf[:, :3].astype(np.float64), tf[:, 3:].astype(np.float64)
    qv, w = -q[:, :3], q[:, 3:]  # the conjugate: inverse of a unit quaternion
    t = 2.0 * _cross(qv, p)
    rp = p + w * t + _cross(qv, t)  # q^-1 rotates p
    out = np.empty((len(tf), 7), np.float32)
    out[:, :3], out[:, 3:6], out[:, 6:] = -rp, qv, w
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b of (n, 3) arrays (np.cross's own overhead is most of a few-geom frame's pose upload)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


INSIDE_MIN_AREA = 0.9  # an open mesh must bound a region behind this fraction of its face area
_PROBE_DEPTH = 1.0e-3  # probes sit this fraction of sqrt(face area) behind / before each face centroid


@wp.kernel
def _winding_above(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), threshold: float,
                   above: wp.array(dtype=wp.int32)):
    # 1 where the generalised winding number at the point exceeds ``threshold``
    i = wp.tid()
    hit = wp.mesh_query_point_sign_winding_number(mesh, points[i], 1.0e6, WINDING_ACCURACY, threshold)
    above[i] = wp.where(hit.result and hit.sign < 0.0, 1, 0)


# a pseudo-normal-signed mesh carries its faces' feature normals (sdf_mesh.pseudo_normal_table): the same
# bits as the walk each query made before; False builds meshes without (the walk per query), for timings
PSEUDO_NORMAL_TABLE = True


def _warp_mesh(v: np.ndarray, f: np.ndarray, device: str, winding: bool) -> wp.Mesh:
    """The ``wp.Mesh`` of (v, f); a pseudo-normal-signed one (not ``winding``) carries its faces'
    feature normals (``sdf_mesh.pseudo_normal_table``) in its ``velocities``, which nothing else uses:
    the sign's edge and vertex cases then read one entry instead of walking the BVH. The table is
    made once, for these points: an object mesh is rigid (its pose moves it), and a mesh whose
    points were changed afterwards would need the table filled again."""
    table = None
    if not winding and PSEUDO_NORMAL_TABLE:
        table = wp.zeros(len(f) * int(FEATURES_PER_FACE), dtype=wp.vec3, device=device)
    mesh = wp.Mesh(points=wp.array(np.asarray(v, np.float32), dtype=wp.vec3, device=device),
                   indices=wp.array(np.asarray(f, np.int32).ravel(), dtype=wp.int32, device=device),
                   velocities=table, support_winding_number=winding)
    if table is not None:  # filled by the walk itself (sdf_mesh.mesh_feature_normal), on this mesh's own BVH
        wp.launch(pseudo_normal_table, len(table), inputs=[mesh.id], outputs=[table], device=device)
    return mesh


def _bounded_area(mesh, tm) -> tuple[float, float]:
    """Area fractions of the faces with the winding number's inside (w > 1/2) just behind them, as
    oriented, and as they would be flipped (w < -1/2 just before them). Faces inside another part
    (w = 2 behind) count: they bound the union no less."""
    area = tm.area_faces
    ok = area > 1e-12 * area.max()
    depth = _PROBE_DEPTH * np.sqrt(area[ok])[:, None]
    above = wp.empty(int(ok.sum()), dtype=wp.int32, device=mesh.device)
    out = []
    for side, threshold in ((-1.0, 0.5), (1.0, -0.5)):
        probes = tm.triangles_center[ok] + side * depth * tm.face_normals[ok]
        pts = wp.array(probes.astype(np.float32), dtype=wp.vec3, device=mesh.device)
        wp.launch(_winding_above, len(probes), inputs=[mesh.id, pts, threshold], outputs=[above], device=mesh.device)
        out.append(above.numpy().astype(bool))
    weight = area[ok] / area[ok].sum()
    return float(weight[out[0]].sum()), float(weight[~out[1]].sum())


def prepare_mesh(vertices, faces, *, name: str = "", sign: str = "auto", device: str = "cpu"):
    """A ``wp.Mesh`` whose signed distance is right, and its sign method (``sdf.MESH_SIGN_*``).

    Vertices are merged (an STL's triangle soup becomes one surface) and faces that repeat a vertex
    dropped. A closed mesh (watertight, consistently wound, no two parts whose boxes overlap) gets
    the pseudo-normal sign; its winding is made consistent and, if it encloses negative volume,
    turned outward (a warning says so). Anything else gets the winding-number sign, closing holes
    over, and is flipped if its faces point inward; a surface that bounds no region (an open sheet,
    a closed one folded onto itself) is a ``ValueError`` that says how to fix it."""
    import trimesh  # lazily: only mesh geoms need it

    what = f"mesh geom '{name}'"
    if sign not in ("auto", "winding"):
        raise ValueError(f"{what}: mesh_sign must be 'auto' or 'winding', got {sign!r}")
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if not len(f) or not np.all(np.isfinite(v)) or f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{what}: empty faces, non-finite vertices or bad indices")
    tm = trimesh.Trimesh(v, f, process=True)  # merges duplicate vertices
    f = tm.faces
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    if not keep.all():
        tm.update_faces(keep)
    if not len(tm.faces) or tm.area <= 0.0:
        raise ValueError(f"{what}: all faces are degenerate (zero area)")
    repaired = []
    if not tm.is_winding_consistent:
        trimesh.repair.fix_winding(tm)
        repaired.append("made its face winding consistent")
    closed = tm.is_watertight and tm.is_winding_consistent and not _parts_overlap(tm)
    extent = float(np.ptp(tm.vertices, axis=0).max())
    if closed:
        with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by a zero volume
            volume = float(tm.volume)
        if abs(volume) <= 1e-9 * extent ** 3:
            raise ValueError(f"{what} is closed but encloses no volume (a surface folded onto itself): "
                             f"give it a thickness (or use a thin box geom)")
        if volume < 0.0:
            tm.invert()
            repaired.append("turned its inside-out faces outward")
    winding = sign == "winding" or not closed
    m = _warp_mesh(tm.vertices, tm.faces, device, winding)
    if winding:
        kept, flipped = _bounded_area(m, tm)
        if flipped > kept:
            tm.invert()
            m = _warp_mesh(tm.vertices, tm.faces, device, True)
            repaired.append("turned its inward-facing faces outward")
        if max(kept, flipped) < INSIDE_MIN_AREA:
            raise ValueError(
                f"{what} does not bound a region (only {100 * max(kept, flipped):.0f}% of its area has the winding "
                f"number's inside behind it): an open sheet or a surface with large holes has no inside to push "
                f"the skin out of. Close it (e.g. trimesh.repair.fill_holes(mesh), or a watertight remesh) or give "
                f"it a thickness (a thin box geom for a plate)")
    if repaired:
        from physhand_mj.warn import warn_user

        warn_user(f"{what}: {' and '.join(repaired)}", UserWarning)
    return m, MESH_SIGN_WINDING if winding else MESH_SIGN_PSEUDO


THICKNESS_SAMPLES = 2048  # inward rays per mesh for its half-thickness (mesh_half_thickness)
THICKNESS_EVEN = 0.5  # a mesh is a wall or shell where its 10 % thickness quantile is >= this x its median


@wp.kernel
def _inward_ray(mesh: wp.uint64, origin: wp.array(dtype=wp.vec3), direction: wp.array(dtype=wp.vec3),
                max_t: float, t: wp.array(dtype=float)):
    i = wp.tid()
    q = wp.mesh_query_ray(mesh, origin[i], direction[i], max_t)
    t[i] = wp.where(q.result, q.t, -1.0)


def mesh_half_thickness(mesh: wp.Mesh, samples: int = THICKNESS_SAMPLES) -> float:
    """Half the thickness (m) of a mesh of even thickness (a plate, a wall, a shell), for the
    side-aware exit's floor (query.side_floor; 0 = none: the fixed floor): from ``samples`` points
    spread evenly over the surface (by area), a ray along the inward face normal to the next surface
    (``wp.mesh_query_ray``); half the 10 % quantile of those lengths where it is at least
    ``THICKNESS_EVEN`` x their median. Tapered meshes (wedges, cones: thin only near an edge or a
    tip) get 0 and keep the fixed floor, as the analytic cone does: a knife's floor from its thin
    edge (0.04 mm) let exits fire along its faces (one frame 570 um deep in the palm, 173 um with
    the fixed floor; tests/stress). Measured: a 1 mm plate 0.5 mm (the fixed 0.5 mm floor never
    acted there: the skin tunnelled, as for thin box geoms), the HOI bowl's 8 mm shell 4 mm, an
    8 mm icosahedron 5.9 mm, a 30-degree knife and cone 0."""
    import trimesh

    v = mesh.points.numpy().astype(np.float64)
    f = mesh.indices.numpy().reshape(-1, 3)
    tm = trimesh.Trimesh(v, f, process=False)
    pts, face = trimesh.sample.sample_surface(tm, samples, seed=0)
    n = tm.face_normals[face]
    extent = float(np.ptp(v, axis=0).max())
    eps = 1.0e-6 * max(extent, 1.0e-3)  # start just inside the face (no hit on the face itself)
    d = mesh.points.device
    t = wp.zeros(len(pts), dtype=float, device=d)
    wp.launch(_inward_ray, len(pts), inputs=[mesh.id, wp.array((pts - eps * n).astype(np.float32), dtype=wp.vec3,
                                                                 device=d),
                                            wp.array((-n).astype(np.float32), dtype=wp.vec3, device=d),
                                            2.0 * extent], outputs=[t], device=d)
    t = t.numpy()
    hit = t[t > 0]
    if len(hit) < 0.5 * len(t):  # mostly misses: no inside to measure across (an open surface)
        return 0.0
    q10, q50 = np.quantile(hit, [0.1, 0.5]) + eps
    return float(0.5 * q10) if q10 >= THICKNESS_EVEN * q50 else 0.0


NEAR_FACES_PROBES = 256  # skin-sized triangles about a closed mesh's surface that near_faces_pay tries (count)
NEAR_FACES_SPREAD = 1.2e-3  # m: their corners' spread about their centre (the hand's skin triangles' size)
NEAR_FACES_MEDIAN = 10  # faces: the median count near a probe up to which a triangle's near faces pay
NEAR_FACES_SHARE = 0.75  # ... and the share of probes that must find them under sdf_mesh.MESH_NEAR_CAP


@wp.kernel
def _near_faces_count(mesh: wp.uint64, tri: wp.array(dtype=wp.vec3), count: wp.array(dtype=int)):
    t = wp.tid()
    m, r = triangle_bound(tri[3 * t], tri[3 * t + 1], tri[3 * t + 2])
    ids, dist, n = mesh_near_faces(mesh, m, r, 1.0e6)
    count[t] = n


def near_faces_pay(mesh: wp.Mesh, seed: int = 0) -> bool:
    """Whether the decision points should search a skin triangle's near faces on ``mesh`` (a closed,
    pseudo-normal-signed mesh) instead of walking the BVH per sample (sdf_mesh.mesh_near_faces; the same
    phi either way): :data:`NEAR_FACES_PROBES` triangles of the skin's size about points 2 mm inside
    to 4 mm outside its surface must find at most :data:`NEAR_FACES_MEDIAN` faces near (median) and
    fit the capacity in :data:`NEAR_FACES_SHARE` of cases. On benchmarks/mesh_near_faces.py: the HOI
    bowl (median 7, 97 %: 1.9 x faster) and a box (2, 100 %: 2.8 x) pay; a 1,280-face sphere of 3 cm
    (13, 43 %: even) and a 20k-face one (0 %: 8 % slower) do not."""
    pts = mesh.points.numpy().astype(np.float64)
    faces = mesh.indices.numpy().reshape(-1, 3)
    tri = pts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(normal, axis=1)
    if not np.any(area > 0):
        return False
    rng = np.random.default_rng(seed)
    f = rng.choice(len(faces), NEAR_FACES_PROBES, p=area / area.sum())
    u, v = rng.uniform(size=(2, NEAR_FACES_PROBES))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    on = tri[f, 0] + u[:, None] * (tri[f, 1] - tri[f, 0]) + v[:, None] * (tri[f, 2] - tri[f, 0])
    centre = on + normal[f] / np.maximum(area[f], 1e-30)[:, None] * rng.uniform(-2e-3, 4e-3, (NEAR_FACES_PROBES, 1))
    probes = centre[:, None, :] + rng.normal(size=(NEAR_FACES_PROBES, 3, 3)) * NEAR_FACES_SPREAD
    d = mesh.device
    count = wp.zeros(NEAR_FACES_PROBES, dtype=int, device=d)
    wp.launch(_near_faces_count, NEAR_FACES_PROBES,
              inputs=[mesh.id, wp.array(probes.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device=d)],
              outputs=[count], device=d)
    n = count.numpy()
    fit = n >= 0
    return bool(fit.mean() >= NEAR_FACES_SHARE and np.median(n[fit]) <= NEAR_FACES_MEDIAN)


MESH_GRID = 2.0e-3  # m: default node spacing of a mesh's distance grid (mesh_grid; 0 = none)
GRID_MAX_NODES = 1_000_000  # larger meshes get a coarser spacing (the grid's memory and build time)


@wp.kernel
def _grid_values(mesh: wp.uint64, size: wp.vec3, origin: wp.vec3, h: float, ny: int, nz: int,
                 out: wp.array(dtype=float)):
    i = wp.tid()
    x = i // (ny * nz)
    y = (i // nz) % ny
    z = i % nz
    d, g = sdf_mesh_grad(origin + h * wp.vec3(float(x), float(y), float(z)), size,
                         wp.vec2ul(mesh, wp.uint64(0)))
    out[i] = d


def mesh_grid(mesh: wp.Mesh, sign: int, spacing: float = MESH_GRID):
    """The exact signed distance (m) of ``mesh`` (sign method ``sign``) at the nodes of a regular grid
    over its box grown by GRID_PAD, as a ``wp.Volume`` (node (i, j, k) at the box corner + spacing x
    (i, j, k); background sdf_mesh.GRID_OFF off the grid, which sdf_mesh.grid_lower reads as "farther than
    GRID_PAD from the mesh's box"), or None for ``spacing`` <= 0 and for meshes signed by the
    winding number (open or overlapping: their inside is not bounded by faces alone). The spacing grows past
    ``spacing`` where the grid would hold more than GRID_MAX_NODES nodes. sdf.geom_sdf (values only) uses it
    only to answer points provably farther than sdf_mesh.GRID_BAND outside the mesh (a lower bound of the
    distance, exact decisions below that band): it skips the BVH query there, which the broadphase
    and the metrics ask for most of their points. Costs one exact query per node once (about 1 us
    each on a CPU) and 4 bytes per node."""
    if spacing is None or spacing <= 0 or sign == MESH_SIGN_WINDING:
        # (an open mesh's inside ends where the winding number crosses 1/2 across a hole, not at a
        # surface: a ball free of faces may hold both sides, so the bound's sign would not hold)
        return None
    v = mesh.points.numpy().astype(np.float64)
    lo, hi = v.min(axis=0) - GRID_PAD, v.max(axis=0) + GRID_PAD
    ext = hi - lo
    h = max(float(spacing), float(np.cbrt(np.prod(ext) / GRID_MAX_NODES)))
    n = np.ceil(ext / h).astype(int) + 1
    d = mesh.points.device
    out = wp.zeros(int(np.prod(n)), dtype=float, device=d)
    size = wp.vec3(4.0 * float(np.linalg.norm(ext)), float(sign), 0.0)  # a range that reaches the surface
    wp.launch(_grid_values, out.shape[0], inputs=[mesh.id, size, wp.vec3(*lo), h, int(n[1]), int(n[2])],
              outputs=[out], device=d)
    values = out.numpy().reshape(n)
    return wp.Volume.load_from_numpy(values, min_world=tuple(float(c) for c in lo), voxel_size=h, bg_value=GRID_OFF,
                                     device=d)


def _parts_overlap(tm, max_parts: int = 512) -> bool:
    """Whether two connected parts of the mesh have overlapping boxes (they may intersect or nest,
    where only the winding number gives the union's sign); past ``max_parts`` parts, assume so."""
    import trimesh

    labels = trimesh.graph.connected_component_labels(tm.face_adjacency, node_count=len(tm.faces))
    parts = int(labels.max()) + 1
    if parts == 1:
        return False
    if parts > max_parts:
        return True
    order = np.argsort(labels, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    lo = np.minimum.reduceat(tm.triangles.min(axis=1)[order], starts, axis=0)
    hi = np.maximum.reduceat(tm.triangles.max(axis=1)[order], starts, axis=0)
    overlap = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    return bool(np.triu(overlap, 1).any())


# sizes an SDF reads per type (MuJoCo's conventions; types.GeomType)
_SIZES_USED = {GeomType.SPHERE: 1, GeomType.CAPSULE: 2, GeomType.CYLINDER: 2, GeomType.CONE: 2,
               GeomType.ELLIPSOID: 3, GeomType.BOX: 3}


@dataclass
class Objects:
    """Up to ``capacity`` geoms on ``device``. Arrays (G = capacity):

    gtype (G,) int (GeomType), size (G,) vec3 (m), pose (G,) transform (world), inv_pose (G,)
    transform (world -> geom frame: what the queries use, inverted once per frame), radius (G,) float
    (bounding radius, m), mesh (G,) vec2ul (wp.Mesh id or 0, its distance grid's wp.Volume id or 0:
    :func:`mesh_grid`; what the broadphase and the metrics query), mesh_exact (G,) vec2ul (the same
    without the grids: what the decision points and Eq. 9 query), obj (G,) int (object index); count (1,)
    int, the number of geoms in use. ``geoms`` and ``geoms_exact`` hold them as the kernels take them
    (sdf.GeomSet, with ``mesh`` and with ``mesh_exact``). Host lists keep names and meshes alive.
    """

    device: str
    capacity: int
    gtype: object = None
    size: object = None
    pose: object = None
    inv_pose: object = None
    radius: object = None
    mesh: object = None
    mesh_exact: object = None
    obj: object = None
    count: object = None
    geoms: object = None
    geoms_exact: object = None
    names: list = field(default_factory=list)
    object_names: list = field(default_factory=list)
    _meshes: list = field(default_factory=list)
    _mesh_cache: dict = field(default_factory=dict)  # the same vertices/faces/sign: one wp.Mesh (batched worlds)
    _host: dict = field(default_factory=dict)
    _pose_buf: object = None
    # bumped by every upload of the geoms (add, SoftHand.refresh_objects): what is built from their
    # types and sizes (the contact's object points and feature lists) is made again when it changes
    version: int = 0

    def __post_init__(self):
        d, c = self.device, max(int(self.capacity), 1)
        self.gtype = wp.zeros(c, dtype=int, device=d)
        self.size = wp.zeros(c, dtype=wp.vec3, device=d)
        self.pose = wp.zeros(c, dtype=wp.transform, device=d)
        self.inv_pose = wp.zeros(c, dtype=wp.transform, device=d)
        self.radius = wp.zeros(c, dtype=float, device=d)
        self.mesh = wp.zeros(c, dtype=wp.vec2ul, device=d)
        self.mesh_exact = wp.zeros(c, dtype=wp.vec2ul, device=d)
        self.obj = wp.zeros(c, dtype=int, device=d)
        self.count = wp.zeros(1, dtype=int, device=d)
        self.geoms, self.geoms_exact = self._geom_set(self.mesh), self._geom_set(self.mesh_exact)
        self._host = dict(gtype=np.zeros(c, np.int32), size=np.zeros((c, 3), np.float32),
                          pose=np.zeros((c, 7), np.float32), radius=np.zeros(c, np.float32),
                          mesh=np.zeros((c, 2), np.uint64), obj=np.zeros(c, np.int32))
        self._pose_buf = wp.empty(2 * c, dtype=wp.transform, device="cpu", pinned=wp.get_device(d).is_cuda)

    def _geom_set(self, mesh) -> GeomSet:
        s = GeomSet()
        s.gtype, s.size, s.inv_pose, s.radius = self.gtype, self.size, self.inv_pose, self.radius
        s.mesh, s.obj, s.count = mesh, self.obj, self.count
        return s

    def __len__(self) -> int:
        return len(self.names)

    @property
    def has_mesh(self) -> bool:
        """Whether a MESH geom was added (scenes without one take kernels compiled without the mesh
        branch: query_tiled.tiled_kernel_for)."""
        return bool(np.any(self._host["gtype"][: len(self.names)] == int(GeomType.MESH)))

    @property
    def geom_objects(self) -> np.ndarray:
        """(n,) int: each added geom's object (its index in ``object_names``), in ``add`` order."""
        return self._host["obj"][: len(self.names)].astype(np.int64)

    def add(self, gtype: GeomType, size, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), *,
            name: str = "", obj: str | None = None, vertices=None, faces=None, mesh_range: float = 1.0,
            mesh_sign: str = "auto", mesh_grid_spacing: float = MESH_GRID) -> int:
        """Add a geom (sizes in m, pose: position m and quaternion w x y z). A MESH takes
        ``vertices`` (V, 3) m and ``faces`` (F, 3) in the geom frame; ``mesh_range`` (m) is how far
        its distance query looks; ``mesh_sign`` is "auto" (see :func:`prepare_mesh`) or "winding"
        (force the winding-number sign, e.g. for a mesh that passes through itself);
        ``mesh_grid_spacing`` (m) the node spacing of its distance grid (:func:`mesh_grid`; 0: none,
        every query walks the BVH; the answers below sdf_mesh.GRID_BAND are the same). ``obj`` groups
        geoms into one object (default: the geom's name)."""
        try:
            gtype = GeomType(gtype)
        except ValueError:
            raise ValueError(f"geom '{name}': unsupported geom type {gtype!r}; use one of "
                             f"{[t.name for t in GeomType if t != GeomType.NONE]}") from None
        if gtype == GeomType.NONE:
            raise ValueError("GeomType.NONE cannot be added")
        if len(self.names) >= self.capacity:
            raise ValueError(f"Objects holds at most {self.capacity} geoms; make it with a larger capacity")
        size = np.zeros(3) if size is None else np.resize(np.asarray(size, float), 3)
        used = _SIZES_USED.get(gtype, 0)  # a zero size the SDF uses makes a degenerate shape
        if not np.all(np.isfinite(size)) or np.any(size[:used] <= 0):
            raise ValueError(f"geom '{name}': sizes must be finite and positive ({gtype.name} uses {used}), got {size}")
        i = len(self.names)
        h = self._host
        mesh_id = (0, 0)
        if gtype == GeomType.MESH:
            if vertices is None or faces is None:
                raise ValueError(f"mesh geom '{name}' needs vertices and faces")
            key = (*_mesh_key(vertices, faces, mesh_sign), float(mesh_grid_spacing or 0.0))
            if key not in self._mesh_cache:  # a rigid mesh in its geom frame: shared by every geom that has it
                m, sign = prepare_mesh(vertices, faces, name=name, sign=mesh_sign, device=self.device)
                grid = mesh_grid(m, sign, mesh_grid_spacing)
                self._meshes.append(m)
                if sign == MESH_SIGN_PSEUDO and near_faces_pay(m):  # (a mode of the same sign: sdf.py)
                    sign = MESH_SIGN_PSEUDO_NEAR
                self._mesh_cache[key] = (m, sign, mesh_half_thickness(m), float(np.linalg.norm(m.points.numpy(), axis=1).max()),
                                         grid)
            m, sign, half, radius, grid = self._mesh_cache[key]
            mesh_id = (m.id, grid.id if grid is not None else 0)
            size = np.array([mesh_range, float(sign), half])  # query.side_floor reads [2]
            h["radius"][i] = radius
        else:
            h["radius"][i] = bounding_radius(gtype, size)
        oname = obj if obj is not None else (name or f"object{i}")
        if oname not in self.object_names:
            self.object_names.append(oname)
        h["gtype"][i] = int(gtype)
        h["size"][i] = size
        h["mesh"][i] = mesh_id
        h["obj"][i] = self.object_names.index(oname)
        self.names.append(name or f"geom{i}")
        self.set_pose(i, pos, quat, upload=False)
        self.upload()
        return i

    def set_pose(self, i: int, pos, quat, upload: bool = True) -> None:
        pos = np.asarray(pos, float)
        quat = np.asarray(quat, float)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))) or np.linalg.norm(quat) < 1e-9:
            raise ValueError(f"geom '{self.names[i] if i < len(self.names) else i}': non-finite or zero pose")
        q = quat / np.linalg.norm(quat)
        self._host["pose"][i] = [*pos, q[1], q[2], q[3], q[0]]  # Warp transforms: xyz, then quat x y z w
        if upload:
            self._upload_pose()

    def set_poses(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """All geom poses at once (the per-frame call): pos (n, 3) m, quat (n, 4) w x y z, in ``add``
        order. Only the pose array is uploaded, through a preallocated host buffer."""
        self.set_pose_rows(self.pose_rows(pos, quat))

    def pose_rows(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """:meth:`set_poses`' checks and conversion, nothing uploaded: (2 n, 7) float32, every geom's
        Warp transform [p, q x y z w], then their inverses. (BatchedHands.submit prepares the next
        frame's while the device runs this one; :meth:`set_pose_rows` uploads them.)"""
        n = len(self.names)
        pos = np.asarray(pos, float).reshape(n, 3)
        quat = np.asarray(quat, float).reshape(n, 4)
        norm = np.linalg.norm(quat, axis=1, keepdims=True)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))) or np.any(norm < 1e-9):
            bad = [self.names[i] for i in np.flatnonzero(~(np.isfinite(pos).all(1) & np.isfinite(quat).all(1)
                                                           & (norm[:, 0] >= 1e-9)))]
            raise ValueError(f"geoms {bad}: non-finite or zero pose")
        q = quat / norm
        rows = np.empty((2 * n, 7), np.float32)
        rows[:n] = np.concatenate([pos, q[:, 1:], q[:, :1]], axis=1)
        rows[n:] = invert_transforms(rows[:n])  # (of the float32 poses, as _upload_pose inverts them)
        return rows

    def set_pose_rows(self, rows: np.ndarray) -> None:
        """Upload the poses and inverses :meth:`pose_rows` made."""
        n = len(self.names)
        if rows.shape != (2 * n, 7):
            raise ValueError(f"pose rows must be ({2 * n}, 7) (Objects.pose_rows), got {rows.shape}")
        self._host["pose"][:n] = rows[:n]
        self._copy_pose(rows[:n], rows[n:])

    def _upload_pose(self) -> None:
        self._copy_pose(self._host["pose"], invert_transforms(self._host["pose"]))

    def _copy_pose(self, pose: np.ndarray, inv: np.ndarray) -> None:
        """The first len(pose) geoms' poses and inverses into the pinned buffer, then both arrays up."""
        c, k = self.pose.shape[0], len(pose)
        buf = self._pose_buf.numpy()
        buf[:k] = pose
        buf[c:c + k] = inv
        wp.copy(self.pose, self._pose_buf, count=c)
        wp.copy(self.inv_pose, self._pose_buf, src_offset=c, count=c)

    def upload(self) -> None:
        """All arrays (after ``add``)."""
        h = self._host
        for name in ("gtype", "size", "radius", "mesh", "obj"):
            getattr(self, name).assign(h[name])
        self.mesh_exact.assign(h["mesh"] * np.array([1, 0], np.uint64))
        self._upload_pose()
        self.count.assign(np.array([len(self.names)], np.int32))
        self.version += 1
