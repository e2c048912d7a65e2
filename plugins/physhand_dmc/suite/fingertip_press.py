"""fingertip_press: press the index fingertip on a fixed plate to a target normal force.

The hand is palm down (``mjcf/scenes/hand_only.xml``'s mount, keyframe ``open``) with the index
finger flexed to ``TOUCH`` (rad); the plate's top (a 40 x 40 x 10 mm box, colliding with the hand's
proxies) is placed where that pose's rest skin of the index fingertip is lowest, so flexing the
index further presses the soft pad into the plate. The force is the soft skin's contact normal force
estimate on the plate (SoftHand), not MuJoCo's proxy contact force.

Each episode draws the target force uniformly from ``force_range`` (N, default 0.1-0.25) with the
task's RNG; it is observed as ``target_force``. The skin's estimate saturates near 0.25 N: past that
the capsule proxy inside the fingertip meets the plate and MuJoCo stops the finger (measured on the
CPU flexing the index 0.15 rad past the touch pose).

Reward (in [0, 1]): ``on_target * no_penetration`` with ``on_target`` = 1 within
``force_tolerance`` N of the target (Gaussian tail to 0.1 at a further 0.5 target) and
``no_penetration`` as in hand_hold.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from dm_control.mujoco import wrapper
from dm_control.utils import containers, rewards

from physhand_dmc.physics import SoftPhysics
from physhand_dmc.sensing import regions, rigid_skin
from physhand_dmc.batch_physics import BatchPhysics
from physhand_dmc.task import SoftTask, batch_config, check_positive, make_environment, solver_config
from physhand_dmc.batch_task import BatchTask
from physhand_mj.asset import load_asset
from physhand_mj.hand_mjcf import SCENES_DIR, body_ids

XML = Path(__file__).with_suffix(".xml")
TOUCH = {"mcp2_flexion_r": 0.35, "pm2_flexion_r": 0.35, "md2_flexion_r": 0.2}  # rad: the index at the plate
_DEFAULT_TIME_LIMIT = 1.0  # s
_CONTROL_TIMESTEP = 0.01  # s

SUITE = containers.TaggedTasks()


def build_model() -> mujoco.MjModel:
    """The domain XML with the plate under the index fingertip and the keyframe ``touch``."""
    hand_only = mujoco.MjModel.from_xml_path(str(SCENES_DIR / "hand_only.xml"))
    spec = mujoco.MjSpec.from_file(str(XML))
    key = hand_only.key("open")
    qpos, ctrl = key.qpos.copy(), key.ctrl.copy()
    probe = spec.compile()
    for name, q in TOUCH.items():
        j = probe.joint(name).id
        qpos[probe.jnt_qposadr[j]] = q
        ctrl[probe.actuator(name + "_act").id] = q
    data = mujoco.MjData(probe)
    data.mocap_pos[0], data.mocap_quat[0] = key.mpos, key.mquat
    data.qpos[:] = qpos
    mujoco.mj_kinematics(probe, data)
    asset = load_asset()
    bones = body_ids(probe, [str(b) for b in asset.body_names])
    skin = rigid_skin(asset, data.xpos[bones], data.xquat[bones])
    names, region = regions(asset)
    tip = skin[region == names.index("index_tip")]
    low = tip[np.argmin(tip[:, 2])]
    plate = spec.body("plate")
    plate.pos = [low[0], low[1], low[2] - 0.005]  # the box's half height below the lowest tip point
    spec.add_key(name="touch", qpos=qpos.tolist(), ctrl=ctrl.tolist(), mpos=key.mpos.tolist(),
                 mquat=key.mquat.tolist())
    return spec.compile()


class Press(SoftTask):
    """Reach and hold a target soft-contact normal force on the plate with the index fingertip."""

    def __init__(self, random=None, settle_frames: int = 20, force_range=(0.1, 0.25), force_tolerance: float = 0.03):
        super().__init__(random=random, settle_frames=settle_frames)
        lo, hi = (check_positive("force_range[0]", force_range[0], "N"),
                  check_positive("force_range[1]", force_range[1], "N"))
        if lo > hi:
            raise ValueError(f"force_range must be (low, high) N with low <= high, got {force_range!r}")
        self.force_range = (lo, hi)
        self.force_tolerance = check_positive("force_tolerance", force_tolerance, "N")
        self.target = lo

    def initialize_episode(self, physics):
        m, d = physics.model, physics.data
        mujoco.mj_resetDataKeyframe(m.ptr, d.ptr, 0)
        self.target = float(self.random.uniform(*self.force_range))
        self.finish_reset(physics)
        super().initialize_episode(physics)

    def _task_observations(self, physics, obs):
        d = physics.data
        obs["joint_pos"] = d.qpos.copy()
        obs["joint_vel"] = d.qvel.copy()
        obs["target_force"] = np.array([self.target])

    def get_reward(self, physics):
        force = float(physics.soft.sensor.obj_host[0, 1])
        depth = float(physics.soft._last.get("penetration_max_um", 0.0)) * 1e-3
        return float(press_reward(force, self.target, self.force_tolerance, depth))


def press_reward(force, target, tolerance: float, depth_mm):
    """``on_target * no_penetration`` (see the module docstring) of soft-contact forces ``force`` N,
    targets ``target`` N and deepest penetrations ``depth_mm``: scalars or (W,) arrays alike (the
    single task and the batched one share it)."""
    force, target, depth_mm = np.asarray(force, float), np.asarray(target, float), np.asarray(depth_mm, float)
    out = (force - (target + tolerance)).clip(0) + ((target - tolerance) - force).clip(0)  # distance from the band
    scale = np.sqrt(-2 * np.log(0.1))  # dm_control's gaussian tolerance: 0.1 at one margin
    on = np.exp(-0.5 * (out / (0.5 * target) * scale) ** 2)
    return on * rewards.tolerance(depth_mm, bounds=(0.0, 0.05), margin=1.0)


class BatchPress(BatchTask):
    """:class:`Press` on W worlds (physhand_dmc.vector): the same episodes, observations and reward."""

    def __init__(self, physics, settle_frames: int = 20, force_range=(0.1, 0.25), force_tolerance: float = 0.03):
        super().__init__(physics, settle_frames)
        probe = Press(force_range=force_range, force_tolerance=force_tolerance, settle_frames=settle_frames)  # (checks)
        self.force_range, self.force_tolerance = probe.force_range, probe.force_tolerance
        self.target = np.full(physics.worlds, self.force_range[0])

    def initialize_episodes(self, mask):
        p = self.physics
        p.reset_keyframe(0, mask)
        for w in np.flatnonzero(mask):  # (each world's own RNG, drawn as the single task draws)
            self.target[w] = self.random[w].uniform(*self.force_range)
        p.restart_soft(self.settle_frames)

    def task_observations(self, obs):
        obs["joint_pos"] = self.physics.host("qpos")
        obs["joint_vel"] = self.physics.host("qvel")
        obs["target_force"] = self.target[:, None].copy()

    def rewards(self):
        p = self.physics
        p.sync()  # (the sensor's pinned host rows: their copies complete)
        force = p.sensor.obj_host.reshape(p.worlds, -1, 3)[:, 0, 1].astype(float)
        return press_reward(force, self.target, self.force_tolerance, self.depth_mm())


def batch_task(task, num_envs, device=None, *, time_limit=_DEFAULT_TIME_LIMIT, settle_frames=20,
               force_range=(0.1, 0.25), force_tolerance=0.03, config=None, control_timestep=_CONTROL_TIMESTEP):
    """The batched ``index`` task (physhand_dmc.vector.load_batch): (BatchPress, time_limit, control_timestep)."""
    check_positive("time_limit", time_limit, "s"), check_positive("control_timestep", control_timestep, "s")
    model = build_model()
    cfg = batch_config(config, float(model.opt.timestep), device)
    physics = BatchPhysics(model, num_envs, cfg, object_bodies=["plate"])
    return BatchPress(physics, settle_frames, force_range, force_tolerance), time_limit, control_timestep


def make_physics(config) -> SoftPhysics:
    model = build_model()
    physics = SoftPhysics.from_model(wrapper.MjModel(model))
    physics.reset(0)
    physics.make_soft(solver_config(config, float(model.opt.timestep)), object_bodies=["plate"])
    return physics


@SUITE.add("benchmarking", "press")
def index(time_limit=_DEFAULT_TIME_LIMIT, random=None, environment_kwargs=None, *, settle_frames=20,
          force_range=(0.1, 0.25), force_tolerance=0.03, config=None, control_timestep=_CONTROL_TIMESTEP):
    """Press the index fingertip on the plate to a target force."""
    check_positive("time_limit", time_limit, "s"), check_positive("control_timestep", control_timestep, "s")
    task = Press(random=random, settle_frames=settle_frames, force_range=force_range, force_tolerance=force_tolerance)
    physics = make_physics(config)
    return make_environment(physics, task, time_limit, control_timestep, environment_kwargs)
