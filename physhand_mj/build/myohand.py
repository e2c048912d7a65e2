"""Source data for the embedded hand: MyoHand's bones and kinematic chain from ``myo-sim``.

``myo_sim.build.compose.build_right_hand_from_arm_spec()`` (myo-sim, Apache-2.0) compiles the right
arm pruned to the hand: 23 joints from forearm pronation to the distal interphalangeal joints, and
one bone mesh per body (about 55k vertices over the hand). This module reads that compiled model
once, in a *rest pose with the fingers spread* (at MyoHand's qpos0 adjacent finger bones are only
4-5 mm apart, less than the two layers of soft tissue between them, so a skin built there would
merge the fingers). Everything is expressed in the *hand frame*: MyoHand's world orientation, origin
at the wrist (the lunate body's origin).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import trimesh

# Bodies kept from the arm model: a distal radius/ulna stub, carpals, metacarpals, phalanges.
HAND_BODIES = (
    "ulna_r", "radius_r", "lunate_r", "scaphoid_r", "pisiform_r", "triquetrum_r", "capitate_r",
    "trapezium_r", "firstmc_r", "proximal_thumb_r", "distal_thumb_r", "trapezoid_r", "hamate_r",
    "secondmc_r", "2proxph_r", "midph2_r", "distph2_r", "thirdmc_r", "3proxph_r", "midph3_r",
    "distph3_r", "fourthmc_r", "4proxph_r", "midph4_r", "distph4_r", "fifthmc_r", "5proxph_r",
    "midph5_r", "distph5_r",
)
FOREARM_BODIES = ("ulna_r", "radius_r")
CARPAL_BODIES = ("lunate_r", "scaphoid_r", "pisiform_r", "triquetrum_r", "capitate_r", "trapezium_r",
                 "trapezoid_r", "hamate_r")
METACARPAL_BODIES = ("secondmc_r", "thirdmc_r", "fourthmc_r", "fifthmc_r")
FINGER_CHAINS = {
    "thumb": ("proximal_thumb_r", "distal_thumb_r"),
    "index": ("2proxph_r", "midph2_r", "distph2_r"),
    "middle": ("3proxph_r", "midph3_r", "distph3_r"),
    "ring": ("4proxph_r", "midph4_r", "distph4_r"),
    "little": ("5proxph_r", "midph5_r", "distph5_r"),
}
# Rest pose (rad): MCP abduction spreads the fingers so the skin separates them distal to the web.
REST_QPOS = {"mcp2_abduction_r": 0.25, "mcp3_abduction_r": 0.05, "mcp4_abduction_r": -0.15,
             "mcp5_abduction_r": -0.25}
WRIST_BODY = "lunate_r"
STUB_START, STUB_LENGTH = 0.008, 0.025  # m: the radius/ulna shaft kept, measured from the wrist


@dataclass
class BodySpec:
    """One body of the kinematic chain, relative to its parent (MuJoCo conventions)."""

    name: str
    parent: str | None
    pos: np.ndarray
    quat: np.ndarray
    mass: float
    ipos: np.ndarray
    iquat: np.ndarray
    inertia: np.ndarray
    joints: list[dict] = field(default_factory=list)


@dataclass
class HandSource:
    """The MyoHand chain and bones in the rest pose, hand frame (metres)."""

    bodies: list[BodySpec]
    root_pos: np.ndarray               # hand-frame position of the first body (ulna_r) at qpos0
    root_quat: np.ndarray
    rest_qpos: dict[str, float]
    rest_xpos: dict[str, np.ndarray]   # body origin, hand frame, rest pose
    rest_xmat: dict[str, np.ndarray]   # body orientation (3x3), hand frame, rest pose
    bones_rest: dict[str, trimesh.Trimesh]  # closed bone mesh per body, hand frame, rest pose
    forearm_axis: np.ndarray           # unit vector from the wrist towards the elbow
    finger_axis: np.ndarray            # unit vector from the wrist towards the middle fingertip


def _geom_mesh(m: mujoco.MjModel, d: mujoco.MjData, g: int) -> trimesh.Trimesh:
    mid = m.geom_dataid[g]
    v = m.mesh_vert[m.mesh_vertadr[mid]: m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
    f = m.mesh_face[m.mesh_faceadr[mid]: m.mesh_faceadr[mid] + m.mesh_facenum[mid]]
    world = v @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    return trimesh.Trimesh(world, f, process=True)


def load_myohand(rest_qpos: dict[str, float] | None = None) -> HandSource:
    """Compile MyoHand from myo-sim and read its chain and bones in the spread rest pose."""
    try:
        from myo_sim.build.compose import build_right_hand_from_arm_spec
    except ImportError as e:  # pragma: no cover - exercised only without the build extra
        raise ImportError("building the MyoHand asset needs myo-sim: pip install -e '.[build]'") from e

    m = build_right_hand_from_arm_spec().compile()
    d = mujoco.MjData(m)
    rest = dict(REST_QPOS if rest_qpos is None else rest_qpos)
    for name, value in rest.items():
        d.qpos[m.joint(name).qposadr[0]] = value
    mujoco.mj_kinematics(m, d)
    origin = d.xpos[m.body(WRIST_BODY).id].copy()

    bodies = []
    for name in HAND_BODIES:
        b = m.body(name).id
        parent = m.body(m.body_parentid[b]).name
        joints = []
        for j in range(m.jnt_bodyid.size):
            if m.jnt_bodyid[j] != b:
                continue
            dof = m.jnt_dofadr[j]
            joints.append(dict(name=m.joint(j).name, type=int(m.jnt_type[j]), pos=m.jnt_pos[j].copy(),
                               axis=m.jnt_axis[j].copy(), range=m.jnt_range[j].copy(),
                               damping=float(m.dof_damping[dof]), armature=float(m.dof_armature[dof])))
        bodies.append(BodySpec(name=name, parent=parent if parent in HAND_BODIES else None,
                               pos=m.body_pos[b].copy(), quat=m.body_quat[b].copy(),
                               mass=float(m.body_mass[b]), ipos=m.body_ipos[b].copy(),
                               iquat=m.body_iquat[b].copy(), inertia=m.body_inertia[b].copy(),
                               joints=joints))

    # Root pose at qpos0 (the ulna does not move with any hand joint).
    d0 = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d0)
    root = m.body(HAND_BODIES[0]).id
    root_pos = d0.xpos[root] - d0.xpos[m.body(WRIST_BODY).id]
    root_quat = d0.xquat[root].copy()

    bones: dict[str, trimesh.Trimesh] = {}
    for g in range(m.ngeom):
        bname = m.body(m.geom_bodyid[g]).name
        if bname in HAND_BODIES and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH and m.geom_group[g] == 0:
            mesh = _geom_mesh(m, d, g)
            mesh.apply_translation(-origin)
            bones[bname] = mesh if bname not in bones else trimesh.util.concatenate([bones[bname], mesh])

    forearm_axis = d.xpos[m.body("ulna_r").id] - d.xpos[m.body(WRIST_BODY).id]
    forearm_axis /= np.linalg.norm(forearm_axis)
    tip = bones["distph3_r"].vertices
    finger_axis = tip.mean(axis=0) / np.linalg.norm(tip.mean(axis=0))

    # Keep a short shaft of the forearm bones (convex, so closed), clear of the radiocarpal joint.
    for name in FOREARM_BODIES:
        cut = trimesh.intersections.slice_mesh_plane(
            bones[name], plane_normal=[-forearm_axis, forearm_axis],
            plane_origin=[forearm_axis * STUB_LENGTH, forearm_axis * STUB_START], cap=False)
        stub = cut.convex_hull
        # Slimmed about its centroid: the full-width shafts touch at the distal radioulnar joint.
        stub.apply_transform(trimesh.transformations.scale_matrix(0.8, stub.centroid))
        bones[name] = stub

    rest_xpos = {n: d.xpos[m.body(n).id] - origin for n in HAND_BODIES}
    rest_xmat = {n: d.xmat[m.body(n).id].reshape(3, 3).copy() for n in HAND_BODIES}
    return HandSource(bodies=bodies, root_pos=root_pos, root_quat=root_quat, rest_qpos=rest,
                      rest_xpos=rest_xpos, rest_xmat=rest_xmat, bones_rest=bones,
                      forearm_axis=forearm_axis, finger_axis=finger_axis)


def palm_normal(src) -> np.ndarray:
    """Unit vector out of the palm: the way fingertips move when the fingers flex (hand frame)."""
    # Flexion moves the tip towards the palm: compare the middle-finger tip at rest and flexed.
    flexed = load_myohand({**src.rest_qpos, "mcp3_flexion_r": 0.6})
    d = flexed.bones_rest["distph3_r"].vertices.mean(0) - src.bones_rest["distph3_r"].vertices.mean(0)
    d -= src.finger_axis * (d @ src.finger_axis)
    return d / np.linalg.norm(d)


def mount_quat(finger_axis: np.ndarray, palm_normal: np.ndarray) -> np.ndarray:
    """Mount orientation that points the fingers along world +x with the palm facing down (-z)."""
    from scipy.spatial.transform import Rotation

    x = finger_axis
    n = np.asarray(palm_normal, dtype=float)
    n = n - x * (n @ x)
    n /= np.linalg.norm(n)
    hand = np.stack([x, np.cross(-n, x), -n], axis=1)  # columns: hand-frame images of world x, y, z
    q = Rotation.from_matrix(hand.T).as_quat()  # x y z w
    return np.array([q[3], q[0], q[1], q[2]])

