"""Object geoms as device arrays: what the contact kernels query, refreshed every frame.

An :class:`Objects` holds up to ``capacity`` geoms (type, size, world pose, bounding radius, mesh
id, object index); poses change per frame without reallocation, so a CUDA graph stays valid.
Geoms of one object form a union (the minimum of their SDFs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from physhand_mj.types import GeomType

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


def invert_transforms(tf: np.ndarray) -> np.ndarray:
    """(n, 7) Warp transforms [p, q x y z w] -> their inverses [-(q^-1 p), q^-1]."""
    p, q = tf[:, :3].astype(np.float64), tf[:, 3:].astype(np.float64)
    qv, w = -q[:, :3], q[:, 3:]  # the conjugate: inverse of a unit quaternion
    t = 2.0 * np.cross(qv, p)
    rp = p + w * t + np.cross(qv, t)  # q^-1 rotates p
    return np.concatenate([-rp, qv, w], axis=1).astype(np.float32)


@dataclass
class Objects:
    """Up to ``capacity`` geoms on ``device``. Arrays (G = capacity):

    gtype (G,) int (GeomType), size (G,) vec3 (m), pose (G,) transform (world), inv_pose (G,)
    transform (world -> geom frame: what the queries use, inverted once per frame), radius (G,) float
    (bounding radius, m), mesh (G,) uint64 (wp.Mesh id or 0), obj (G,) int (object index); count (1,)
    int, the number of geoms in use. Host lists keep names and meshes alive.
    """

    device: str
    capacity: int
    gtype: object = None
    size: object = None
    pose: object = None
    inv_pose: object = None
    radius: object = None
    mesh: object = None
    obj: object = None
    count: object = None
    names: list = field(default_factory=list)
    object_names: list = field(default_factory=list)
    _meshes: list = field(default_factory=list)
    _host: dict = field(default_factory=dict)
    _pose_buf: object = None

    def __post_init__(self):
        d, c = self.device, max(int(self.capacity), 1)
        self.gtype = wp.zeros(c, dtype=int, device=d)
        self.size = wp.zeros(c, dtype=wp.vec3, device=d)
        self.pose = wp.zeros(c, dtype=wp.transform, device=d)
        self.inv_pose = wp.zeros(c, dtype=wp.transform, device=d)
        self.radius = wp.zeros(c, dtype=float, device=d)
        self.mesh = wp.zeros(c, dtype=wp.uint64, device=d)
        self.obj = wp.zeros(c, dtype=int, device=d)
        self.count = wp.zeros(1, dtype=int, device=d)
        self._host = dict(gtype=np.zeros(c, np.int32), size=np.zeros((c, 3), np.float32),
                          pose=np.zeros((c, 7), np.float32), radius=np.zeros(c, np.float32),
                          mesh=np.zeros(c, np.uint64), obj=np.zeros(c, np.int32))
        self._pose_buf = wp.empty(2 * c, dtype=wp.transform, device="cpu", pinned=wp.get_device(d).is_cuda)

    def __len__(self) -> int:
        return len(self.names)

    def add(self, gtype: GeomType, size, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), *,
            name: str = "", obj: str | None = None, vertices=None, faces=None, mesh_range: float = 1.0) -> int:
        """Add a geom (sizes in m, pose: position m and quaternion w x y z). A MESH takes
        ``vertices`` (V, 3) m and ``faces`` (F, 3) in the geom frame; ``mesh_range`` (m) is how far
        its distance query looks. ``obj`` groups geoms into one object (default: the geom's name)."""
        gtype = GeomType(gtype)
        if gtype == GeomType.NONE:
            raise ValueError("GeomType.NONE cannot be added")
        if len(self.names) >= self.capacity:
            raise ValueError(f"Objects holds at most {self.capacity} geoms; make it with a larger capacity")
        size = np.zeros(3) if size is None else np.resize(np.asarray(size, float), 3)
        if not np.all(np.isfinite(size)) or (gtype not in (GeomType.PLANE, GeomType.MESH) and np.any(size[:1] <= 0)):
            raise ValueError(f"geom '{name}': sizes must be finite and positive, got {size}")
        i = len(self.names)
        h = self._host
        mesh_id = 0
        if gtype == GeomType.MESH:
            if vertices is None or faces is None:
                raise ValueError(f"mesh geom '{name}' needs vertices and faces")
            v = np.asarray(vertices, np.float32).reshape(-1, 3)
            f = np.asarray(faces, np.int32).reshape(-1, 3)
            if not len(f) or not np.all(np.isfinite(v)) or f.min() < 0 or f.max() >= len(v):
                raise ValueError(f"mesh geom '{name}': empty faces, non-finite vertices or bad indices")
            m = wp.Mesh(points=wp.array(v, dtype=wp.vec3, device=self.device),
                        indices=wp.array(f.ravel(), dtype=wp.int32, device=self.device))
            self._meshes.append(m)
            mesh_id = m.id
            size = np.array([mesh_range, 0.0, 0.0])
            h["radius"][i] = float(np.linalg.norm(v, axis=1).max())
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
        n = len(self.names)
        pos = np.asarray(pos, float).reshape(n, 3)
        quat = np.asarray(quat, float).reshape(n, 4)
        norm = np.linalg.norm(quat, axis=1, keepdims=True)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))) or np.any(norm < 1e-9):
            bad = [self.names[i] for i in np.flatnonzero(~(np.isfinite(pos).all(1) & np.isfinite(quat).all(1)
                                                           & (norm[:, 0] >= 1e-9)))]
            raise ValueError(f"geoms {bad}: non-finite or zero pose")
        q = quat / norm
        self._host["pose"][:n] = np.concatenate([pos, q[:, 1:], q[:, :1]], axis=1)
        self._upload_pose()

    def _upload_pose(self) -> None:
        c = self.pose.shape[0]
        buf = self._pose_buf.numpy()
        buf[:c] = self._host["pose"]
        buf[c:] = invert_transforms(self._host["pose"])
        wp.copy(self.pose, self._pose_buf, count=c)
        wp.copy(self.inv_pose, self._pose_buf, src_offset=c, count=c)

    def upload(self) -> None:
        """All arrays (after ``add``)."""
        h = self._host
        for name in ("gtype", "size", "radius", "mesh", "obj"):
            getattr(self, name).assign(h[name])
        self._upload_pose()
        self.count.assign(np.array([len(self.names)], np.int32))
