"""``SoftTask``: what the suite's tasks share (actions, soft-contact observations, reward terms).

- Actions: one per actuator, normalised to [-1, 1]; ``ctrl = centre + a * half_range`` of the
  actuator's ctrlrange (clipped), i.e. -1 / +1 are the range's ends (position targets, rad or m).
- Soft observations (all float64, from :class:`~physhand_dmc.sensing.SoftSensor`'s host buffers and
  the frame's metrics, no extra device sync):
    ``region_contact`` (R, 4): per hand region [contact area cm^2, normal force N, contacting skin
    vertices, largest deformation mm];
    ``object_contact`` (4,): the task object's [contact area cm^2, normal force N, penetrating
    skin samples (the paper's 21-sample metric), deepest penetration mm].
- Randomness only from ``self.random`` (``task_kwargs={"random": seed}``).
"""

from __future__ import annotations

import collections
import time

import numpy as np
from dm_control.rl import control
from dm_control.suite import base
from dm_env import specs

from physhand_mj import Config, Settings


def check_positive(name: str, value, unit: str) -> float:
    if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0 ({unit}), got {value!r}")
    return float(value)


def check_nonneg(name: str, value, unit: str) -> float:
    if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0 ({unit}), got {value!r}")
    return float(value)


def solver_config(config, timestep: float) -> Config:
    """The soft hand's Config: a frame is one MuJoCo step (``frame_dt`` = the model's timestep)."""
    if config is None:
        config = Config(frame_dt=timestep)
    if not isinstance(config, (Config, Settings)):
        raise TypeError(f"config must be a physhand_mj.Config, got {type(config).__name__}")
    if abs(config.frame_dt - timestep) > 1e-12:
        raise ValueError(f"Config.frame_dt ({config.frame_dt} s) must equal the domain's MuJoCo timestep "
                         f"({timestep} s): one solver frame runs per MuJoCo step")
    return config.validate()


def batch_config(config, timestep: float, device) -> Config:
    """:func:`solver_config` for a batch (physhand_dmc.vector) on ``device`` (None: the config's, else
    Warp's default); a batch's worlds reset themselves when their skin turns non-finite
    (``NonFinite.RECOVER``: BatchedHands needs it)."""
    import dataclasses

    from physhand_mj.types import NonFinite

    import warp as wp

    cfg = solver_config(config, timestep)
    # a device by name (None: Warp's default): the batch's objects, solver and MuJoCo Warp on one
    dev = str(wp.get_device(device if device is not None else cfg.device))
    return dataclasses.replace(cfg, device=dev, nonfinite=NonFinite.RECOVER).validate()


class SoftTask(base.Task):
    """Base of the suite's tasks. Subclasses set ``self._actuators`` (ids, or None for all) in
    ``initialize_episode`` or ``__init__`` and implement ``_task_observations`` and ``get_reward``."""

    def __init__(self, random=None, settle_frames: int = 20):
        if not (isinstance(settle_frames, (int, np.integer)) and settle_frames >= 1):
            raise ValueError(f"settle_frames must be an integer >= 1 (solver frames), got {settle_frames!r}")
        super().__init__(random=random)
        self.settle_frames = int(settle_frames)
        self.obs_seconds = 0.0
        self.obs_calls = 0

    # -- actions ---------------------------------------------------------------------------------
    def action_spec(self, physics):
        nu = physics.model.nu
        names = "\t".join(physics.model.id2name(i, "actuator") for i in range(nu))
        return specs.BoundedArray(shape=(nu,), dtype=np.float64, minimum=-np.ones(nu), maximum=np.ones(nu),
                                  name=names)

    def before_step(self, action, physics):
        lo, hi = physics.model.actuator_ctrlrange.T
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        physics.set_control(0.5 * (lo + hi) + a * 0.5 * (hi - lo))

    @staticmethod
    def normalise_ctrl(physics, ctrl) -> np.ndarray:
        """The action that commands ``ctrl`` (inverse of ``before_step``'s mapping)."""
        lo, hi = physics.model.actuator_ctrlrange.T
        return np.clip((np.asarray(ctrl, float) - 0.5 * (lo + hi)) / (0.5 * (hi - lo)), -1.0, 1.0)

    # -- episodes --------------------------------------------------------------------------------
    _bound = False

    def bind(self, physics) -> None:
        """Index arrays into the physics (subclasses); runs once, before the first reset or observation."""

    def _bind_once(self, physics) -> None:
        if not self._bound:
            self.bind(physics)
            self._bound = True

    def finish_reset(self, physics) -> None:
        """Call at the end of ``initialize_episode``: kinematics of the new pose, soft tissue reset."""
        physics.forward()
        physics.reset_soft(self.settle_frames)

    # -- observations ----------------------------------------------------------------------------
    def free_object_observations(self, physics, obs) -> None:
        """The free object's pose and velocity (its joint at ``self._qadr`` / ``self._vadr``) into
        ``obs``: offset from its episode start ``self._start`` (m), quaternion, 6-D velocity."""
        d = physics.data
        obs["object_offset"] = d.qpos[self._qadr: self._qadr + 3] - self._start
        obs["object_quat"] = d.qpos[self._qadr + 3: self._qadr + 7].copy()
        obs["object_vel"] = d.qvel[self._vadr: self._vadr + 6].copy()

    def get_observation(self, physics):
        t0 = time.perf_counter()
        obs = collections.OrderedDict()
        self._bind_once(physics)
        self._task_observations(physics, obs)
        hand = physics.soft
        s = hand.sensor
        reg = s.region_host
        region = np.empty((reg.shape[0], 4))
        region[:, 0] = reg[:, 0] * 1e4  # m^2 -> cm^2
        region[:, 1:3] = reg[:, 1:3]
        region[:, 3] = reg[:, 3] * 1e3  # m -> mm
        obs["region_contact"] = region
        obs["object_contact"] = self.object_contact(physics)
        self.obs_seconds += time.perf_counter() - t0
        self.obs_calls += 1
        return obs

    @staticmethod
    def object_contact(physics) -> np.ndarray:
        """[contact area cm^2, normal force N, penetrating samples, deepest penetration mm] of the
        task's object (the only object the soft hand collides with)."""
        hand = physics.soft
        o = hand.sensor.obj_host[0]
        last = hand._last  # the frame's metrics row, read at the solver's one sync
        return np.array([o[0] * 1e4, o[1], float(last.get("penetration_count", 0)),
                         float(last.get("penetration_max_um", 0.0)) * 1e-3])

    def _task_observations(self, physics, obs) -> None:
        raise NotImplementedError

    # -- reward terms ----------------------------------------------------------------------------
    @staticmethod
    def no_penetration(physics, tolerance_mm: float = 0.05, margin_mm: float = 1.0) -> float:
        """1 while the skin's deepest penetrating sample is within ``tolerance_mm``, falling to 0.1 at
        ``tolerance_mm + margin_mm`` (a Gaussian tail)."""
        from dm_control.utils import rewards

        depth = float(physics.soft._last.get("penetration_max_um", 0.0)) * 1e-3
        return float(rewards.tolerance(depth, bounds=(0.0, tolerance_mm), margin=margin_mm))


def make_environment(physics, task, time_limit: float, control_timestep: float, environment_kwargs):
    kwargs = dict(environment_kwargs or {})
    kwargs.setdefault("time_limit", check_positive("time_limit", time_limit, "s"))
    kwargs.setdefault("control_timestep", check_positive("control_timestep", control_timestep, "s"))
    return control.Environment(physics, task, **kwargs)
