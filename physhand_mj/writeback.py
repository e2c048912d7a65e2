"""Skin write-back in Warp: solver positions -> the MuJoCo skin mesh (vertices and normals).

MuJoCo stores a mesh in its own frame and places it with the geom pose, so each world vertex goes
back through the geom's pose; vertex normals are the area-weighted sums of the face normals
(MuJoCo indexes normals per vertex when the mesh has one normal per vertex). On the CPU the kernels
write straight into ``model.mesh_vert`` / ``mesh_normal`` (Warp arrays over MuJoCo's memory); on
CUDA they write device buffers that come back through pinned host memory in one copy each.
"""

from __future__ import annotations

import numpy as np
import warp as wp


@wp.kernel
def to_mesh_frame(x: wp.array(dtype=wp.vec3), origin: wp.vec3, rot: wp.mat33, local: wp.array(dtype=wp.vec3),
                  normal: wp.array(dtype=wp.vec3)):
    """local_i = R^T (x_i - origin); clears the normal accumulator."""
    i = wp.tid()
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

    def write(self, origin: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Map the skin into the mesh frame of a geom at (origin (3,), rot (3, 3)); returns the world
        positions (n, 3) float64 (m). Raises ValueError if they are not finite."""
        d, n = self.device, self.n
        if d.is_cpu:  # the kernels write MuJoCo's mesh directly: check before launching them
            self.world[:] = self.x.numpy()[:n]
            _check_finite(self.world)
        else:
            wp.copy(self.x_host, self.x, count=n)
        wp.launch(to_mesh_frame, n, inputs=[self.x, wp.vec3(*origin), wp.mat33(*np.asarray(rot).ravel())],
                  outputs=[self.local, self.normal], device=d)
        if self.with_normals:
            wp.launch(accumulate_normals, self.faces.shape[0], inputs=[self.faces, self.local], outputs=[self.normal],
                      device=d)
            wp.launch(normalize, n, inputs=[self.normal], device=d)
        if not d.is_cpu:  # one sync for the three copies; MuJoCo's mesh is written after the check
            wp.copy(self.local_host, self.local)
            if self.with_normals:
                wp.copy(self.normal_host, self.normal)
            wp.synchronize_device(d)
            self.world[:] = self.x_host.numpy()
            _check_finite(self.world)
            self.vert[:] = self.local_host.numpy()
            if self.with_normals:
                self.norm[:] = self.normal_host.numpy()
        return self.world


def _check_finite(world: np.ndarray) -> None:
    if not np.all(np.isfinite(world)):
        raise ValueError("skin vertices hold non-finite values")
