"""What every peer run shares: the soft body, the pressed object and its path, and both measures.

The work is :func:`physhand_mj.bench.cases.run_case`'s: an object (a :class:`physhand_mj.bench.cases.Case`)
placed against a skin point of a body at rest, its +z axis along the skin's inward normal, moved
from ``start`` m outside the skin to ``depth`` m into the rest skin over ``press_frames`` 5 ms
frames, then held; the body's skeleton layer does not move. :func:`object_path` gives that path
frame by frame (the same formula as ``run_case``; ``run_cpu.py`` checks the end poses agree), so a
peer simulator moves its copy of the object along it.

:class:`Measure` evaluates physhand_mj's two penetration measures on any vertex positions (a
peer's), through a physhand_mj solver built only to own the metric kernels and the object:
skin samples on the order-5 (and the order-9) lattice of the body's skin triangles against the
object's exact SDF, and object surface points inside the closed skin (winding number).

:func:`block_body` is the soft block for peers that cannot take the hand (and the analytic test).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench.cases import Case, rot_z_to, press_case, site_point  # noqa: E402
from physhand_mj.types import GeomType, Layer  # noqa: E402

FRAME_DT = 0.005  # s: one frame, as physhand_mj's Config.frame_dt

# The benchmark's objects: (label, press_case kind or a Case factory, site). A sphere on the palm and
# the two sharp meshes of cases.py (a 30-degree cone's tip at the fingertip, a 30-degree knife edge
# on the palm); meshes because MuJoCo has no analytic cone and both peers take triangle meshes.
def sphere_case(site: str = "palm", radius: float = 0.01, depth: float = 0.003, start: float = 0.002) -> Case:
    """A sphere of ``radius`` m whose lowest point goes ``depth`` m into the rest skin."""
    return Case("sphere", GeomType.SPHERE, (radius, 0.0, 0.0), lead=radius, site=site, depth=depth, start=start)


def cases(depth: float = 0.003, start: float = 0.002, press_frames: int = 15) -> list[Case]:
    """The sphere on the palm, the cone mesh at the fingertip, the knife on the palm."""
    out = [sphere_case(depth=depth, start=start), press_case("mesh_cone", site="fingertip", depth=depth, start=start),
           press_case("knife", site="palm", depth=depth, start=start)]
    for c in out:
        c.press_frames = press_frames
    return out


def _quat_mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def contact_frame(asset, case: Case):
    """(skin point (3,), outward unit normal (3,)) the case presses at: the hand's named site, or
    the top centre of a block (an asset whose meta has ``block_top``)."""
    if "block_top" in asset.meta:
        return np.asarray(asset.meta["block_top"], float), np.array([0.0, 0.0, 1.0])
    return site_point(asset, case.site)


def object_path(asset, case: Case, frames: int):
    """The object's pose at the end of each frame: pos (frames, 3) m, quat (4,) w x y z (fixed),
    and its pose at frame 0's start, as run_case moves it."""
    p0, n = contact_frame(asset, case)
    quat = _quat_mul(rot_z_to(-n), np.array([np.cos(case.spin / 2), 0, 0, np.sin(case.spin / 2)]))
    if case.lay:
        quat = _quat_mul(quat, np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]))

    def place(depth_now):  # the lead point (geom z = lead) depth_now into the skin along -n
        return p0 - n * depth_now + n * case.lead

    a = np.minimum((np.arange(frames) + 1) / max(case.press_frames, 1), 1.0)
    pos = np.stack([place(-case.start + s * (case.depth + case.start)) for s in a])
    return pos, quat, place(-case.start)


def add_object(objs, case: Case, pos, quat):
    """The case's geom into a physhand_mj ``Objects`` (as run_case adds it)."""
    if case.gtype == GeomType.MESH:
        objs.add(GeomType.MESH, None, pos, quat, name=case.name, vertices=case.vertices, faces=case.faces,
                 mesh_range=0.05)
    else:
        objs.add(case.gtype, case.size, pos, quat, name=case.name)


