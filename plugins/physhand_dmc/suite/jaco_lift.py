"""jaco_lift: the Kinova Jaco hand with soft fingertip pads grasps a free cylinder and lifts it.

The hand (dm-control's ``jaco_hand.xml``, pointing down, names prefixed ``jaco/``) hangs from a
carriage that slides along z (position actuator ``lift_act``, m); each finger has a position
actuator (rad, ``0.15-1.35``). The pads are ``physhand_mj/assets/jaco_pads.npz`` (SoftHand with the
pads asset, as in ``examples/jaco_pads.py``); MuJoCo's finger geoms push the cylinder (0.1 kg,
r 25 mm, 100 mm tall), the pads deform against it. Each episode moves the cylinder by up to
``object_jitter`` (m) in x and y (task RNG); the fingers start open, the carriage at 0.

Reward (in [0, 1]): ``(0.3 * firm + 0.7 * firm * lifted) * no_penetration``: ``firm`` = 1 from
``min_force`` N of pad normal force on the cylinder (linear below), ``lifted`` = 1 once the
cylinder is ``lift_height`` m above its start (linear below), ``no_penetration`` as in hand_hold.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from dm_control.mujoco import wrapper
from dm_control.utils import containers, rewards

from physhand_dmc.physics import SoftPhysics
from physhand_dmc.task import SoftTask, check_nonneg, check_positive, make_environment, solver_config
from physhand_mj.asset import load_asset
from physhand_mj.hand_mjcf import SKIN_GEOM
from physhand_mj.robots import FINGER_JOINTS, PADS_ASSET, jaco_hand_xml

XML = Path(__file__).with_suffix(".xml")
PREFIX = "jaco/"
_DEFAULT_TIME_LIMIT = 2.0  # s
_CONTROL_TIMESTEP = 0.01  # s

SUITE = containers.TaggedTasks()


def build_model(pads) -> mujoco.MjModel:
    """The domain XML with the Jaco hand (pointing down, pads' skin geom, finger actuators) attached
    under ``carriage``."""
    jaco = mujoco.MjSpec.from_file(str(jaco_hand_xml()))
    jaco.body("hand").quat = [1, 0, 0, 0]  # grip site along -z: the fingers point down
    for b in jaco.bodies:
        b.gravcomp = 1.0
    jaco.add_mesh(name=SKIN_GEOM, uservert=pads.skin_vertices.ravel().tolist(),
                  userface=pads.skin_faces.ravel().tolist())
    jaco.worldbody.add_geom(name=SKIN_GEOM, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=SKIN_GEOM, contype=0,
                            conaffinity=0, group=2, density=0, rgba=[0.87, 0.68, 0.58, 1])
    for j in FINGER_JOINTS:
        act = jaco.add_actuator(name=f"{j}_act", target=j, trntype=mujoco.mjtTrn.mjTRN_JOINT, ctrlrange=[0.15, 1.35])
        act.set_to_position(kp=10.0)
    spec = mujoco.MjSpec.from_file(str(XML))
    spec.attach(jaco, frame=spec.body("carriage").add_frame(), prefix=PREFIX)
    return spec.compile()


class Lift(SoftTask):
    """Grasp the cylinder with the soft pads and lift it."""

    def __init__(self, random=None, settle_frames: int = 5, object_jitter: float = 0.005, min_force: float = 1.0,
                 lift_height: float = 0.05):
        super().__init__(random=random, settle_frames=settle_frames)
        self.object_jitter = check_nonneg("object_jitter", object_jitter, "m")
        self.min_force = check_positive("min_force", min_force, "N")
        self.lift_height = check_positive("lift_height", lift_height, "m")
        self._start = np.zeros(3)

    def bind(self, physics):
        m = physics.model
        j = m.name2id("object_free", "joint")
        self._qadr, self._vadr = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        self._hand_q = np.array([i for i in range(m.nq) if not self._qadr <= i < self._qadr + 7])
        self._hand_v = np.array([i for i in range(m.nv) if not self._vadr <= i < self._vadr + 6])

    def initialize_episode(self, physics):
        m, d = physics.model, physics.data
        self._bind_once(physics)
        mujoco.mj_resetData(m.ptr, d.ptr)
        for name in FINGER_JOINTS:
            d.qpos[m.jnt_qposadr[m.name2id(PREFIX + name, "joint")]] = 0.15  # open
        d.qpos[self._qadr: self._qadr + 2] += self.random.uniform(-self.object_jitter, self.object_jitter, 2)
        d.ctrl[:] = d.qpos[m.jnt_qposadr[m.actuator_trnid[:, 0]]]
        self._start = d.qpos[self._qadr: self._qadr + 3].copy()
        self.finish_reset(physics)
        super().initialize_episode(physics)

    def _task_observations(self, physics, obs):
        d = physics.data
        obs["joint_pos"] = d.qpos[self._hand_q].copy()
        obs["joint_vel"] = d.qvel[self._hand_v].copy()
        self.free_object_observations(physics, obs)

    def get_reward(self, physics):
        d = physics.data
        force = float(physics.soft.sensor.obj_host[0, 1])
        firm = rewards.tolerance(force, bounds=(self.min_force, np.inf), margin=self.min_force, sigmoid="linear",
                                 value_at_margin=0.0)
        rise = float(d.qpos[self._qadr + 2] - self._start[2])
        lifted = rewards.tolerance(rise, bounds=(self.lift_height, np.inf), margin=self.lift_height,
                                   sigmoid="linear", value_at_margin=0.0)
        return float((0.3 * firm + 0.7 * firm * lifted) * self.no_penetration(physics))


def make_physics(config) -> SoftPhysics:
    pads = load_asset(PADS_ASSET)
    model = build_model(pads)
    physics = SoftPhysics.from_model(wrapper.MjModel(model))
    physics.reset()
    physics.make_soft(solver_config(config, float(model.opt.timestep)), asset=pads, prefix=PREFIX,
                       object_bodies=["object"])
    return physics


@SUITE.add("benchmarking", "robot")
def lift(time_limit=_DEFAULT_TIME_LIMIT, random=None, environment_kwargs=None, *, settle_frames=5,
         object_jitter=0.005, min_force=1.0, lift_height=0.05, config=None, control_timestep=_CONTROL_TIMESTEP):
    """Grasp the cylinder with the soft-padded Jaco hand and lift it by lift_height (m)."""
    check_positive("time_limit", time_limit, "s"), check_positive("control_timestep", control_timestep, "s")
    task = Lift(random=random, settle_frames=settle_frames, object_jitter=object_jitter, min_force=min_force,
                lift_height=lift_height)
    physics = make_physics(config)
    return make_environment(physics, task, time_limit, control_timestep, environment_kwargs)
