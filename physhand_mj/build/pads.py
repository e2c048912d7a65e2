"""Soft pads around robot finger links: the same layered-body builder as the hand.

For each link: the skin is the ``thickness`` offset of the convex hull of the link's geoms (for a
convex body the offset is the Minkowski sum with a ball: the convex hull of the hull's vertices
spread over a ball), ACVD-remeshed like the hand's skin; the pad's rigid core ("bone", inverse mass
0, moved by the link's MuJoCo body) is the hull scaled by ``core_scale`` about its centroid, which
keeps it strictly inside for the builder's clearance check; TetGen fills the flesh between. The
pads of all links form one asset (one skin mesh with one shell per link).
"""

from __future__ import annotations

import numpy as np
import trimesh

from physhand_mj.build import build_from_meshes
from physhand_mj.build.layered import TetOptions


def link_hulls(model, data, bodies: list[str]) -> dict[str, trimesh.Trimesh]:
    """World-frame convex hull of each body's geoms at the current pose (after kinematics)."""
    import mujoco

    out = {}
    for name in bodies:
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            raise ValueError(f"the model has no body '{name}'")
        pts = []
        for g in np.flatnonzero(model.geom_bodyid == bid):
            rot = data.geom_xmat[g].reshape(3, 3)
            if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                mid = model.geom_dataid[g]
                v = model.mesh_vert[model.mesh_vertadr[mid]: model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
            else:
                v = trimesh.creation.icosphere(2, radius=float(model.geom_rbound[g])).vertices
            pts.append(v @ rot.T + data.geom_xpos[g])
        if not pts:
            raise ValueError(f"body '{name}' has no geoms to build a pad around")
        out[name] = trimesh.convex.convex_hull(np.concatenate(pts))
    return out


def build_pads(model, data, bodies: list[str], *, thickness: float = 4.0e-3, core_scale: float = 0.8,
               skin_vertices: int = 500, core_vertices: int = 200, max_tet_volume: float = 1.0e-8):
    """A layered asset of soft pads around ``bodies`` of a compiled MuJoCo model at ``data``'s pose
    (lengths in m, volumes in m^3)."""
    from physhand_mj.build.skin import remesh_uniform

    hulls = link_hulls(model, data, bodies)
    ball = trimesh.creation.icosphere(2, radius=thickness).vertices
    shells, cores = [], {}
    for name, hull in hulls.items():
        offset = trimesh.convex.convex_hull((hull.vertices[:, None, :] + ball[None]).reshape(-1, 3))
        shells.append(remesh_uniform(offset, skin_vertices))
        core = hull.copy()
        c = hull.vertices.mean(axis=0)
        core.vertices = (core.vertices - c) * core_scale + c
        cores[name] = core
    pose = {n: (data.xpos[model.body(n).id].copy(), data.xquat[model.body(n).id].copy()) for n in bodies}
    return build_from_meshes(trimesh.util.concatenate(shells), cores, pose,
                             skeleton_vertices=core_vertices * len(bodies), tet=TetOptions(max_volume=max_tet_volume),
                             meta=dict(name="soft pads", bodies=list(bodies), thickness_m=thickness))
