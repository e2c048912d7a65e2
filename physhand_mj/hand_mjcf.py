"""Where the hand MJCF lives, and small helpers over a compiled model that contains the hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
MJCF_DIR = REPO_ROOT / "mjcf"
HAND_XML = MJCF_DIR / "hand" / "myohand.xml"
SCENES_DIR = MJCF_DIR / "scenes"
SKIN_GEOM = "physhand_skin"
MOUNT_BODY = "hand_mount"
PROXY_SUFFIX = "_proxy"  # a bone's collision proxy against objects (MJCF class proxy, build/mjcf.py)
PROXY_INSET = 2.5e-3  # m between a collision proxy and the rest skin (build/mjcf.py fits them so)
SELF_PROXY_SUFFIX = "_proxy_self"  # a collision proxy's self copy (MJCF class self_proxy, build/mjcf.py)
SELF_PROXY_BIT = 1 << 29  # their contype as shipped; their conaffinity too once turned on (no shipped geom uses it)


def scene_path(name: str) -> Path:
    """Path of a bundled scene, e.g. ``scene_path("hand_only")``."""
    path = SCENES_DIR / f"{name}.xml"
    if not path.is_file():
        known = sorted(p.stem for p in SCENES_DIR.glob("*.xml"))
        raise FileNotFoundError(f"no bundled scene '{name}'; bundled scenes: {known}")
    return path


def skin_geom_id(model, prefix: str = "") -> int:
    """Id of the hand's skin mesh geom (``prefix`` as given to ``MjSpec.attach``); ValueError if the
    model has no physhand hand."""
    import mujoco

    gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, prefix + SKIN_GEOM)
    if gid < 0:
        raise ValueError(f"the model has no geom '{prefix + SKIN_GEOM}': include mjcf/hand/myohand.xml in the "
                         f"scene (or pass the prefix used to attach it)")
    if model.geom_type[gid] != mujoco.mjtGeom.mjGEOM_MESH:
        raise ValueError(f"geom '{prefix + SKIN_GEOM}' must be a mesh geom")
    return gid


def set_skin_vertices(model, data, world_vertices: np.ndarray, faces: np.ndarray | None = None,
                      prefix: str = "") -> None:
    """Write world-frame skin vertices (n_skin, 3) into the model's skin mesh.

    MuJoCo stores a mesh in its own centred frame and places it with the geom pose, so the world
    vertices are mapped back through the geom's pose (``data.geom_xpos``/``geom_xmat`` after
    ``mj_kinematics``). The passive viewer shows the change after ``viewer.update_mesh(mesh_id)``,
    a ``mujoco.Renderer`` after ``mujoco.mjr_uploadMesh``, a Renderer created afterwards at once.
    """
    gid = skin_geom_id(model, prefix)
    mid = model.geom_dataid[gid]
    n = model.mesh_vertnum[mid]
    v = np.asarray(world_vertices, dtype=np.float64)
    if v.shape != (n, 3):
        raise ValueError(f"skin has {n} vertices, got an array of shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("skin vertices hold non-finite values")
    rot = data.geom_xmat[gid].reshape(3, 3)
    adr = model.mesh_vertadr[mid]
    local = (v - data.geom_xpos[gid]) @ rot
    model.mesh_vert[adr: adr + n] = local
    if faces is not None and model.mesh_normalnum[mid] == n:
        # area-weighted vertex normals; MuJoCo indexes normals per face corner (mesh_facenormal)
        f = np.asarray(faces)
        fn = np.cross(local[f[:, 1]] - local[f[:, 0]], local[f[:, 2]] - local[f[:, 0]])
        idx = f.ravel()
        w = np.repeat(fn, 3, axis=0)  # each face normal to its three corners (bincount: fast scatter-add)
        vn = np.stack([np.bincount(idx, w[:, k], minlength=n) for k in range(3)], axis=1)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
        nadr = model.mesh_normaladr[mid]
        model.mesh_normal[nadr: nadr + n] = vn


def rest_skin_world(model, data, asset) -> np.ndarray:
    """The asset's rest skin placed by the hand mount's current pose (valid in the rest pose)."""
    import mujoco

    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, MOUNT_BODY)
    if bid < 0:
        raise ValueError(f"the model has no body '{MOUNT_BODY}': include mjcf/hand/myohand.xml")
    return asset.skin_vertices @ data.xmat[bid].reshape(3, 3).T + data.xpos[bid]


def open_hand_scene(scene: str = "hand_only", keyframe: str = "open", asset=None):
    """Load a bundled scene at a keyframe with the asset's rest skin placed at the hand mount.

    Returns ``(asset, model, data)``. The rest skin matches the bones only in the rest keyframe
    (``open``) until the solver writes the deformed skin back.
    """
    import mujoco

    from physhand_mj.asset import load_asset

    asset = asset if asset is not None else load_asset()
    model = mujoco.MjModel.from_xml_path(str(scene_path(scene)))
    data = mujoco.MjData(model)
    kid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, keyframe)
    if kid < 0:
        known = [model.key(k).name for k in range(model.nkey)]
        raise ValueError(f"scene '{scene}' has no keyframe '{keyframe}'; it has {known}")
    mujoco.mj_resetDataKeyframe(model, data, kid)
    mujoco.mj_forward(model, data)
    set_skin_vertices(model, data, rest_skin_world(model, data, asset))
    return asset, model, data


def body_ids(model, names) -> np.ndarray:
    """MuJoCo body ids of ``names`` (e.g. ``asset.body_names``); ValueError listing the missing ones."""
    import mujoco

    ids = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, str(n)) for n in names])
    missing = [str(n) for n, i in zip(names, ids) if i < 0]
    if missing:
        raise ValueError(f"the MuJoCo model lacks the hand's bone bodies {missing}: include "
                         f"mjcf/hand/myohand.xml or build an asset for this model (physhand build-hand)")
    return ids


def enable_self_proxies(model, bones, on: bool = True) -> np.ndarray:
    """Turn on (``on``) or off the self proxies of the bodies ``bones`` (ids): each collision proxy's
    copy, of class ``self_proxy``, inert as shipped, then colliding with the other copies only
    (``SELF_PROXY_BIT``), with a margin of 2.5 mm each, so MuJoCo keeps two parts' bones from coming
    nearer than where their rest skins would meet over the proxies (docs/self_collision.md, "The
    bones keep the flesh's room"). MuJoCo's own rules still apply: a body and its parent do not
    collide. Edits ``model`` in place; returns the geom ids turned on (empty when turning off, or for
    a model without them, e.g. one built elsewhere)."""
    bodies = {int(b) for b in np.asarray(bones).reshape(-1)}
    ids = np.array([g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in bodies
                    and (model.geom(g).name or "").endswith(SELF_PROXY_SUFFIX)], dtype=int)
    # (shipped with the bit in contype only; MuJoCo also filters by body: its bodies' OR of their geoms')
    owners = model.geom_bodyid[ids]
    if on:
        model.geom_conaffinity[ids] |= SELF_PROXY_BIT
        model.body_conaffinity[owners] |= SELF_PROXY_BIT
        return ids
    model.geom_conaffinity[ids] &= ~SELF_PROXY_BIT
    model.body_conaffinity[owners] &= ~SELF_PROXY_BIT
    return np.zeros(0, dtype=int)


def set_proxy_margin(model, bones, margin: float | None) -> np.ndarray:
    """Give the object collision proxies of the bodies ``bones`` (ids; geoms named ``*_proxy``, MJCF
    class ``proxy``: the shipped hand's) MuJoCo contact margin ``margin`` (m), so MuJoCo stops a bone
    that much before its proxy meets an object: ``PROXY_INSET`` stops it about where the rest skin
    over the proxy would touch, leaving the flesh its room (docs/coupling.md "The bones keep the
    flesh's room"; the self proxies' rule, ``enable_self_proxies``, for objects). ``None``: the
    model is left as it is. Edits ``model`` in place; returns the geom ids set (empty for None, or a
    model without such proxies, e.g. one with a skin attached by ``add_skin``)."""
    if margin is None:
        return np.zeros(0, dtype=int)
    bodies = {int(b) for b in np.asarray(bones).reshape(-1)}
    ids = np.array([g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in bodies
                    and (model.geom(g).name or "").endswith(PROXY_SUFFIX)], dtype=int)
    model.geom_margin[ids] = float(margin)
    return ids


def body_poses(data, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions (B, 3) m and quaternions (B, 4) w x y z of bodies ``ids`` (after kinematics)."""
    return data.xpos[ids].copy(), data.xquat[ids].copy()


def mount_pose(model, data) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the hand mount (the asset's frame): position (3,) m, quaternion (4,) w x y z."""
    import mujoco

    bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, MOUNT_BODY)
    if bid < 0:
        raise ValueError(f"the model has no body '{MOUNT_BODY}': include mjcf/hand/myohand.xml")
    return data.xpos[bid].copy(), data.xquat[bid].copy()


def bone_poses_at(model, data, qpos: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Set ``data.qpos``, run MuJoCo's forward kinematics, return :func:`body_poses` of ``ids``."""
    import mujoco

    qpos = np.asarray(qpos, dtype=float)
    if qpos.shape != (model.nq,) or not np.all(np.isfinite(qpos)):
        raise ValueError(f"qpos must be {model.nq} finite values (rad / m), got shape {qpos.shape}")
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return body_poses(data, ids)
