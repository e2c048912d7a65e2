"""The generic layered-body builder: skin mesh + bone meshes named by MuJoCo body -> asset arrays.

Works for the embedded MyoHand and for any other input a user brings (a NIMBLE or MANO skin they
are licensed to use with bones per body, or soft pads around robot-finger links):

1. bones: each closed (holes filled, else its convex hull), bones of one rigid group fused
   (manifold3d union), decimated to a vertex budget (fast-simplification), every vertex labelled
   with the body of the nearest input bone;
2. checks: bones disjoint and strictly inside the skin;
3. flesh: TetGen fills the space between skin and bones (``-pYq``: surfaces preserved, so every
   skin and bone vertex is a tet vertex; quality refinement adds interior nodes), tets inside bones
   are dropped (bones are holes);
4. derived data (:mod:`physhand_mj.build.derive`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from physhand_mj.build import derive
from physhand_mj.types import Layer

log = logging.getLogger(__name__)


class BuildError(ValueError):
    """The builder's input cannot make a valid layered body; the message says what to fix."""


@dataclass(frozen=True)
class TetOptions:
    """TetGen quality settings.

    Attributes:
      radius_edge: maximum radius-edge ratio (TetGen ``-q`` first value).
      min_dihedral_deg: requested minimum dihedral angle, degrees (``-q`` second value); with the
        surfaces preserved (``-Y``) TetGen may not reach it next to the boundary: the built asset
        reports what it got.
      max_volume: maximum tet volume (m^3), ``None`` for no limit.
    """

    radius_edge: float = 1.6
    min_dihedral_deg: float = 10.0
    max_volume: float | None = 3.0e-8


def close_mesh(mesh: trimesh.Trimesh, name: str) -> trimesh.Trimesh:
    """A closed, outward copy of ``mesh``: holes filled, or its convex hull as the last resort."""
    m = mesh.copy()
    m.merge_vertices()
    if not m.is_watertight:
        trimesh.repair.fill_holes(m)
    if not m.is_watertight or not m.is_winding_consistent:
        log.info("bone %s is not closed: using its convex hull", name)
        m = m.convex_hull
    trimesh.repair.fix_normals(m)
    return m


def prepare_bones(bones: dict[str, trimesh.Trimesh], rigid_groups: list[list[str]] | None,
                  n_vertices: int, spacing: float = 0.4e-3
                  ) -> tuple[list[trimesh.Trimesh], list[np.ndarray], list[str]]:
    """Close, fuse and remesh the bones.

    Each rigid group (bodies welded together, e.g. the carpals and metacarpals 2-5) becomes one
    closed surface: the zero level set of the minimum of its bones' signed distances, extracted by
    marching cubes at ``spacing`` (m) and remeshed uniformly (ACVD) to a share of ``n_vertices``
    proportional to its area. Fusing in the implicit domain removes the small overlaps between
    neighbouring carpals, and the level-set route gives clean, near-uniform triangles where
    quadric decimation of the raw scans opened or self-intersected several bones.

    Returns ``(meshes, vertex_body, body_names)``: one closed mesh per rigid group, for each the
    body index (into ``body_names``) of every vertex (the body of the nearest input bone).
    """
    from physhand_mj.build.skin import SkinPart, extract_surface, implicit_skin_field, remesh_uniform

    body_names = list(bones)
    closed = {n: close_mesh(m, n) for n, m in bones.items()}
    groups = [list(g) for g in (rigid_groups or [])]
    grouped = {n for g in groups for n in g}
    unknown = grouped - set(bones)
    if unknown:
        raise BuildError(f"rigid groups name bodies without a bone mesh: {sorted(unknown)}")
    groups += [[n] for n in body_names if n not in grouped]
    areas = np.array([sum(closed[n].area for n in g) for g in groups])
    budget = np.maximum(40, np.round(n_vertices * areas / areas.sum())).astype(int)
    meshes, labels = [], []
    for g, nv in zip(groups, budget):
        parts = [SkinPart(n, closed[n], 0.0) for n in g]
        field, origin, h = implicit_skin_field(parts, spacing=spacing, blend=0.0)
        m = remesh_uniform(extract_surface(field, origin, h, largest_only=False), int(nv))
        pts = np.concatenate([closed[n].vertices for n in g])
        owner = np.concatenate([np.full(len(closed[n].vertices), body_names.index(n)) for n in g])
        meshes.append(m)
        labels.append(owner[cKDTree(pts).query(m.vertices)[1]].astype(np.int32))
    return meshes, labels, body_names


def check_bones(skin: trimesh.Trimesh, meshes: list[trimesh.Trimesh], min_clearance: float,
                names: list[str] | None = None) -> float:
    """Raise :class:`BuildError` if bones overlap or come closer than ``min_clearance`` to the skin.

    Returns the smallest bone-to-skin distance (metres).
    """
    from physhand_mj.build.skin import signed_distance

    names = names or [f"bone {i}" for i in range(len(meshes))]
    for i, a in enumerate(meshes):  # no vertex of one bone inside another (TetGen catches crossings)
        for j, b in enumerate(meshes):
            if i != j and np.all(a.bounds[0] < b.bounds[1]) and np.all(b.bounds[0] < a.bounds[1]):
                sd = signed_distance(b, a.vertices, max_dist=0.05)
                if sd.min() < 0:
                    raise BuildError(f"{names[i]} enters {names[j]} by {-sd.min() * 1e3:.2f} mm; put them in "
                                     "one rigid group or pose them apart")
    clearance = np.inf
    for name, m in zip(names, meshes):
        depth = -signed_distance(skin, m.vertices)  # > 0 inside the skin
        if depth.min() < min_clearance:
            k = int(np.argmin(depth))
            raise BuildError(f"{name} comes {depth[k] * 1e3:.2f} mm from the skin at "
                             f"{np.round(m.vertices[k] * 1e3, 1)} mm (needs {min_clearance * 1e3:.2f} mm "
                             "inside); thicken the skin there")
        clearance = min(clearance, float(depth.min()))
    return clearance


