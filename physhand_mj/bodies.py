"""Layered soft bodies from plain arrays: the general form of the hand asset.

:func:`soft_body` derives everything the solver needs (edges, rest lengths and volumes, lumped
masses, flesh attachments, skin dihedral pairs) from positions and topology, so a tet mesh around
robot-finger links, a cloth-like sheet (the paper's cone experiment) or a single tet in a test use
the same :class:`~physhand_mj.asset.HandAsset` as the embedded hand.
"""

from __future__ import annotations

import numpy as np

from physhand_mj.asset import HandAsset, validate_asset
from physhand_mj.build import derive
from physhand_mj.types import Layer


def soft_body(positions, *, skin_faces=None, tets=None, edges=None, layer=None, vertex_body=None,
              body_names=(), body_rest_pos=None, body_rest_quat=None, density: float = 1100.0,
              vertex_mass=None, name: str = "soft body") -> HandAsset:
    """A validated layered body.

    Args:
      positions: (N, 3) rest positions (m), ordered skin, flesh, skeleton.
      skin_faces: (F, 3) outward skin triangles (their pairs get Eq. 6); None for no skin surface.
      tets: (T, 4) tetrahedra (reoriented to positive volume); None for a surface-only body.
      edges: (E, 2) extra edges; the body's edges are these plus every tet edge and skin-triangle edge.
      layer: (N,) :class:`Layer` labels; default all SKIN.
      vertex_body: (N,) body index of skeleton vertices (-1 elsewhere); body_names: (B,) names;
        body_rest_pos (B, 3) m and body_rest_quat (B, 4) w x y z: bodies' poses at rest.
      density: kg/m^3 for tet-lumped masses; vertex_mass: (N,) kg or a scalar, overrides density
        (needed for a body without tets).
    Raises:
      AssetError (via validate_asset) for inconsistent input, ValueError for missing masses.
    """
    x = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    n = len(x)
    layer = np.full(n, Layer.SKIN, np.int8) if layer is None else np.asarray(layer, np.int8)
    faces = np.zeros((0, 3), np.int32) if skin_faces is None else np.asarray(skin_faces, np.int32).reshape(-1, 3)
    t = np.zeros((0, 4), np.int32) if tets is None else derive.orient_tets(x, np.asarray(tets, np.int32).reshape(-1, 4))
    pairs = [derive.tet_edges(t), faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)]
    if edges is not None:
        pairs.append(np.asarray(edges).reshape(-1, 2))
    e = np.unique(np.sort(np.concatenate(pairs).astype(np.int32), axis=1), axis=0)
    if vertex_mass is not None:
        mass = np.broadcast_to(np.asarray(vertex_mass, float), (n,)).copy()
    elif len(t):
        mass = derive.lumped_masses(x, t, density)
    else:
        raise ValueError("a body without tets needs vertex_mass (kg per vertex)")
    skel = np.flatnonzero(layer == Layer.SKELETON)
    movable = np.flatnonzero(layer != Layer.SKELETON)
    attach = derive.nearest_skeleton_pairs(x, movable, skel) if len(skel) else np.zeros((0, 2), np.int32)
    quads, angles = derive.dihedral_pairs(x, faces) if len(faces) else (np.zeros((0, 4), np.int32), np.zeros(0))
    nb = len(body_names)
    asset = HandAsset(
        positions=x, layer=layer, skin_faces=faces, tets=t, tet_rest_volume=derive.tet_signed_volumes(x, t),
        edges=e, edge_rest_length=np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1), mass=mass,
        density=float(density), attach=attach,
        attach_rest_length=np.linalg.norm(x[attach[:, 0]] - x[attach[:, 1]], axis=1),
        dihedral=quads, dihedral_rest_angle=angles, bone_faces=np.zeros((0, 3), np.int32),
        body_names=np.asarray(body_names, dtype="U32").reshape(nb),
        vertex_body=np.full(n, -1, np.int32) if vertex_body is None else np.asarray(vertex_body, np.int32),
        body_rest_pos=np.zeros((nb, 3)) if body_rest_pos is None else np.asarray(body_rest_pos, float).reshape(nb, 3),
        body_rest_quat=(np.tile([1.0, 0, 0, 0], (nb, 1)) if body_rest_quat is None
                        else np.asarray(body_rest_quat, float).reshape(nb, 4)),
        rest_qpos_names=np.zeros(0, dtype="U16"), rest_qpos=np.zeros(0), meta=dict(name=name),
    )
    validate_asset(asset, name)
    return asset


def sheet(nx: int, ny: int, spacing: float, *, height: float = 0.0, areal_density: float = 0.1,
          name: str = "sheet") -> HandAsset:
    """A flat triangle sheet of nx x ny vertices (spacing m) centred on the z axis at ``height`` (m),
    skin layer only (edges and dihedral pairs, no tets), mass from ``areal_density`` (kg/m^2).
    Diagonals alternate so the sheet has no preferred shear direction."""
    if nx < 2 or ny < 2 or not spacing > 0:
        raise ValueError("a sheet needs nx, ny >= 2 and spacing > 0 (m)")
    xs = (np.arange(nx) - (nx - 1) / 2) * spacing
    ys = (np.arange(ny) - (ny - 1) / 2) * spacing
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pos = np.stack([gx.ravel(), gy.ravel(), np.full(nx * ny, float(height))], axis=1)
    faces = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = i * ny + j, (i + 1) * ny + j, (i + 1) * ny + j + 1, i * ny + j + 1
            faces += [[a, b, c], [a, c, d]] if (i + j) % 2 == 0 else [[a, b, d], [b, c, d]]
    mass = areal_density * (spacing * (nx - 1)) * (spacing * (ny - 1)) / (nx * ny)
    return soft_body(pos, skin_faces=faces, vertex_mass=mass, name=name)
