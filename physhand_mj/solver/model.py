"""Build the solver's immutable :class:`~physhand_mj.types.Model` from a layered asset."""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.solver.attach import attachment_pairs
from physhand_mj.solver.coloring import color_ranges, greedy_colors
from physhand_mj.types import Config, Layer, Model, Scheme

FAMILIES = ("edge", "tet", "dih")  # projection order within an iteration (edge includes Eq. 4)
# Jacobi groups: families of one group are projected from the same positions and their corrections
# averaged together (one apply launch per group); groups run one after another. One family per group
# measured best (docs/solver.md): grouping edges with tets saves a launch per substep but made the
# hand visibly softer (slower settling, 2.4 mm left after a grasp and release vs < 2 mm).
JACOBI_GROUPS = (("edge",), ("tet",), ("dih",))


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """(..., 4) MuJoCo quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=float)
    q = q / np.sqrt((q * q).sum(axis=-1, keepdims=True))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = np.empty(q.shape[:-1] + (3, 3))  # filled in place: the per-frame sleep tests call this
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - z * w)
    m[..., 0, 2] = 2 * (x * z + y * w)
    m[..., 1, 0] = 2 * (x * y + z * w)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - x * w)
    m[..., 2, 0] = 2 * (x * z - y * w)
    m[..., 2, 1] = 2 * (y * z + x * w)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def signed_dihedral(x: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Signed dihedral angle (rad) per quad (e0, e1, o0, o1), as ``smooth.dihedral_angle``."""
    e0, e1, o0, o1 = (x[quads[:, i]] for i in range(4))
    e = e1 - e0
    n0 = np.cross(e, o0 - e0)
    n1 = np.cross(e0 - e1, o1 - e1)
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    eh = e / np.linalg.norm(e, axis=1, keepdims=True)
    return np.arctan2(np.einsum("ij,ij->i", np.cross(n1, n0), eh), np.einsum("ij,ij->i", n0, n1))


