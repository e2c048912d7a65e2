"""Batched worlds: W hands advanced by one solver step (issue 15, first part: no contact yet).

W copies of one asset become one body with W disconnected components (``replicate_asset``): the
skins of all worlds first (the solver's layout: skin vertices lead), then every world's flesh and
skeleton; bodies ``name#w``. Every solver kernel is element-parallel over vertices and constraints,
so the replicated model runs through the unchanged :class:`~physhand_mj.solver.Solver`: one
frame of W hands is one recorded frame (one CUDA graph on a GPU), its launches W times wider, like
Newton's replicated builders and mujoco_warp's ``nworld``. Worlds never interact (no constraint
crosses them; contact is not batched yet).

:class:`BatchedHands` keeps the per-world views: bone poses in per world, skins out per world.
Per-world recovery is per vertex already (``integrate.advance`` resets a non-finite vertex to its
last position), but the frame's guard counts are summed over worlds. Not built yet: objects and
contact per world, per-world metrics and guards, ``physhand rollout --batch``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from physhand_mj.types import Layer


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
    """W hands of one asset in one solver (no contact): ``step(pos, quat)`` with bone poses
    (W, B, 3) m and (W, B, 4) w x y z per world advances all W by one frame."""

    def __init__(self, asset, worlds: int, config=None, pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0)):
        from physhand_mj.solver import Solver, make_model
        from physhand_mj.types import Config

        self.asset, self.worlds = asset, int(worlds)
        self.config = config if config is not None else Config()
        self.replicated = replicate_asset(asset, self.worlds)
        self.solver = Solver(make_model(self.replicated, self.config), self.config)
        self.state = self.solver.make_state(pos, quat)
        self.n_bodies = len(asset.body_names)

    def step(self, pos: np.ndarray, quat: np.ndarray) -> dict:
        """One frame of every world: bone poses at its end, ``pos`` (W, B, 3) m, ``quat`` (W, B, 4)
        w x y z, bodies ordered as ``asset.body_names``. Returns the solver's frame dict (summed over
        worlds)."""
        pos, quat = np.asarray(pos, float), np.asarray(quat, float)
        want = (self.worlds, self.n_bodies)
        if pos.shape != want + (3,) or quat.shape != want + (4,):
            raise ValueError(f"bone poses must be {want + (3,)} positions and {want + (4,)} quaternions, "
                             f"got {pos.shape} and {quat.shape}")
        self.solver.set_body_poses(self.state, pos.reshape(-1, 3), quat.reshape(-1, 4))
        return self.solver.step(self.state)

    def skin(self, world: int) -> np.ndarray:
        """(n_skin, 3) skin positions (m) of one world."""
        ns = self.asset.n_skin
        return self.state.x.numpy()[world * ns:(world + 1) * ns]

    def positions(self, world: int) -> np.ndarray:
        """(N, 3) all positions (m) of one world, in the asset's vertex order."""
        n, ns = self.asset.n_vertices, self.asset.n_skin
        x = self.state.x.numpy()
        rest = self.worlds * ns + world * (n - ns)
        return np.concatenate([x[world * ns:(world + 1) * ns], x[rest:rest + n - ns]])