@contextlib.contextmanager
def _stdout_to_stderr():
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def tetrahedralize(skin: trimesh.Trimesh, bones: list[trimesh.Trimesh], opts: TetOptions):
    """TetGen over the skin and bone surfaces; returns ``(nodes, tets)`` with bone interiors removed."""
    import tetgen

    pieces = [skin] + bones
    offsets = np.cumsum([0] + [len(m.vertices) for m in pieces])
    points = np.concatenate([m.vertices for m in pieces])
    faces = np.concatenate([m.faces + o for m, o in zip(pieces, offsets[:-1])]).astype(np.int32)
    switches = f"pYq{opts.radius_edge}/{opts.min_dihedral_deg}"
    if opts.max_volume:
        switches += f"a{opts.max_volume:.3e}"
    tg = tetgen.TetGen(points, faces)
    with _stdout_to_stderr():  # TetGen's C code prints to stdout even when quiet
        nodes, elems, *_ = tg.tetrahedralize(switches=switches + "Q")
    nodes = np.asarray(nodes, dtype=np.float64)
    elems = np.asarray(elems, dtype=np.int64)
    if not np.allclose(nodes[: len(points)], points):
        raise BuildError("TetGen moved or merged surface vertices; the skin or a bone self-intersects")
    from physhand_mj.build.skin import signed_distance

    centroid = nodes[elems].mean(axis=1)
    inside_bone = np.zeros(len(elems), dtype=bool)
    for b in bones:  # with -Y every tet lies wholly inside or outside each bone: centroids decide
        inside_bone |= signed_distance(b, centroid, max_dist=0.05) < 0
    return nodes, elems[~inside_bone], len(skin.vertices), offsets


def assemble(skin: trimesh.Trimesh, bones: dict[str, trimesh.Trimesh], *,
             rigid_groups: list[list[str]] | None = None, skeleton_vertices: int = 3300,
             tet: TetOptions = TetOptions(), density: float = 1100.0,
             min_clearance: float = 1.0e-3) -> dict[str, np.ndarray]:
    """Build the layered body's arrays (see :class:`physhand_mj.asset.HandAsset` for their meaning)."""
    if not (skin.is_watertight and skin.is_winding_consistent and skin.volume > 0):
        raise BuildError("the skin must be a closed, consistently oriented, outward triangle mesh")
    bone_meshes, bone_labels, body_names = prepare_bones(bones, rigid_groups, skeleton_vertices)
    group_names = ["+".join(body_names[i] for i in np.unique(lab)) for lab in bone_labels]
    clearance = check_bones(skin, bone_meshes, min_clearance, group_names)
    nodes, tets, n_skin, offsets = tetrahedralize(skin, bone_meshes, tet)

    used = np.zeros(len(nodes), dtype=bool)
    used[tets.reshape(-1)] = True
    n_surface = offsets[-1]
    if not used[:n_surface].all():
        raise BuildError("some skin or bone vertices ended up in no tet; check the inputs are disjoint")
    # New order: skin, flesh (interior nodes in use), skeleton.
    flesh_old = np.nonzero(used[n_surface:])[0] + n_surface
    skel_old = np.arange(n_skin, n_surface)
    order = np.concatenate([np.arange(n_skin), flesh_old, skel_old])
    remap = np.full(len(nodes), -1, dtype=np.int64)
    remap[order] = np.arange(len(order))
    x = nodes[order]
    tets = derive.orient_tets(x, remap[tets].astype(np.int32))
    layer = np.concatenate([np.full(n_skin, Layer.SKIN), np.full(len(flesh_old), Layer.FLESH),
                            np.full(len(skel_old), Layer.SKELETON)]).astype(np.int8)
    vertex_body = np.full(len(x), -1, dtype=np.int32)
    vertex_body[layer == Layer.SKELETON] = np.concatenate(bone_labels)
    bone_faces = np.concatenate([m.faces + o for m, o in zip(bone_meshes, offsets[1:-1])])
    bone_faces = remap[bone_faces].astype(np.int32)

    edges = derive.tet_edges(tets).astype(np.int32)
    skeleton = np.nonzero(layer == Layer.SKELETON)[0]
    movable = np.nonzero(layer != Layer.SKELETON)[0]
    attach = derive.nearest_skeleton_pairs(x, movable, skeleton)
    skin_faces = np.asarray(skin.faces, dtype=np.int32)
    quads, angles = derive.dihedral_pairs(x, skin_faces)
    return dict(
        positions=x, layer=layer, skin_faces=skin_faces, tets=tets,
        tet_rest_volume=derive.tet_signed_volumes(x, tets),
        edges=edges, edge_rest_length=np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1),
        mass=derive.lumped_masses(x, tets, density), density=np.float64(density),
        attach=attach, attach_rest_length=np.linalg.norm(x[attach[:, 0]] - x[attach[:, 1]], axis=1),
        dihedral=quads, dihedral_rest_angle=angles,
        bone_faces=bone_faces, body_names=np.array(body_names), vertex_body=vertex_body,
        bone_skin_clearance=np.float64(clearance),
    )
