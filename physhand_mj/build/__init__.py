"""The layered-body builder (``physhand build-hand``; needs the ``build`` extra).

:func:`build_myohand` regenerates the embedded hand (asset ``.npz`` + hand MJCF) from myo-sim;
:func:`build_from_meshes` takes a user's skin mesh and bone meshes named after MuJoCo bodies.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import trimesh

from physhand_mj.asset import HandAsset, save_asset, validate_asset
from physhand_mj.build.layered import BuildError, TetOptions, assemble

__all__ = ["BuildError", "TetOptions", "build_from_meshes", "build_myohand", "quality_figures"]
log = logging.getLogger(__name__)

# Soft-tissue thickness (m) over each part of the implicit MyoHand skin.
MYOHAND_THICKNESS = {"forearm": 5.0e-3, "palm": 6.0e-3, "thenar": 5.5e-3, "thumb": 4.5e-3,
                     "index": 4.0e-3, "middle": 4.0e-3, "ring": 4.0e-3, "little": 3.5e-3}


def quality_figures(arrays: dict) -> dict:
    """Tet and skin quality figures, prefixed ``q_`` (lengths in mm, volumes in mm^3, angles in deg)."""
    from physhand_mj.build import derive

    x, tets = arrays["positions"], arrays["tets"]
    dih = derive.tet_min_dihedral_deg(x, tets)
    f = arrays["skin_faces"]
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    le = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) * 1e3
    return dict(q_tet_min_dihedral_deg=float(dih.min()), q_tet_dihedral_p1_deg=float(np.percentile(dih, 1)),
                q_tet_frac_below_5deg=float(np.mean(dih < 5.0)), q_tet_min_volume_mm3=float(arrays["tet_rest_volume"].min() * 1e9),
                q_skin_edge_mean_mm=float(le.mean()), q_skin_edge_p5_mm=float(np.percentile(le, 5)),
                q_skin_edge_p95_mm=float(np.percentile(le, 95)),
                q_bone_skin_clearance_mm=float(arrays.pop("bone_skin_clearance") * 1e3))


def build_from_meshes(skin: trimesh.Trimesh, bones: dict[str, trimesh.Trimesh],
                      body_rest_pose: dict[str, tuple[np.ndarray, np.ndarray]], *,
                      rigid_groups: list[list[str]] | None = None, skeleton_vertices: int = 3300,
                      tet: TetOptions = TetOptions(), density: float = 1100.0,
                      rest_qpos: dict[str, float] | None = None, meta: dict | None = None) -> HandAsset:
    """Build a layered body from a closed skin and bone meshes (all in one frame, metres).

    Args:
      skin: closed, outward skin surface (vertices are kept as given: remesh beforehand).
      bones: closed bone mesh per MuJoCo body name, in the skin's frame, strictly inside the skin.
      body_rest_pose: per body, ``(pos (3,), quat wxyz (4,))`` of the body frame in that frame.
      rigid_groups: lists of bodies welded together; their bones are fused into one surface.
      skeleton_vertices: total bone-surface vertex budget.
      tet: TetGen quality options.
      density: soft-tissue density (kg/m^3), 1100 for hand flesh.
      rest_qpos: joint values (rad) of the pose the meshes are in.
      meta: extra facts stored in the asset.
    """
    missing = [b for b in bones if b not in body_rest_pose]
    if missing:
        raise BuildError(f"no rest pose given for bodies {missing}")
    t0 = time.perf_counter()
    arrays = assemble(skin, bones, rigid_groups=rigid_groups, skeleton_vertices=skeleton_vertices,
                      tet=tet, density=density)
    names = list(arrays["body_names"])
    q = quality_figures(arrays)
    rest_qpos = rest_qpos or {}
    asset = HandAsset(
        **arrays,
        body_rest_pos=np.array([body_rest_pose[n][0] for n in names], dtype=np.float64).reshape(-1, 3),
        body_rest_quat=np.array([body_rest_pose[n][1] for n in names], dtype=np.float64).reshape(-1, 4),
        rest_qpos_names=np.array(list(rest_qpos), dtype=str), rest_qpos=np.array(list(rest_qpos.values()), dtype=np.float64),
        meta={**(meta or {}), **q, "build_seconds_tets": round(time.perf_counter() - t0, 2)},
    )
    validate_asset(asset, "built asset")
    return asset


def build_myohand(asset_path: str | Path, mjcf_path: str | Path | None = None, *, skin_vertices: int = 5000,
                  skeleton_vertices: int = 3300, spacing: float = 1.0e-3) -> HandAsset:
    """Regenerate the embedded MyoHand asset (and, if ``mjcf_path`` is given, its MJCF).

    Deterministic: the same myo-sim and tool versions give the same arrays.
    """
    from scipy.spatial.transform import Rotation
    from tqdm import tqdm

    from physhand_mj.build import myohand as mh
    from physhand_mj.build.layered import close_mesh
    from physhand_mj.build.skin import SkinPart, extract_surface, implicit_skin_field, remesh_uniform

    t0 = time.perf_counter()
    steps = tqdm(total=5, desc="build-hand", unit="step")
    steps.set_postfix_str("MyoHand from myo-sim")
    src = mh.load_myohand()
    bones = {n: close_mesh(m, n) for n, m in src.bones_rest.items()}
    steps.update()

    def hull(names):
        return trimesh.util.concatenate([bones[n] for n in names]).convex_hull

    th = MYOHAND_THICKNESS
    parts = [SkinPart("forearm", hull([*mh.FOREARM_BODIES, "lunate_r", "scaphoid_r", "triquetrum_r", "pisiform_r"]), th["forearm"]),
             SkinPart("palm", hull([*mh.CARPAL_BODIES, *mh.METACARPAL_BODIES]), th["palm"]),
             SkinPart("thenar", hull(["firstmc_r", "trapezium_r", "secondmc_r"]), th["thenar"])]
    parts += [SkinPart(f, trimesh.util.concatenate([bones[n] for n in chain]), th[f]) for f, chain in mh.FINGER_CHAINS.items()]
    steps.set_postfix_str("implicit skin")
    field, origin, h = implicit_skin_field(parts, spacing=spacing, blend=3.0e-3,
                                           clip_plane=(src.forearm_axis * (mh.STUB_LENGTH + 4e-3), src.forearm_axis))
    skin = remesh_uniform(extract_surface(field, origin, h), skin_vertices)
    steps.update()
    steps.set_postfix_str("bones + TetGen")
    pose = {n: (src.rest_xpos[n], _wxyz(Rotation.from_matrix(src.rest_xmat[n]).as_quat())) for n in mh.HAND_BODIES}
    tip = skin.vertices @ src.finger_axis
    palm_normal = mh.palm_normal(src)
    meta = dict(name="myohand", source="MyoHand bones and kinematic chain from myo-sim (Apache-2.0)",
                myo_sim_version=_version("myo-sim"), mujoco_version=_version("mujoco"),
                thickness_m=th, grid_spacing_m=spacing, hand_length_mm=float(tip.max() * 1e3),
                finger_axis=src.finger_axis.tolist(), forearm_axis=src.forearm_axis.tolist(),
                palm_normal=palm_normal.tolist())
    asset = build_from_meshes(skin, bones, pose, rigid_groups=[[*mh.CARPAL_BODIES, *mh.METACARPAL_BODIES]],
                              skeleton_vertices=skeleton_vertices, rest_qpos=src.rest_qpos, meta=meta)
    steps.update()
    asset.meta["build_seconds"] = round(time.perf_counter() - t0, 1)
    save_asset(asset, asset_path)
    steps.update()
    if mjcf_path is not None:
        steps.set_postfix_str("MJCF")
        from physhand_mj.build.mjcf import write_hand_mjcf

        mount_quat = mh.mount_quat(src.finger_axis, palm_normal)
        write_hand_mjcf(src, asset, mjcf_path, mount_quat=mount_quat)
        from physhand_mj.build.scenes import write_hand_only_scene

        mjcf_path = Path(mjcf_path)
        write_hand_only_scene(mjcf_path, mjcf_path.parent.parent / "scenes" / "hand_only.xml", src.rest_qpos)
    steps.update()
    steps.close()
    log.info("built %s", json.dumps(asset.summary()))
    return asset


def _wxyz(xyzw):
    x, y, z, w = xyzw
    return np.array([w, x, y, z])


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "unknown"
