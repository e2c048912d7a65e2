"""Where the object side's queries run: the closed skin as meshes, and batched worlds queried apart.

Batched worlds (physhand_mj/batch.py) are solved at one origin, but the object side's queries (the
feature lists and pushes, the object points inside the skin) need each world's skin and geoms apart:
:meth:`QuerySpace.set_offsets` moves them per world, the skin meshes (:class:`SkinVolume`) hold the
shifted skin and the query poses the shifted geoms. A :class:`~physhand_mj.contact.contact.Contact`
holds one (``Contact.space``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.inside import SkinVolume, shift_poses


class QuerySpace:
    """The skin meshes and poses the object side queries (shifted per world where asked), of a
    solver ``model``'s skin against ``objects`` in ``worlds`` batched worlds of
    ``geoms_per_world`` geoms each."""

    def __init__(self, model, objects, worlds: int, geoms_per_world: int):
        self.model, self.objects = model, objects
        self.worlds, self.geoms_per_world = worlds, geoms_per_world
        self.volumes: dict = {}  # SkinVolume per (state's x, winding) (its mesh's points: the state's skin)
        # set_offsets: (n_skin,) vec3 m, each skin vertex's world offset; (W,) vec3 m, the worlds';
        # (capacity,) transform, the geoms' poses moved by them (None: not queried apart)
        self.shift = self.offsets = self.poses = None
        self.no_shift = wp.zeros(0, dtype=wp.vec3, device=model.device)  # (apply_contact's, unshifted)

    def volume(self, state, winding: bool = True) -> SkinVolume:
        """The closed skin of ``state`` as a mesh, with winding-number data or not (made on first use;
        shifted per world where :meth:`set_offsets` asked)."""
        key = (id(state.x), winding)
        v = self.volumes.get(key)
        if v is None:
            v = self.volumes[key] = SkinVolume(state.x, self.model.n_skin, self.model.skin_faces, winding,
                                               shift=self.shift, worlds=self.worlds)
        return v

    def set_offsets(self, offsets) -> None:
        """Batched worlds (physhand_mj/batch.py) solved at one origin: the object side's queries (the
        feature lists and pushes, the object points inside the skin) run on the skin and the geoms
        moved by ``offsets`` (W, 3) m per world, so they stay in their world (every such query is
        distance-limited, to well under the offsets' spacing) while the solve stays at the origin.
        Call before the first step or measure."""
        off = np.asarray(offsets, np.float32).reshape(self.worlds, 3)
        if self.volumes:
            raise RuntimeError("set_query_offsets must come before the first step or measure")
        if not np.any(off):
            return
        d = self.model.device
        world = self.model.vertex_world.numpy()[: self.model.n_skin]
        self.shift = wp.array(off[world], dtype=wp.vec3, device=d)
        self.offsets = wp.array(off, dtype=wp.vec3, device=d)
        self.poses = wp.zeros(self.objects.capacity, dtype=wp.transform, device=d)

    def record_pose(self, rec):
        """The geoms' poses for the object side's queries (moved per world by the query offsets:
        recorded into ``rec``)."""
        if self.poses is None:
            return self.objects.pose
        rec.launch(shift_poses, self.poses.shape[0], [self.objects.pose, self.offsets, self.geoms_per_world],
                   [self.poses])
        return self.poses

    @property
    def pose(self):
        """The poses the object side queries with (set once per frame by :meth:`record_pose`)."""
        return self.objects.pose if self.poses is None else self.poses

    def skin_x(self, state):
        """Skin positions as the object side's meshes hold them (shifted per world, or state.x)."""
        return state.x if self.shift is None else self.volume(state, winding=False).points

    def refit_op(self, vol: SkinVolume, count):
        """An op syncing ``vol``'s points (where shifted) and refitting its BVH; on the CPU only when
        ``count`` (a (1,) int array, e.g. the frame's feature list length) is non-zero (free to read there)."""
        ops = vol.refit_ops()
        if wp.get_device(self.model.device).is_cuda:
            return ops[0] if len(ops) == 1 else (lambda: [op() for op in ops])
        count = count.numpy()
        return lambda: [op() for op in ops] if count[0] else None

    def apply_shift(self, state) -> tuple:
        """apply_contact's (shift, shifted copy): batched worlds queried apart keep the object side's
        copy of the skin (set_offsets) current vertex by vertex; else two empty arrays."""
        if self.shift is None:
            return self.no_shift, self.no_shift
        return self.shift, self.volume(state, winding=False).points
