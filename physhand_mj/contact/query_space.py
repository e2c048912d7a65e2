"""Where the object side's queries run: the closed skin as meshes, and batched worlds queried apart.

Batched worlds (physhand_mj/batch.py) are solved at one origin, but the object side's queries (the
feature lists and pushes, the object points inside the skin) need each world's skin and geoms apart:
:meth:`QuerySpace.set_query_offsets` moves them per world, the skin meshes (:class:`SkinVolume`) hold
the shifted skin and the query poses the shifted geoms. :class:`QuerySpace` is a mixin of
:class:`~physhand_mj.contact.contact.Contact` (which owns the model, objects, config, the world layout,
``_volumes``, ``query_shift``, ``_qoff``, ``_qpose``, ``_no_shift`` and ``feat_count``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.inside import SkinVolume, shift_poses


class QuerySpace:
    """The skin meshes and poses the object side queries (shifted per world where asked)."""

    def volume(self, state, winding: bool = True) -> SkinVolume:
        """The closed skin of ``state`` as a mesh, with winding-number data or not (made on first use;
        shifted per world where :meth:`set_query_offsets` asked)."""
        key = (id(state.x), winding)
        v = self._volumes.get(key)
        if v is None:
            v = self._volumes[key] = SkinVolume(state.x, self.model.n_skin, self.model.skin_faces, winding,
                                                shift=self.query_shift, worlds=self.worlds)
        return v

    def set_query_offsets(self, offsets) -> None:
        """Batched worlds (physhand_mj/batch.py) solved at one origin: the object side's queries (the
        feature lists and pushes, the object points inside the skin) run on the skin and the geoms
        moved by ``offsets`` (W, 3) m per world, so they stay in their world (every such query is
        distance-limited, to well under the offsets' spacing) while the solve stays at the origin.
        Call before the first step or measure."""
        off = np.asarray(offsets, np.float32).reshape(self.worlds, 3)
        if self._volumes:
            raise RuntimeError("set_query_offsets must come before the first step or measure")
        if not np.any(off):
            return
        d = self.model.device
        world = self.model.vertex_world.numpy()[: self.model.n_skin]
        self.query_shift = wp.array(off[world], dtype=wp.vec3, device=d)
        self._qoff = wp.array(off, dtype=wp.vec3, device=d)
        self._qpose = wp.zeros(self.objects.capacity, dtype=wp.transform, device=d)

    def _query_pose(self, rec):
        """The geoms' poses for the object side's queries (moved per world by the query offsets)."""
        if self._qpose is None:
            return self.objects.pose
        rec.launch(shift_poses, self._qpose.shape[0], [self.objects.pose, self._qoff, self.geoms_per_world], [self._qpose])
        return self._qpose

    @property
    def _qp(self):
        """The poses the object side queries with (set once per frame by :meth:`_query_pose`)."""
        return self.objects.pose if self._qpose is None else self._qpose

    def _query_x(self, state):
        """Skin positions as the object side's meshes hold them (shifted per world, or state.x)."""
        return state.x if self.query_shift is None else self.volume(state, winding=False).points

    def _refit_op(self, vol: SkinVolume, count=None):
        """An op syncing ``vol``'s points (where shifted) and refitting its BVH; on the CPU only when
        ``count`` (default: the frame's feature list length) is non-zero (free to read there)."""
        ops = vol.refit_ops()
        if wp.get_device(self.model.device).is_cuda:
            return ops[0] if len(rec.ops) == 1 else (lambda: [op() for op in ops])
        count = (self.feat_count if count is None else count).numpy()
        return lambda: [op() for op in ops] if count[0] else None

    def _apply_shift(self, state) -> tuple:
        """apply_contact's (shift, shifted copy): batched worlds queried apart keep the object side's
        copy of the skin (set_query_offsets) current vertex by vertex; else two empty arrays."""
        if self.query_shift is None:
            return self._no_shift, self._no_shift
        return self.query_shift, self.volume(state, winding=False).points
