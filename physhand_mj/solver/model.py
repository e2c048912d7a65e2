"""Build the solver's immutable :class:`~physhand_mj.types.Model` from a layered asset."""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.solver.attach import attachment_pairs
from physhand_mj.solver.coloring import color_ranges, greedy_colors
from physhand_mj.solver.gather import gather_lists
from physhand_mj.rotations import quat_to_mat
from physhand_mj.types import Config, Layer, Model, Scheme

FAMILIES = ("edge", "tet", "dih")  # projection order within an iteration (edge includes Eq. 4)
# Jacobi groups: families of one group are projected from the same positions and their corrections
# averaged together (one apply launch per group); groups run one after another. One family per group
# measured best (docs/solver.md): grouping edges with tets saves a launch per substep but made the
# hand visibly softer (slower settling, 2.4 mm left after a grasp and release vs < 2 mm).
JACOBI_GROUPS = (("edge",), ("tet",), ("dih",))



def vertex_world(n: int, n_skin: int, worlds: int) -> np.ndarray:
    """World of every vertex of a replicated body of ``n`` vertices (``n_skin`` skin) holding
    ``worlds`` copies: the skins first, world by world, then the rest, world by world."""
    ns, per = n_skin // worlds, (n - n_skin) // worlds
    i = np.arange(n)
    return np.where(i < n_skin, i // max(ns, 1), (i - n_skin) // max(per, 1))


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


def morton_code(p: np.ndarray) -> np.ndarray:
    """(K, 3) points -> (K,) 30-bit Morton codes of their cells on a 1024^3 grid over their box
    (a space-filling-curve order: points close in the order are close in space)."""
    p = np.asarray(p, float)
    q = ((p - p.min(axis=0)) / max(float(np.ptp(p, axis=0).max()), 1e-12) * 1023).astype(np.int64)

    def spread(v):  # 10 bits -> every third of 30
        v = (v | (v << 16)) & 0x030000FF
        v = (v | (v << 8)) & 0x0300F00F
        v = (v | (v << 4)) & 0x030C30C3
        return (v | (v << 2)) & 0x09249249

    return spread(q[:, 0]) | (spread(q[:, 1]) << 1) | (spread(q[:, 2]) << 2)


def make_model(asset, config: Config | None = None) -> Model:
    """Arrays of the constraint families that ``config`` switches on, on ``config.device``.

    Constraints whose vertices are all kinematic (bone-to-bone edges, tets inside a bone's fixed
    vertices) are dropped: they can do no work. For ``Scheme.COLORED`` each family is sorted by colour.
    """
    cfg = (config or Config()).validate()
    return upload_model(model_arrays(asset, cfg), cfg)


def model_arrays(asset, cfg: Config, batch: bool = False) -> dict:
    """:func:`make_model`'s arrays on the host (numpy), before the upload: :func:`upload_model`
    turns them into the Model; batched worlds tile one world's (physhand_mj/batch.py; ``batch``:
    the arrays are for a batch of several worlds, where ``Config.execution.jacobi_gather=None`` gathers on
    CUDA)."""
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
        rest = asset.edge_rest_length[e]
        # stretch only (Config.skin_compression / flesh_compression False): a negative rest length
        # (edge.edge_correction); the attachments below resist both ways
        stretch_only = np.where(skin, not cfg.skin_compression, not cfg.flesh_compression)
        rest = np.where(stretch_only, -rest, rest)
        edges = ids, rest, np.where(skin, cfg.edge_compliance_skin, cfg.edge_compliance_flesh)
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

    # the world of every vertex (batched worlds replicated into one asset, physhand_mj/batch.py)
    worlds = int(asset.meta.get("worlds", 1)) if isinstance(asset.meta, dict) else 1
    world = np.zeros(n, np.int32)
    if worlds > 1:

        world = vertex_world(n, int(asset.n_skin), worlds).astype(np.int32)

    # Jacobi without atomics (solver/gather.py): per group, each movable vertex's correction slots
    gather_off, gather_slot, slot_base = [], [], {}
    # (Config.execution.fused_substep sums in shared memory: no slots)
    gather = cfg.jacobi_gather if cfg.jacobi_gather is not None else (batch and device.is_cuda and not cfg.fused_substep)
    if cfg.scheme == Scheme.JACOBI and gather:
        # tets in space-filling-curve order of their rest centroids (per world): neighbouring threads
        # then read neighbouring vertices and a vertex's slots lie close together (H100, 256 worlds:
        # solve_tets 0.50 -> 0.34 ms, its gather 0.88 -> 0.70 ms a launch). Each vertex still sums in
        # the tets' asset order (``order``), so the result is the atomic path's bit for bit on the CPU.
        order = {name: None for name in FAMILIES}
        ids = np.asarray(fam["tet"][0])
        if len(ids):
            perm = np.lexsort((morton_code(x[ids].mean(axis=1)), world[ids[:, 0]]))
            fam["tet"] = tuple(np.asarray(v)[perm] for v in fam["tet"])
            order["tet"] = perm
        for group in JACOBI_GROUPS:
            off, slots, bases = gather_lists([fam[name][0] for name in group], movable,
                                             [order[name] for name in group])
            gather_off.append(off)
            gather_slot.append(slots)
            slot_base.update(zip(group, bases))

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
    skin_anchor = np.zeros((ns, 3))  # that skeleton vertex (the skin's anchor), in the same bone's frame
    # batched worlds (physhand_mj/batch.py) share their rest positions: a 4th coordinate keeps
    # every nearest-vertex query inside its own world
    xw = np.c_[x, 1.0e3 * world] if worlds > 1 else x
    if len(kv) and ns:
        from scipy.spatial import cKDTree

        near = kv[cKDTree(xw[kv]).query(xw[:ns])[1]]
        skin_body = vb[near].astype(np.int32)
        skin_local = np.einsum("kji,kj->ki", rot[skin_body], x[:ns] - asset.body_rest_pos[skin_body])
        skin_anchor = local[near]

    # every vertex's carrier (a sleeping hand's rigid ride, activity.py): its own bone for the
    # skeleton, the bone of the nearest skeleton vertex at rest for the others
    carrier = vb.copy()
    if len(kv):
        from scipy.spatial import cKDTree

        soft = np.flatnonzero(~kin)
        carrier[soft] = vb[kv[cKDTree(xw[kv]).query(xw[soft])[1]]]

    return dict(
        n_vertices=n, n_skin=ns, body_names=tuple(str(b) for b in asset.body_names), worlds=worlds,
        rest_x=x, inv_mass=inv_mass, vertex_body=vb, body_local=local, skin_body=skin_body,
        skin_local=skin_local, skin_anchor=skin_anchor, vertex_carrier=carrier, vertex_world=world,
        edge_ids=np.asarray(fam["edge"][0]), edge_rest=np.asarray(fam["edge"][1]),
        edge_alpha=np.asarray(fam["edge"][2]), edge_is_att=edge_is_att,
        tet_ids=np.asarray(fam["tet"][0]), tet_rest6v=np.asarray(fam["tet"][1]), tet_alpha=np.asarray(fam["tet"][2]),
        dih_ids=np.asarray(fam["dih"][0]), dih_rest=np.asarray(fam["dih"][1]), dih_alpha=float(cfg.smooth_compliance),
        skin_faces=np.asarray(asset.skin_faces), guard_tets=np.asarray(asset.tets[keep(asset.tets)]),
        vertex_count=count, colors=colors,
        body_rest_pos=np.asarray(asset.body_rest_pos, float), body_rest_quat=np.asarray(asset.body_rest_quat, float),
        gather_off=gather_off, gather_slot=gather_slot, slot_base=slot_base,
    )


def upload_model(a: dict, cfg: Config) -> Model:
    """The Model of :func:`model_arrays`' host arrays ``a``, on ``cfg.device``."""
    device = wp.get_device(cfg.device)

    def arr(v, dtype):
        return wp.array(np.ascontiguousarray(v), dtype=dtype, device=device)

    v3 = lambda v: arr(np.asarray(v, np.float32).reshape(-1, 3), wp.vec3)  # noqa: E731
    f32 = lambda v: arr(np.asarray(v, np.float32), float)  # noqa: E731
    i1 = lambda v: arr(np.asarray(v, np.int32), int)  # noqa: E731
    i2 = lambda v, k: arr(np.asarray(v, np.int32).reshape(-1, k), int)  # noqa: E731
    sizes = {name: np.asarray(a[f"{name}_ids"]).size for name in FAMILIES}
    n_slots = max((sum(sizes[name] for name in group) for group in JACOBI_GROUPS), default=0) if a["gather_off"] else 0
    return Model(
        device=str(device), n_vertices=int(a["n_vertices"]), n_skin=int(a["n_skin"]), n_bodies=len(a["body_names"]),
        body_names=tuple(a["body_names"]),
        rest_x=v3(a["rest_x"]), inv_mass=f32(a["inv_mass"]),
        vertex_body=i1(a["vertex_body"]), body_local=v3(a["body_local"]), skin_body=i1(a["skin_body"]),
        skin_local=v3(a["skin_local"]), skin_anchor=v3(a["skin_anchor"]), vertex_carrier=i1(a["vertex_carrier"]),
        edge_ids=i2(a["edge_ids"], 2), edge_rest=f32(a["edge_rest"]), edge_alpha=f32(a["edge_alpha"]),
        tet_ids=i2(a["tet_ids"], 4), tet_rest6v=f32(a["tet_rest6v"]), tet_alpha=f32(a["tet_alpha"]),
        edge_is_att=np.asarray(a["edge_is_att"]),
        dih_ids=i2(a["dih_ids"], 4), dih_rest=f32(a["dih_rest"]), dih_alpha=float(a["dih_alpha"]),
        skin_faces=i2(a["skin_faces"], 3), guard_tets=i2(a["guard_tets"], 4),
        vertex_count=arr(np.asarray(a["vertex_count"], np.float32), float), colors=a["colors"],
        body_rest_pos=np.asarray(a["body_rest_pos"], float), body_rest_quat=np.asarray(a["body_rest_quat"], float),
        vertex_world=i1(a["vertex_world"]), worlds=int(a["worlds"]),
        gather_off=[i1(v) for v in a["gather_off"]], gather_slot=[i1(v) for v in a["gather_slot"]],
        slot_base=dict(a["slot_base"]), n_slots=int(n_slots),
    )