class Measure:
    """Both penetration measures of a body's vertex positions against a case's object.

    ``m(x, pos, quat)`` with x (N, 3) m in the body's vertex order (skin first, as the asset), the
    object's pose; returns skin_count/_max_um (order 5, the paper's metric), dense_count/_max_um
    (order 9), obj_count/_max_um (object surface points inside the closed skin)."""

    def __init__(self, asset, case: Case, device: str = "cpu"):
        import warp as wp

        from physhand_mj.contact import Objects

        self._wp = wp
        cfg = ph.Config(device=device)
        objs = Objects(device, 1)
        pos, quat, _ = object_path(asset, case, 1)
        add_object(objs, case, pos[0], quat)
        self.objects = objs
        self.solver = ph.Solver(ph.make_model(asset, cfg), cfg, objects=objs)
        self.state = self.solver.make_state()
        self.n = asset.n_vertices

    def __call__(self, x, pos, quat) -> dict:
        from physhand_mj.contact.metrics import summarize

        x = np.asarray(x, np.float32).reshape(-1, 3)
        if len(x) != self.n:
            raise ValueError(f"Measure: {len(x)} positions for a body of {self.n} vertices")
        self.state.x.assign(x)
        self.objects.set_poses(np.asarray(pos, float)[None], np.asarray(quat, float)[None])
        c = self.solver.contact
        m5 = summarize(c.measure(self.state, order=5))
        m9 = summarize(c.measure(self.state, order=9, objects_side=False))
        return dict(skin_count=m5["penetration_count"], skin_max_um=m5["penetration_max_um"],
                    dense_count=m9["penetration_count"], dense_max_um=m9["penetration_max_um"],
                    obj_count=m5["object_in_skin_count"], obj_max_um=m5["object_in_skin_max_um"])


def block_body(nx: int = 10, ny: int = 10, nz: int = 4, spacing: float = 0.004, density: float = 1100.0):
    """A soft block (nx x ny x nz cells of ``spacing`` m, top face at z = 0 centred on the z axis):
    skin = its closed boundary, flesh = the interior, skeleton = a plane of pinned vertices one cell
    below its bottom face, tied to it by one slab of tets (so the skin itself stays free and closed).
    Six tets per cube (Kuhn split: conforming). ``meta['block_top']`` is the top centre."""
    gx, gy, gz = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(-1, nz + 1), indexing="ij")
    grid = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], 1)
    idx = -np.ones((nx + 1, ny + 1, nz + 2), int)
    idx[grid[:, 0], grid[:, 1], grid[:, 2] + 1] = np.arange(len(grid))
    kuhn = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    corner = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])
    tets, slab = [], []
    for i in range(nx):
        for j in range(ny):
            for k in range(-1, nz):
                c = [idx[i + dx, j + dy, k + 1 + dz] for dx, dy, dz in corner]
                (slab if k < 0 else tets).extend([[c[a] for a in t] for t in kuhn])
    tets, slab = np.array(tets), np.array(slab)
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]]), 1)
    uniq, cnt = np.unique(faces, axis=0, return_counts=True)
    skin_f = uniq[cnt == 1]
    x = (grid - [nx / 2, ny / 2, nz]) * spacing
    skin_v = np.unique(skin_f)
    skel_v = np.flatnonzero(grid[:, 2] == -1)
    flesh_v = np.setdiff1d(np.arange(len(grid)), np.concatenate([skin_v, skel_v]))
    order = np.concatenate([skin_v, flesh_v, skel_v])
    new = np.empty(len(order), int)
    new[order] = np.arange(len(order))
    x, skin_f, all_t = x[order], new[skin_f], new[np.concatenate([tets, slab])]
    cen = x[skin_f].mean(1)  # orient outward: the normal away from the block's centre (convex)
    nrm = np.cross(x[skin_f[:, 1]] - x[skin_f[:, 0]], x[skin_f[:, 2]] - x[skin_f[:, 0]])
    flip = np.einsum("ij,ij->i", nrm, cen - [0, 0, -nz * spacing / 2]) < 0
    skin_f[flip] = skin_f[flip][:, [0, 2, 1]]
    layer = np.concatenate([np.full(len(skin_v), Layer.SKIN), np.full(len(flesh_v), Layer.FLESH),
                            np.full(len(skel_v), Layer.SKELETON)]).astype(np.int8)
    vb = np.where(layer == Layer.SKELETON, 0, -1)
    body = ph.soft_body(x, skin_faces=skin_f, tets=all_t, layer=layer, vertex_body=vb, body_names=("base",),
                        density=density, name="soft block")
    body.meta["block_top"] = [0.0, 0.0, 0.0]
    return body
