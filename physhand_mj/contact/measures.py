"""The contact's two penetration measures (DESIGN.md, Metrics), a :class:`ContactMeasures` that
:class:`~physhand_mj.contact.contact.Contact` holds (``Contact.measures``): skin samples on an
order-L lattice inside objects, and object surface points inside the closed skin (the contact's own
feature points, or the denser :attr:`~ContactMeasures.check_points` it never uses), recorded into a
frame or run at once.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.data import MetricsBuffers
from physhand_mj.contact.inside import (ObjectPoints, keep_points, keep_poses, object_points_inside,
                                        object_points_inside_reuse, reset_patches, skin_patches)
from physhand_mj.contact import metrics
from physhand_mj.launch import Recorder
from physhand_mj.contact.metrics import lattice_phi, penetration_cull, penetration_samples, reduce_worlds

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

# the independent check's object points (ContactMeasures.check_points): each edge piece that holds a feature
# point (Config.tuning.feature_spacing long) cut in CHECK_EDGE_SUBDIVIDE (a count; even, so no check point is
# a feature point; surface rings of revolution shifted half a step off the cone's slant line), the
# surface every CHECK_SURFACE_SPACING m (half the measure's 1 mm)
CHECK_EDGE_SUBDIVIDE = 4  # check points: each feature point's piece of edge cut in 4 (even: none coincides)
assert CHECK_EDGE_SUBDIVIDE % 2 == 0
CHECK_SURFACE_SPACING = 5.0e-4
# the most check points made at once (count; ~28 bytes each on the device): a batch measures more in
# pieces of whole worlds (ContactMeasures.measure_worlds)
CHECK_POINTS_AT_ONCE = 50_000_000


class ContactMeasures:
    """Both measures of a contact's skin against its objects. Owns the measures' rows
    (:class:`~physhand_mj.contact.data.MetricsBuffers`, ``rows``), the check points, the skin
    measure's culled list and Config.execution.reuse_outside's memory; reads the model, the objects,
    the config, the world layout and the contact's :class:`~physhand_mj.contact.query_space.QuerySpace`
    (``space``: the skin volume and the queries' poses). The object side's default points are the
    contact's own (``Contact.points``), passed in by the caller."""

    def __init__(self, model, objects, config, rows: MetricsBuffers, space, *, n_tris: int, worlds: int,
                 tris_per_world: int, geoms_per_world: int, closed_skin: bool):
        self.model, self.objects, self.config, self.rows, self.space = model, objects, config, rows, space
        self.n_tris, self.worlds = n_tris, worlds
        self.tris_per_world, self.geoms_per_world = tris_per_world, geoms_per_world
        self.closed_skin = closed_skin
        self._check_points = None  # the denser check set (check_points), built on first use
        self._check_shapes = {}  # the check points' sampled shapes, shared by every piece (ObjectPoints.shapes)
        self.reuse_memory = {}  # Config.execution.reuse_outside's per (points, skin volume) memory (_Reuse)
        self._lists = {}  # the skin measure's kept triangles and count, culled or not (_penetration_list)
        # the skin measure culls its triangles into a list first for batched worlds (cull_measure)
        self._cull_measure = worlds > 1

    @property
    def check_points(self) -> ObjectPoints:
        """A denser set of object surface points that the contact never uses: edges every
        Config.tuning.feature_spacing / CHECK_EDGE_SUBDIVIDE (each piece that holds a feature point at its
        midpoint cut in 4: none of their points), the surface every CHECK_SURFACE_SPACING. The
        independent check of the second measure (the feature push works on Contact.points' corners and edges, so
        a measure on those same points would share the method's own samples)."""
        if self._check_points is None:
            self._check_points = self.check_piece(None)
        return self._check_points

    def record_metrics(self, rec, state, row: int, points: ObjectPoints | None, obj: int = -1, out=None,
                       objects_side: bool = True, order: int = 5, skin_side: bool = True,
                       reuse: bool | None = None):
        """Both penetration measures of ``state`` into row ``row`` of ``out`` (default the frame's
        metrics, ``rows.metrics``): skin samples on the order-``order`` lattice inside objects (columns
        0-2; unless not ``skin_side``) and, with ``objects_side``, object surface points inside the
        closed skin (columns 3-5; ``points``: the contact's own, Contact.points, or the check points;
        ``reuse``: ask only what could have changed since the last measure of the same points, default
        Config.execution.reuse_outside). ``obj`` >= 0: that object only. No skin triangles: nothing."""
        m, o = self.model, self.objects
        out = self.rows.metrics if out is None else out
        if not self.n_tris:
            return
        per = out.shape[0] // self.worlds  # rows per world (world w's row ``row`` is w per + row)
        if skin_side:
            self._record_skin_side(rec, state, row, obj, out, order, per)
        pts = points
        if objects_side and self.closed_skin and len(pts):
            vol = self.space.volume(state)
            rec.ops += vol.ops()
            qpose = self.space.record_pose(rec)
            if not (self.config.reuse_outside if reuse is None else reuse):
                rec.launch(object_points_inside, len(pts),
                           [vol.mesh.id, vol.box, pts.pts, pts.geom, qpose, *[None] * 5, 0, o.count, o.obj, obj, row,
                            self.geoms_per_world, per], [out, pts.depth, None])
                return
            r = self._reuse(pts, vol, qpose)  # (Config.execution.reuse_outside: ask only what could have changed)
            bodies = r.motion.shape[0] // self.worlds  # skin patches a world: one per bone
            rec.launch(reset_patches, r.motion.shape[0], [], [r.motion, r.lower, r.upper])
            rec.launch(skin_patches, m.skin_faces.shape[0],
                       [vol.points, r.prev_x, m.skin_faces, vol.points.shape[0] // self.worlds, m.skin_body, bodies],
                       [r.motion, r.lower, r.upper])
            rec.launch(keep_points, vol.points.shape[0], [vol.points], [r.prev_x])
            rec.launch(object_points_inside_reuse, len(pts),
                       [vol.mesh.id, vol.box, pts.pts, pts.geom, qpose, r.prev_pose, pts.geom_radius, r.motion,
                        r.lower, r.upper, bodies, o.count, o.obj, obj, row, self.geoms_per_world, per],
                       [out, pts.depth, r.slack])
            rec.launch(keep_poses, qpose.shape[0], [qpose], [r.prev_pose])

    def _record_skin_side(self, rec, state, row, obj, out, order, per):
        """The skin measure: samples of the order-``order`` lattice inside objects (columns 0-2)."""
        m, o = self.model, self.objects
        culled = obj < 0 and self.cull_measure
        listed, count = self._penetration_list(culled)
        args = [m.skin_faces, state.x, o.geoms, self.geoms_per_world, obj, row, order, self.tris_per_world, per, listed,
                count, metrics.SKIP_MARGIN]
        if culled:  # the triangles near an object first, then a thread per kept triangle
            rec.ops.append(count.zero_)
            rec.launch(penetration_cull, self.n_tris, args, [out])
        rec.launch(penetration_samples, self.n_tris, args, [out])

    @property
    def cull_measure(self) -> bool:
        """Whether the skin measure culls its triangles into a list first (:func:`penetration_cull`):
        for batched worlds, where ~5 % of the triangles are near an object (H100, the bowl at W =
        1,024: 76.6 -> 13.3 ms a frame). One hand keeps the one-kernel layout, as measured there."""
        return self._cull_measure

    @cull_measure.setter
    def cull_measure(self, on: bool) -> None:
        self._cull_measure = bool(on)

    def _penetration_list(self, culled: bool):
        """The skin measure's kept triangles and their count (made on first use, shared by every
        measure: they run one after another); not culled: empty arrays (every triangle asks)."""
        if culled not in self._lists:
            d, n = self.model.device, self.n_tris if culled else 0
            self._lists[culled] = (wp.zeros(n, dtype=int, device=d), wp.zeros(int(culled), dtype=int, device=d))
        return self._lists[culled]

    def _reuse(self, pts: ObjectPoints, vol, pose) -> "_Reuse":
        """The object-side measure's memory for ``pts`` against the skin volume ``vol`` (made on first
        use: every point is asked the first time)."""
        key = (id(pts), id(vol))
        if key not in self.reuse_memory:
            bodies = max(int(self.model.n_bodies) // self.worlds, 1)
            self.reuse_memory[key] = _Reuse(len(pts), vol.points.shape[0], pose.shape[0], self.worlds * bodies,
                                            self.model.device)
        return self.reuse_memory[key]

    def measure(self, state, points: ObjectPoints | None, obj: int = -1, order: int = 5,
                objects_side: bool = True, check: bool = False) -> np.ndarray:
        """Both measures of ``state`` now (see :meth:`record_metrics`) as a (6,) float row: [count,
        sum depth m, max depth m] of skin samples inside objects, then of object points inside the
        skin (``points``: the contact's own; ``check``: the denser :attr:`check_points` instead). Runs
        at once, outside any frame (reports, pictures, checks)."""
        return reduce_worlds(self.measure_worlds(state, points, obj, order, objects_side, check))

    def measure_worlds(self, state, points: ObjectPoints | None, obj: int = -1, order: int = 5,
                       objects_side: bool = True, check: bool = False) -> np.ndarray:
        """:meth:`measure` per world: (W, 6) float rows, world w's skin against world w's objects
        (batched worlds, physhand_mj/batch.py; one world: (1, 6))."""
        out = wp.zeros((self.worlds, 6), dtype=float, device=self.model.device)
        rec = Recorder(self.model.device)
        check = check and objects_side
        pieces = self.check_pieces() if check else None
        if pieces is None:
            self.record_metrics(rec, state, 0, self.check_points if check else points, obj=obj, out=out,
                                objects_side=objects_side, order=order)
        else:  # the check points a few worlds at a time, each piece made, asked and dropped (not kept)
            self.record_metrics(rec, state, 0, points, obj=obj, out=out, objects_side=False, order=order)
        rec.run()
        for geoms in pieces or ():
            pts = self.check_piece(geoms)
            self.record_metrics(rec, state, 0, pts, obj=obj, out=out, skin_side=False, reuse=False)
            rec.run()  # (ops dropped as run: a launch kept would hold this piece's arrays while the next is made)
            del pts
        return out.numpy().astype(float)

    def check_pieces(self) -> list | None:
        """None when :attr:`check_points` fit at once (at most CHECK_POINTS_AT_ONCE points), else the
        geom ranges of the pieces they are measured in (whole worlds each). A batch's check points are
        W copies of each object's: the HOI bowl has 212,271, so W = 4,096 would hold 870 million."""
        if self._check_points is not None:
            return None
        gpw, n = self.geoms_per_world, len(self.objects.names)
        shapes = self._check_shapes
        keys = ObjectPoints.shapes(self.objects, range(n), shapes, *self._check_spacing())
        per_geom = [len(shapes[k][0]) for k in keys]
        per_world = [sum(per_geom[w * gpw:(w + 1) * gpw]) for w in range(self.worlds)]
        if sum(per_world) <= CHECK_POINTS_AT_ONCE:
            return None
        pieces, start, held = [], 0, 0  # whole worlds a piece, each piece at most the limit (or one world)
        for w, c in enumerate(per_world):
            if held and held + c > CHECK_POINTS_AT_ONCE:
                pieces.append(range(start * gpw, min(w * gpw, n)))
                start, held = w, 0
            held += c
        pieces.append(range(start * gpw, n))
        return [p for p in pieces if len(p)]

    def forget(self) -> None:
        """Drop the check points and the reuse memory (their device memory; made again on use, when
        every point is asked again once)."""
        self._check_points = None
        self.reuse_memory.clear()

    def _check_spacing(self) -> tuple:
        """The check points' (edge spacing m, surface spacing m, edge subdivision) for ObjectPoints."""
        return self.config.feature_spacing, CHECK_SURFACE_SPACING, CHECK_EDGE_SUBDIVIDE

    def check_piece(self, geoms) -> ObjectPoints:
        """:attr:`check_points` of ``geoms`` alone (None: all; the shapes sampled once, shared)."""
        e, s, k = self._check_spacing()
        return ObjectPoints(self.objects, edge_spacing=e, surface_spacing=s, edge_subdivide=k, geoms=geoms,
                            shapes=self._check_shapes)

    def object_points_inside(self, state, points: ObjectPoints) -> tuple[np.ndarray, np.ndarray]:
        """The object surface points ``points`` (the contact's own) inside the skin of ``state`` now:
        world points (k, 3) m and their depths (k,) m (distance to the closest skin point), for
        pictures and checks."""
        pts = points
        if not len(pts):
            return np.zeros((0, 3)), np.zeros(0)
        self.measure(state, pts)  # fills pts.depth
        depth = pts.depth.numpy()[: len(pts)].astype(float)
        hit = np.flatnonzero(depth > 0)
        pose = self.objects._host["pose"][pts.geom_host[hit]].astype(float)  # [p, q x y z w]
        from physhand_mj.rotations import quat_to_mat

        rot = quat_to_mat(np.concatenate([pose[:, 6:], pose[:, 3:6]], axis=1)).reshape(-1, 3, 3)
        world = np.einsum("kij,kj->ki", rot, pts.pts_host[hit]) + pose[:, :3]
        return world.reshape(-1, 3), depth[hit]

    def penetrating_samples(self, state, order: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """The skin samples on the order-``order`` lattice inside objects now: world points (k, 3) m
        and their depths (k,) m (for pictures and checks)."""
        m, o, d = self.model, self.objects, self.model.device
        f = self.n_tris
        if not f:
            return np.zeros((0, 3)), np.zeros(0)
        k = (order + 1) * (order + 2) // 2
        pts = wp.zeros((f, k), dtype=wp.vec3, device=d)
        phi = wp.zeros((f, k), dtype=float, device=d)
        wp.launch(lattice_phi, f, inputs=[m.skin_faces, state.x, o.geoms, self.tris_per_world, self.geoms_per_world,
                                          order],
                  outputs=[pts, phi], device=d)
        p, s = pts.numpy().reshape(-1, 3), phi.numpy().ravel()
        inside = s < 0
        return p[inside].astype(float), -s[inside].astype(float)

    def copy_rows(self) -> None:
        """Start the rows' device-to-host copy (Contact.copy_metrics; the caller synchronises)."""
        wp.copy(self.rows.metrics_host, self.rows.metrics)

    def read_metrics(self) -> np.ndarray:
        """(substeps + 1, 6): per row [count, sum depth m, max depth m] of skin samples inside objects,
        then of object points inside the skin; the last row is the frame's end (the host copy as
        the last frame's sync left it). Rows of substeps are zero unless Config.substep_metrics (and
        their object columns are always zero: the second measure runs at the frame's end)."""
        return reduce_worlds(self.read_metrics_worlds()).copy()

    def read_metrics_worlds(self) -> np.ndarray:
        """:meth:`read_metrics` per world: (W, substeps + 1, 6) (batched worlds; one world: (1, ...))."""
        return self.rows.metrics_host.numpy().reshape(self.worlds, -1, 6).copy()


class _Reuse:
    """Config.execution.reuse_outside's memory for one set of object points against one skin volume: each
    point's slack (m, 0: ask it), the skin points and the geom poses when last measured, and per skin
    patch (a world's skin triangles whose first corner is on one bone) its motion since and its box
    (inside.object_points_inside_reuse)."""

    def __init__(self, n_points: int, n_skin: int, n_geoms: int, patches: int, device):
        self.slack = wp.zeros(max(n_points, 1), dtype=float, device=device)
        self.prev_x = wp.zeros(n_skin, dtype=wp.vec3, device=device)
        self.prev_pose = wp.zeros(max(n_geoms, 1), dtype=wp.transform, device=device)
        self.motion = wp.zeros(patches, dtype=float, device=device)
        self.lower = wp.zeros(patches, dtype=wp.vec3, device=device)
        self.upper = wp.zeros(patches, dtype=wp.vec3, device=device)
