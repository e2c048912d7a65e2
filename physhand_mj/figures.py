"""Pictures of the layered hand, rendered by MuJoCo offscreen (see :mod:`physhand_mj.render`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from physhand_mj.render import look_at_camera, make_renderer, mesh_scene_spec, write_png
from physhand_mj.types import Layer

SKIN_RGBA = (0.87, 0.68, 0.58, 1.0)
BONE_RGBA = (0.95, 0.93, 0.84, 1.0)
FLESH_RGBA = (0.80, 0.30, 0.30, 1.0)


def _hand_camera(model, data, distance=0.42, azimuth=200.0, elevation=-55.0):
    import mujoco

    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "thirdmc_r")
    center = data.xpos[bid] if bid >= 0 else np.zeros(3)
    return look_at_camera(center, distance, azimuth, elevation)


def render_layers(model, data, path: str | Path, *, skin_alpha: float = 0.45, width: int = 960,
                  height: int = 720, camera=None) -> Path:
    """The hand with a translucent skin over its bones (groups 1-2 shown, collision proxies hidden)."""
    import mujoco

    from physhand_mj.hand_mjcf import skin_geom_id

    gid = skin_geom_id(model)
    old = model.geom_rgba[gid].copy()
    model.geom_rgba[gid, 3] = skin_alpha
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = [1, 1, 1, 0, 0, 0]
    renderer = make_renderer(model, width, height)
    try:
        renderer.update_scene(data, camera=camera or _hand_camera(model, data), scene_option=opt)
        pixels = renderer.render()
    finally:
        renderer.close()
        model.geom_rgba[gid] = old
    return write_png(pixels, path)


def cutaway_meshes(asset, normal=(0.0, 0.0, 1.0), offset: float | None = None):
    """Meshes of the hand cut by a plane: skin, bone and exposed flesh faces of the kept tets.

    Keeps the tets whose centroid lies below the plane ``normal . x = offset`` (default: through
    the centroid of the skeleton) and returns ``[(name, vertices, faces, rgba), ...]``.
    """
    x, tets = asset.positions, asset.tets
    n = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    if offset is None:
        offset = float(x[asset.layer == Layer.SKELETON].mean(axis=0) @ n)
    keep = tets[(x[tets].mean(axis=1) @ n) < offset]
    faces = keep[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3)  # outward per tet
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = faces[counts[inv.reshape(-1)] == 1]
    lay = asset.layer[boundary]
    skin = np.all(lay == Layer.SKIN, axis=1)
    bone = np.all(lay == Layer.SKELETON, axis=1)
    out = []
    for name, sel, rgba in (("cut_skin", skin, SKIN_RGBA), ("cut_bone", bone, BONE_RGBA),
                            ("cut_flesh", ~(skin | bone), FLESH_RGBA)):
        f = boundary[sel]
        used, inv2 = np.unique(f, return_inverse=True)
        out.append((name, x[used], inv2.reshape(-1, 3), rgba))
    return out


def render_cutaway(asset, path: str | Path, *, normal=(0.0, 0.0, 1.0), width: int = 960, height: int = 720,
                   distance: float = 0.32, tilt_deg: float = 20.0) -> Path:
    """Render :func:`cutaway_meshes`, looking at the cut face (against ``normal``, tilted a little)."""
    import mujoco

    spec = mesh_scene_spec(cutaway_meshes(asset, normal))
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    center = asset.positions[asset.layer == Layer.SKELETON].mean(axis=0)
    renderer = make_renderer(model, width, height)
    try:
        f = -np.asarray(normal, dtype=float) / np.linalg.norm(normal)  # camera forward
        azimuth = np.degrees(np.arctan2(f[1], f[0])) + tilt_deg
        elevation = np.degrees(np.arcsin(np.clip(f[2], -1, 1)))
        renderer.update_scene(data, camera=look_at_camera(center, distance, azimuth, elevation))
        pixels = renderer.render()
    finally:
        renderer.close()
    return write_png(pixels, path)


def pressure_rgba(p: np.ndarray, vmax: float) -> np.ndarray:
    """Blue (0) -> yellow -> red (vmax) colours for pressures (Pa)."""
    t = np.clip(np.asarray(p, float) / max(vmax, 1e-9), 0.0, 1.0)[:, None]
    lo, mid, hi = np.array([0.2, 0.35, 0.95]), np.array([1.0, 0.85, 0.1]), np.array([0.9, 0.1, 0.1])
    rgb = np.where(t < 0.5, lo + (mid - lo) * (2 * t), mid + (hi - mid) * (2 * t - 1))
    return np.concatenate([rgb, np.ones_like(t)], axis=1)


def add_pressure_markers(scene, points: np.ndarray, pressure: np.ndarray, vmax: float,
                         radius: float = 0.0012) -> int:
    """Append small spheres at ``points`` coloured by ``pressure`` to a ``mujoco.MjvScene`` (the skin
    is one mesh, which MuJoCo cannot colour per vertex). Returns how many fitted."""
    import mujoco

    rgba = pressure_rgba(pressure, vmax).astype(np.float32)
    room = scene.maxgeom - scene.ngeom
    n = min(len(points), room)
    for i in range(n):
        g = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.array([radius, 0, 0]), points[i],
                            np.eye(3).ravel(), rgba[i])
        scene.ngeom += 1
    return n


def contact_camera(skin: np.ndarray, distance: float = 0.3, azimuth: float = -70.0, elevation: float = -35.0):
    return look_at_camera(skin.mean(axis=0), distance, azimuth, elevation)


def render_contact_frame(renderer, model, data, hand, camera, vmax: float | None = None) -> np.ndarray:
    """One frame: the deformed skin (uploaded to this renderer's GL context) with the contact
    pressure heat map as markers on the skin vertices in contact (colour scale 0..vmax Pa; default
    the 95th percentile of this frame's contact pressures)."""
    import mujoco

    mujoco.mjr_uploadMesh(model, renderer._mjr_context, hand.skin_mesh_id)
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = [1, 0, 1, 0, 0, 0]  # objects (0) and skin (2); bones and proxies hidden
    renderer.update_scene(data, camera=camera, scene_option=opt)
    report = hand.contacts()
    p = report["pressure_pa"]
    idx = np.flatnonzero(p > 0)
    if vmax is None:
        vmax = float(np.percentile(p[idx], 95)) if len(idx) else 1.0
    add_pressure_markers(renderer.scene, hand.skin_vertices[idx], p[idx], vmax)
    return renderer.render()


def render_penetration_frame(renderer, model, data, hand, camera, max_marks: int = 2000) -> np.ndarray:
    """One frame: the skin as it is (uploaded to this renderer) and the metric's penetrating samples
    as magenta dots (at most ``max_marks``, the deepest first)."""
    import mujoco

    mujoco.mjr_uploadMesh(model, renderer._mjr_context, hand.skin_mesh_id)
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = [1, 0, 1, 0, 0, 0]  # objects (0) and skin (2); bones and proxies hidden
    renderer.update_scene(data, camera=camera, scene_option=opt)
    pts, depth = hand.penetrating_samples()
    order = np.argsort(-depth)[:max_marks]
    scene = renderer.scene
    for i in order[: scene.maxgeom - scene.ngeom]:
        g = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_SPHERE, np.array([0.0015, 0, 0]), pts[i], np.eye(3).ravel(),
                            np.array([0.95, 0.1, 0.85, 1.0], np.float32))
        scene.ngeom += 1
    return renderer.render()


def render_marked_skin(renderer, model, data, hand, camera, points: np.ndarray,
                       rgba=(0.95, 0.1, 0.85, 1.0), radius: float = 0.0012) -> np.ndarray:
    """One frame: the skin as it is (uploaded to this renderer), objects shown, bones and proxies
    hidden, and ``points`` (k, 3) m marked as dots (as many as the scene holds): e.g. the skin
    vertices a self-penetration measure finds inside the hand (benchmarks/self_collision.py --picture)."""
    import mujoco

    mujoco.mjr_uploadMesh(model, renderer._mjr_context, hand.skin_mesh_id)
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = [1, 0, 1, 0, 0, 0]  # objects (0) and skin (2); bones and proxies hidden
    renderer.update_scene(data, camera=camera, scene_option=opt)
    scene = renderer.scene
    for p in np.asarray(points, float)[: scene.maxgeom - scene.ngeom]:
        mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, np.array([radius, 0, 0]), p,
                            np.eye(3).ravel(), np.array(rgba, np.float32))
        scene.ngeom += 1
    return renderer.render()


def render_grasp_view(model, data, hand, width: int = 640, height: int = 480) -> np.ndarray:
    """Pixels of the hand's object (the first non-world object body) and the skin as it is now,
    seen from above with the object made translucent and the penetrating samples marked
    (:func:`render_penetration_frame`); the object's colours are restored afterwards."""
    renderer = make_renderer(model, width, height)
    body = model.body([n for n in hand.objects.object_names if n != "world"][0]).id
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body]
    alpha = model.geom_rgba[geoms, 3].copy()
    model.geom_rgba[geoms, 3] = 0.45  # see the samples inside the object
    try:
        cam = look_at_camera(0.5 * (data.xpos[body] + hand.skin_vertices.mean(axis=0)), 0.3, 90.0, -88.0)
        return render_penetration_frame(renderer, model, data, hand, cam).copy()
    finally:
        model.geom_rgba[geoms, 3] = alpha
        renderer.close()
