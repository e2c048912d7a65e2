"""Batched worlds: W hands advanced by one solver step (issue 15, first part).

W copies of one asset become one body with W disconnected components (``replicate_asset``): the
skins of all worlds first (the solver's layout: skin vertices lead), then every world's flesh and
skeleton; bodies ``name#w``. Every solver kernel is element-parallel over vertices and constraints,
so the replicated model runs through the unchanged :class:`~physhand_mj.solver.Solver`: one
frame of W hands is one recorded frame (one CUDA graph on a GPU), its launches W times wider, like
Newton's replicated builders and mujoco_warp's ``nworld``. Worlds never interact: no constraint
crosses them, and each world is solved at its own place in space (``BatchedHands.offsets``), far
enough apart that no distance-limited contact query reaches another world.

:class:`BatchedHands` keeps the per-world views: bone poses in per world, skins out per world.
Per-world recovery is per vertex already (``integrate.advance`` resets a non-finite vertex to its
last position), but the frame's guard counts and penetration summary are summed over worlds. Not
built yet: per-world metrics and guards, a world-indexed broadphase for thousands of worlds,
``physhand rollout --batch``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from physhand_mj.types import Layer


def vertex_world(n: int, n_skin: int, worlds: int) -> np.ndarray:
    """World of every vertex of a replicated body of ``n`` vertices (``n_skin`` skin) holding
    ``worlds`` copies: the skins first, world by world, then the rest, world by world."""
    ns, per = n_skin // worlds, (n - n_skin) // worlds
    i = np.arange(n)
    return np.where(i < n_skin, i // max(ns, 1), (i - n_skin) // max(per, 1))


def replicate_asset(asset, worlds: int):
    """``worlds`` disconnected copies of ``asset`` as one asset: all skins first (world 0's, then
    world 1's, ...), then each world's other vertices; every index array remapped, bodies
    ``name#w``. World w's skin is vertices [w n_skin, (w + 1) n_skin)."""
    if not (isinstance(worlds, (int, np.integer)) and worlds >= 1):
        raise ValueError(f"worlds must be an integer >= 1, got {worlds!r}")
    n, ns, nb = asset.n_vertices, asset.n_skin, len(asset.body_names)
    if not np.all(asset.layer[:ns] == Layer.SKIN):
        raise ValueError("asset: skin vertices must come first (layer SKIN for vertices [0, n_skin))")
    w = np.arange(worlds)[:, None]
    i = np.arange(n)[None, :]
    new = np.where(i < ns, w * ns + i, worlds * ns + w * (n - ns) + (i - ns))  # (W, N): old -> new index
    order = np.empty(worlds * n, np.int64)
    order[new.ravel()] = np.arange(worlds * n)  # new index -> (world, old index) flattened

    def per_vertex(a):
        return np.asarray(a)[order % n]

    def indices(a):
        a = np.asarray(a)
        return np.concatenate([new[k][a] for k in range(worlds)]).astype(a.dtype)

    def tiled(a):
        return np.concatenate([np.asarray(a)] * worlds)

    vb = np.asarray(asset.vertex_body)
    body = per_vertex(vb)
    body = np.where(body >= 0, body + (order // n) * nb, -1).astype(vb.dtype)
    return dataclasses.replace(
        asset,
        positions=per_vertex(asset.positions), layer=per_vertex(asset.layer), mass=per_vertex(asset.mass),
        vertex_body=body, skin_faces=indices(asset.skin_faces), tets=indices(asset.tets),
        tet_rest_volume=tiled(asset.tet_rest_volume), edges=indices(asset.edges),
        edge_rest_length=tiled(asset.edge_rest_length), attach=indices(asset.attach),
        attach_rest_length=tiled(asset.attach_rest_length), dihedral=indices(asset.dihedral),
        dihedral_rest_angle=tiled(asset.dihedral_rest_angle), bone_faces=indices(asset.bone_faces),
        body_names=np.array([f"{b}#{k}" for k in range(worlds) for b in asset.body_names]),
        body_rest_pos=tiled(asset.body_rest_pos), body_rest_quat=tiled(asset.body_rest_quat),
        meta={**asset.meta, "worlds": int(worlds)},
    )


class BatchedHands:
    """W hands of one asset in one solver: ``step(pos, quat)`` with bone poses (W, B, 3) m and
    (W, B, 4) w x y z per world advances all W by one frame.

    ``objects``: the geoms every world holds, as dicts of :meth:`Objects.add`'s arguments (``gtype``,
    ``size``, ``name``; ``vertices``/``faces`` for a mesh); each world gets its own copy, posed by
    ``step(..., object_pos (W, k, 3), object_quat (W, k, 4))``. With objects the worlds are kept
    apart in space: world w's hand and objects are solved shifted by ``offsets[w]`` (a square grid,
    ``spacing`` m apart, default 1 m; every query of the contact is distance-limited to ~1 cm, so
    worlds cannot touch while each world's objects stay within spacing / 2 - 0.15 m of its hand's
    origin); float32 then rounds positions at the offset's scale (a world at 1 m ends ~10 um from
    the same run at the origin after 8 frames: the solver's rounding, not the physics). Without
    objects all worlds share the origin and equal serial runs bit for bit (CPU). Poses in and
    positions out are in each world's own frame. The frame broadphase tests every triangle against
    every world's geoms (a bounding-sphere test each: fine for tens of worlds, not thousands), and
    the frame's penetration summary is summed over worlds.
    """

    def __init__(self, asset, worlds: int, config=None, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0),
                 objects=(), spacing: float | None = None):
        from physhand_mj.contact import Objects
        from physhand_mj.solver import Solver, make_model
        from physhand_mj.types import Config

        self.asset, self.worlds = asset, int(worlds)
        self.config = config if config is not None else Config()
        self.replicated = replicate_asset(asset, self.worlds)
        if spacing is None:  # apart only where contact could reach across (float32 rounds at 1 m)
            spacing = 1.0 if objects else 0.0
        side = int(np.ceil(np.sqrt(self.worlds)))
        k = np.arange(self.worlds)
        self.offsets = np.stack([k % side, k // side, np.zeros(self.worlds)], axis=1) * float(spacing)
        self.objects = None
        self.n_objects = len(objects)
        if objects:
            self.objects = Objects(str(self.config.device or "cpu"), self.worlds * len(objects))
            for w in range(self.worlds):
                for spec in objects:
                    spec = dict(spec)
                    name = f"{spec.pop('name', 'object')}#{w}"
                    self.objects.add(spec.pop("gtype"), spec.pop("size", None), self.offsets[w] + 1e3,
                                     name=name, obj=name, **spec)  # parked far away until step poses them
        self.solver = Solver(make_model(self.replicated, self.config), self.config, objects=self.objects)
        self.state = self.solver.make_state(pos, quat)
        self.n_bodies = len(asset.body_names)
        # shift each world to its place: positions (x, x_prev, x_safe) and the bones' host poses
        world = vertex_world(self.replicated.n_vertices, self.replicated.n_skin, self.worlds)
        shift = self.offsets[world].astype(np.float32)
        import warp as wp

        for name in ("x", "x_prev", "x_safe"):
            arr = getattr(self.state, name)
            arr.assign(wp.array(arr.numpy() + shift, dtype=wp.vec3, device="cpu"))
        body_shift = np.repeat(self.offsets, self.n_bodies, axis=0).astype(np.float32)
        self.state.pose_host[:, :, :3] += body_shift

    def step(self, pos: np.ndarray, quat: np.ndarray, object_pos=None, object_quat=None) -> dict:
        """One frame of every world: bone poses at its end, ``pos`` (W, B, 3) m, ``quat`` (W, B, 4)
        w x y z, bodies ordered as ``asset.body_names``; with objects their poses ``object_pos``
        (W, k, 3) m and ``object_quat`` (W, k, 4) w x y z, in each world's frame. Returns the
        solver's frame dict (summed over worlds)."""
        pos, quat = np.asarray(pos, float), np.asarray(quat, float)
        want = (self.worlds, self.n_bodies)
        if pos.shape != want + (3,) or quat.shape != want + (4,):
            raise ValueError(f"bone poses must be {want + (3,)} positions and {want + (4,)} quaternions, "
                             f"got {pos.shape} and {quat.shape}")
        if self.objects is not None:
            if object_pos is None or object_quat is None:
                raise ValueError(f"object poses are needed: object_pos {(self.worlds, self.n_objects, 3)} m and "
                                 f"object_quat {(self.worlds, self.n_objects, 4)} w x y z")
            op = np.asarray(object_pos, float).reshape(self.worlds, self.n_objects, 3) + self.offsets[:, None]
            self.objects.set_poses(op.reshape(-1, 3), np.asarray(object_quat, float).reshape(-1, 4))
        self.solver.set_body_poses(self.state, (pos + self.offsets[:, None]).reshape(-1, 3), quat.reshape(-1, 4))
        return self.solver.step(self.state)

    def skin(self, world: int) -> np.ndarray:
        """(n_skin, 3) skin positions (m) of one world, in its frame."""
        ns = self.asset.n_skin
        return self.state.x.numpy()[world * ns:(world + 1) * ns] - self.offsets[world].astype(np.float32)

    def positions(self, world: int) -> np.ndarray:
        """(N, 3) all positions (m) of one world, in the asset's vertex order and the world's frame."""
        n, ns = self.asset.n_vertices, self.asset.n_skin
        x = self.state.x.numpy()
        rest = self.worlds * ns + world * (n - ns)
        return np.concatenate([x[world * ns:(world + 1) * ns], x[rest:rest + n - ns]]) - \
            self.offsets[world].astype(np.float32)
