"""Skin write-back in Warp: solver positions -> the MuJoCo skin mesh (vertices and normals).

MuJoCo stores a mesh in its own frame and places it with the geom pose, so each world vertex goes
back through the geom's pose; vertex normals are the area-weighted sums of the face normals
(MuJoCo indexes normals per vertex when the mesh has one normal per vertex). On the CPU the kernels
write straight into ``model.mesh_vert`` / ``mesh_normal`` (Warp arrays over MuJoCo's memory); on
CUDA they write device buffers that come back through pinned host memory in one copy each. On
CUDA the device half (the geom frame up, the three kernels, the copies down) is a list of ops
(:meth:`SkinWriter.device_ops`) that SoftHand records at the end of the solver's frame graph
(``Solver.set_frame_tail``): no launches of its own and no sync of its own each frame; the host
half (:meth:`SkinWriter.finish`) then copies into MuJoCo's arrays after the frame's sync.
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.kernel
def to_mesh_frame(x: wp.array(dtype=wp.vec3), frame: wp.array(dtype=float), local: wp.array(dtype=wp.vec3),
                  normal: wp.array(dtype=wp.vec3)):
    """local_i = R^T (x_i - origin) for the geom frame [origin (3), R row by row (9)]; clears the
    normal accumulator."""
    i = wp.tid()
    origin = wp.vec3(frame[0], frame[1], frame[2])
    rot = wp.mat33(frame[3], frame[4], frame[5], frame[6], frame[7], frame[8], frame[9], frame[10], frame[11])
    local[i] = wp.transpose(rot) * (x[i] - origin)
    normal[i] = wp.vec3(0.0)


@wp.kernel
def accumulate_normals(faces: wp.array2d(dtype=int), local: wp.array(dtype=wp.vec3), normal: wp.array(dtype=wp.vec3)):
    """Each face adds its area-weighted normal (the cross product) to its three vertices."""
    f = wp.tid()
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    n = wp.cross(local[i1] - local[i0], local[i2] - local[i0])
    wp.atomic_add(normal, i0, n)
    wp.atomic_add(normal, i1, n)
    wp.atomic_add(normal, i2, n)


@wp.kernel
def normalize(normal: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    n = normal[i]
    normal[i] = n / wp.max(wp.length(n), 1.0e-12)


class SkinWriter:
    """Writes the first ``n`` solver vertices into mesh ``mesh_id`` of ``model`` (faces (F, 3) index
    those vertices); ``x`` is the solver's position array (its device decides the path)."""

    def __init__(self, model, mesh_id: int, faces: np.ndarray, x: wp.array):
        self.model = model
        n = int(model.mesh_vertnum[mesh_id])
        self.n = n
        adr = int(model.mesh_vertadr[mesh_id])
        self.vert = model.mesh_vert[adr: adr + n]
        self.with_normals = int(model.mesh_normalnum[mesh_id]) == n
        nadr = int(model.mesh_normaladr[mesh_id])
        self.norm = model.mesh_normal[nadr: nadr + n] if self.with_normals else np.zeros((n, 3), np.float32)
        d = x.device
        self.device = d
        self.x = x
        self.faces = wp.array(np.asarray(faces, np.int32), dtype=int, device=d)
        self.world = np.zeros((n, 3), np.float64)
        self._ops = None  # device_ops, recorded on the first immediate write
        # the geom frame [origin, R row by row]: the kernel reads it from the device (a recorded graph
        # replays the same launch every frame); on CUDA uploaded from pinned memory inside the ops
        self.frame_host = wp.zeros(12, dtype=float, device="cpu", pinned=not d.is_cpu)
        self.frame = self.frame_host if d.is_cpu else wp.zeros(12, dtype=float, device=d)
        if d.is_cpu:  # alias MuJoCo's arrays: the kernels write the model directly
            self.local = wp.array(self.vert, dtype=wp.vec3, device="cpu", copy=False)
            self.normal = wp.array(self.norm, dtype=wp.vec3, device="cpu", copy=False)
            self.x_host = None
        else:
            self.local = wp.zeros(n, dtype=wp.vec3, device=d)
            self.normal = wp.zeros(n, dtype=wp.vec3, device=d)
            self.local_host = wp.zeros(n, dtype=wp.vec3, device="cpu", pinned=True)
            self.normal_host = wp.zeros(n, dtype=wp.vec3, device="cpu", pinned=True)
            self.x_host = wp.zeros(n, dtype=wp.vec3, device="cpu", pinned=True)

    def set_frame(self, origin: np.ndarray, rot: np.ndarray) -> None:
        """The geom's pose the next write maps into: origin (3,) m, rotation (3, 3)."""
        f = self.frame_host.numpy()
        f[:3] = origin
        f[3:] = np.asarray(rot).ravel()

    def device_ops(self) -> list:
        """The write's device work as ops (CUDA; SoftHand records them into the solver's frame graph):
        the frame up, to the mesh frame, the normals, the three copies down (into pinned memory)."""
        d, n = self.device, self.n
        ops = [] if d.is_cpu else [lambda: wp.copy(self.frame, self.frame_host)]
        ops.append(wp.launch(to_mesh_frame, n, inputs=[self.x, self.frame], outputs=[self.local, self.normal],
                             device=d, record_cmd=True).launch)
        if self.with_normals:
            ops.append(wp.launch(accumulate_normals, self.faces.shape[0], inputs=[self.faces, self.local],
                                 outputs=[self.normal], device=d, record_cmd=True).launch)
            ops.append(wp.launch(normalize, n, inputs=[self.normal], device=d, record_cmd=True).launch)
        if not d.is_cpu:
            ops.append(lambda: wp.copy(self.x_host, self.x, count=n))
            ops.append(lambda: wp.copy(self.local_host, self.local))
            if self.with_normals:
                ops.append(lambda: wp.copy(self.normal_host, self.normal))
        return ops

    def finish(self) -> np.ndarray:
        """CUDA, after the device ops ran and the device synchronised: MuJoCo's mesh from the pinned
        copies (after the finite check); returns the world positions (n, 3) float64 (m)."""
        self.world[:] = self.x_host.numpy()
        _check_finite(self.world)
        self.vert[:] = self.local_host.numpy()
        if self.with_normals:
            self.norm[:] = self.normal_host.numpy()
        return self.world

    def write(self, origin: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Map the skin into the mesh frame of a geom at (origin (3,), rot (3, 3)) now; returns the
        world positions (n, 3) float64 (m). Raises ValueError if they are not finite."""
        d, n = self.device, self.n
        self.set_frame(origin, rot)
        if d.is_cpu:  # the kernels write MuJoCo's mesh directly: check before launching them
            self.world[:] = self.x.numpy()[:n]
            _check_finite(self.world)
        if self._ops is None:
            self._ops = self.device_ops()
        for op in self._ops:
            op()
        if d.is_cpu:
            return self.world
        wp.synchronize_device(d)  # one sync for the three copies; MuJoCo's mesh is written after the check
        return self.finish()


def _check_finite(world: np.ndarray) -> None:
    if not np.all(np.isfinite(world)):
        raise ValueError("skin vertices hold non-finite values")
