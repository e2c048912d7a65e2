"""Soft fingertip pads on a robot gripper: the Kinova Jaco hand shipped with dm-control.

The pads are a layered asset built by ``physhand_mj.build.pads.build_pads`` around the three
fingertip links (shipped as ``assets/jaco_pads.npz``); the scene is built with ``mujoco.MjSpec``
from dm-control's ``jaco_hand.xml``: the pads' skin mesh geom (named like the hand's, so the same
``SoftHand`` drives it), a position actuator per finger joint, and an object between the fingers.
Nothing here is hand-specific: ``SoftHand(model, data, asset=pads)`` is the same coupling.
"""

from __future__ import annotations

from pathlib import Path


PADS_ASSET = Path(__file__).parent / "assets" / "jaco_pads.npz"
PAD_BODIES = ("b_finger_tip_1", "b_finger_tip_2", "b_finger_tip_3")
FINGER_JOINTS = ("finger_1", "finger_2", "finger_3")


def jaco_hand_xml() -> Path:
    import dm_control

    path = Path(dm_control.__file__).parent / "third_party" / "kinova" / "jaco_hand.xml"
    if not path.is_file():
        raise FileNotFoundError(f"dm-control has no Jaco hand at {path}; install dm-control>=1.0.50")
    return path


def jaco_pads_scene(object_radius: float = 0.025, object_half_height: float = 0.04, kp: float = 10.0):
    """(model, data, pads asset): the Jaco hand with soft fingertip pads around a static cylinder at
    its grip site; ``data.ctrl`` holds closing targets (rad), so stepping MuJoCo closes the fingers."""
    import mujoco

    from physhand_mj.asset import load_asset
    from physhand_mj.hand_mjcf import SKIN_GEOM

    pads = load_asset(PADS_ASSET)
    spec = mujoco.MjSpec.from_file(str(jaco_hand_xml()))
    spec.add_mesh(name=SKIN_GEOM, uservert=pads.skin_vertices.ravel().tolist(),
                  userface=pads.skin_faces.ravel().tolist())
    spec.worldbody.add_geom(name=SKIN_GEOM, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=SKIN_GEOM, contype=0,
                            conaffinity=0, group=2, density=0, rgba=[0.87, 0.68, 0.58, 1])
    for j in FINGER_JOINTS:
        act = spec.add_actuator(name=f"{j}_act", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=kp)
    spec.worldbody.add_light(pos=[0, -0.4, 0.6], dir=[0, 0.4, -0.6], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    probe = spec.compile()
    pdata = mujoco.MjData(probe)
    mujoco.mj_forward(probe, pdata)
    grip = pdata.site_xpos[probe.site("gripsite").id].copy()
    body = spec.worldbody.add_body(name="object", pos=grip)
    body.add_geom(name="object", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[object_radius, object_half_height, 0],
                  rgba=[0.3, 0.6, 0.9, 0.6])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    data.ctrl[:] = 1.2  # closing targets (rad) inside the joints' 0.15-1.35 range
    return model, data, pads