def make_model(asset, config: Config | None = None) -> Model:
    """Arrays of the constraint families that ``config`` switches on, on ``config.device``.

    Constraints whose vertices are all kinematic (bone-to-bone edges, tets inside a bone's fixed
    vertices) are dropped: they can do no work. For ``Scheme.COLORED`` each family is sorted by colour.
    """
    cfg = (config or Config()).validate()
    device = wp.get_device(cfg.device)
    x = np.asarray(asset.positions, dtype=np.float64)
    layer = np.asarray(asset.layer)
    n = len(x)
    kin = layer == Layer.SKELETON
    inv_mass = np.where(kin, 0.0, 1.0 / np.maximum(asset.mass, 1e-30))
    movable = ~kin

    def keep(ids):
        return movable[ids].any(axis=1)

    fam = {}
    edges = np.zeros((0, 2), np.int32), np.zeros(0), np.zeros(0)
    if cfg.edges:
        e = keep(asset.edges)
        ids = asset.edges[e]
        skin = (layer[ids] == Layer.SKIN).all(axis=1)
        edges = ids, asset.edge_rest_length[e], np.where(skin, cfg.edge_compliance_skin, cfg.edge_compliance_flesh)
    att = attachment_pairs(asset, cfg)
    # Eq. 4 is an edge constraint: attachments ride in the edge family, after the tet edges
    fam["edge"] = tuple(np.concatenate([a, b]) for a, b in zip(edges, att))
    n_edges = len(edges[0])
    if cfg.volumes:
        t = keep(asset.tets)
        v = asset.tet_rest_volume[t]
        fam["tet"] = (asset.tets[t], 6.0 * v, 36.0 * v * cfg.volume_compliance)
    else:
        fam["tet"] = (np.zeros((0, 4), int), np.zeros(0), np.zeros(0))
    if cfg.smoothness:
        fam["dih"] = (asset.dihedral, signed_dihedral(x, asset.dihedral), None)
    else:
        fam["dih"] = (np.zeros((0, 4), int), np.zeros(0), None)

    edge_is_att = np.arange(len(fam["edge"][0])) >= n_edges  # which edge-family rows are Eq. 4 pairs
    colors = {}
    for name, (ids, rest, alpha) in list(fam.items()):
        if cfg.scheme == Scheme.COLORED and len(ids):
            order, ranges = color_ranges(greedy_colors(ids, movable))
            if name == "edge":
                edge_is_att = edge_is_att[order]
            ids, rest = ids[order], rest[order]
            alpha = alpha[order] if alpha is not None else None
            fam[name] = (ids, rest, alpha)
            colors[name] = ranges
        else:
            colors[name] = [(0, len(ids))] if len(ids) else []

    count = np.zeros((len(JACOBI_GROUPS), n))  # per Jacobi group: constraints touching each movable vertex
    for row, group in enumerate(JACOBI_GROUPS):
        for name in group:
            count[row] += np.bincount(np.asarray(fam[name][0]).ravel(), minlength=n)[:n]
    count[:, kin] = 0.0

    vb = np.where(kin, np.asarray(asset.vertex_body), -1).astype(np.int32)
    if (vb[kin] < 0).any():
        raise ValueError("asset: a skeleton vertex has no body (vertex_body < 0)")
    rot = quat_to_mat(asset.body_rest_quat)
    local = np.zeros_like(x)
    kv = np.flatnonzero(kin)
    local[kv] = np.einsum("kji,kj->ki", rot[vb[kv]], x[kv] - asset.body_rest_pos[vb[kv]])  # R^T (x - t)

    # the skin's tether (Config.skin_tether): each skin vertex rides with the bone of its nearest
    # skeleton vertex at rest, at its rest offset in that bone's frame
    ns = int(asset.n_skin)
    skin_body = np.full(ns, -1, np.int32)
    skin_local = np.zeros((ns, 3))
    # batched worlds (physhand_mj/batch.py) share their rest positions: a 4th coordinate keeps
    # every nearest-vertex query inside its own world
    worlds = int(asset.meta.get("worlds", 1)) if isinstance(asset.meta, dict) else 1
    world = np.zeros(n, np.int32)
    if worlds > 1:
        from physhand_mj.batch import vertex_world

        world = vertex_world(n, ns, worlds).astype(np.int32)
        xw = np.c_[x, 1.0e3 * world]
    else:
        xw = x
    if len(kv) and ns:
        from scipy.spatial import cKDTree

        near = kv[cKDTree(xw[kv]).query(xw[:ns])[1]]
        skin_body = vb[near].astype(np.int32)
        skin_local = np.einsum("kji,kj->ki", rot[skin_body], x[:ns] - asset.body_rest_pos[skin_body])

    # every vertex's carrier (a sleeping hand's rigid ride, activity.py): its own bone for the
    # skeleton, the bone of the nearest skeleton vertex at rest for the others
    carrier = vb.copy()
    if len(kv):
        from scipy.spatial import cKDTree

        soft = np.flatnonzero(~kin)
        carrier[soft] = vb[kv[cKDTree(xw[kv]).query(xw[soft])[1]]]

    def arr(a, dtype, shape=None):
        a = np.ascontiguousarray(a)
        if shape is not None:
            a = a.reshape(shape)
        return wp.array(a, dtype=dtype, device=device)

    v3 = lambda a: arr(np.asarray(a, np.float32).reshape(-1, 3), wp.vec3)  # noqa: E731
    f32 = lambda a: arr(np.asarray(a, np.float32), float)  # noqa: E731
    i2 = lambda a, k: wp.array(np.asarray(a, np.int32).reshape(-1, k), dtype=int, device=device)  # noqa: E731
    return Model(
        device=str(device), n_vertices=n, n_skin=int(asset.n_skin), n_bodies=len(asset.body_names),
        body_names=tuple(str(b) for b in asset.body_names),
        rest_x=v3(x), inv_mass=f32(inv_mass),
        vertex_body=arr(vb, int), body_local=v3(local), skin_body=arr(skin_body, int), skin_local=v3(skin_local),
        vertex_carrier=arr(carrier, int),
        edge_ids=i2(fam["edge"][0], 2), edge_rest=f32(fam["edge"][1]), edge_alpha=f32(fam["edge"][2]),
        tet_ids=i2(fam["tet"][0], 4), tet_rest6v=f32(fam["tet"][1]), tet_alpha=f32(fam["tet"][2]),
        edge_is_att=edge_is_att,
        dih_ids=i2(fam["dih"][0], 4), dih_rest=f32(fam["dih"][1]), dih_alpha=float(cfg.smooth_compliance),
        skin_faces=i2(asset.skin_faces, 3), guard_tets=i2(asset.tets[keep(asset.tets)], 4), vertex_count=wp.array(count.astype(np.float32), dtype=float, device=device), colors=colors,
        body_rest_pos=np.asarray(asset.body_rest_pos, float), body_rest_quat=np.asarray(asset.body_rest_quat, float),
        vertex_world=arr(world, int), worlds=worlds,
    )
