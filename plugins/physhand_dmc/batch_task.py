"""``BatchTask``: what the suite's batched tasks share (resets, observations and rewards on (W, ...)
arrays), and :func:`load_batch`, which builds one (physhand_dmc.vector wraps it as a gymnasium
VectorEnv). No gymnasium here: the suite's domains import this module.
"""

from __future__ import annotations

import collections
import inspect

import numpy as np

from physhand_dmc.batch_physics import BatchPhysics

_DOMAINS = ("fingertip_press", "hand_hold")


class BatchTask:
    """What the batched tasks share (:class:`~physhand_dmc.task.SoftTask` on (W, ...) arrays): the
    action mapping, per-world RNGs, the soft observations. Subclasses implement
    ``initialize_episodes(mask)``, ``task_observations(obs)`` and ``rewards()``."""

    def __init__(self, physics: BatchPhysics, settle_frames: int = 20):
        self.physics = physics
        self.settle_frames = int(settle_frames)
        self.random = [np.random.RandomState(k) for k in range(physics.worlds)]
        lo, hi = physics.model.actuator_ctrlrange.T
        self._centre, self._half = 0.5 * (lo + hi), 0.5 * (hi - lo)

    def seed(self, seeds) -> None:
        """Each world's task RNG (as the single task's ``random``): ``np.random.RandomState(seeds[w])``."""
        self.random = [np.random.RandomState(int(s)) for s in seeds]

    def ctrl(self, action: np.ndarray) -> np.ndarray:
        """(W, nu) controls of normalised actions (``SoftTask.before_step``)."""
        return self._centre + np.clip(np.asarray(action, np.float64), -1.0, 1.0) * self._half

    def normalise_ctrl(self, ctrl) -> np.ndarray:
        return np.clip((np.asarray(ctrl, float) - self._centre) / self._half, -1.0, 1.0)

    def soft_observations(self, obs) -> None:
        """``region_contact`` (W, R, 4) and ``object_contact`` (W, 4) as ``SoftTask.get_observation``."""
        p = self.physics
        p.sync()
        s = p.sensor
        W = p.worlds
        reg = s.region_host.reshape(W, -1, 4)
        region = np.empty(reg.shape)
        region[..., 0] = reg[..., 0] * 1e4  # m^2 -> cm^2
        region[..., 1:3] = reg[..., 1:3]
        region[..., 3] = reg[..., 3] * 1e3  # m -> mm
        obs["region_contact"] = region
        o = s.obj_host.reshape(W, -1, 3)[:, 0]
        count, deep = p.penetration()
        obs["object_contact"] = np.stack([o[:, 0] * 1e4, o[:, 1], count.astype(float), deep * 1e-3], axis=1)

    def observations(self) -> collections.OrderedDict:
        obs = collections.OrderedDict()
        self.task_observations(obs)
        self.soft_observations(obs)
        return obs

    def depth_mm(self) -> np.ndarray:
        return self.physics.penetration()[1] * 1e-3

    def initialize_episodes(self, mask: np.ndarray) -> None:
        raise NotImplementedError

    def task_observations(self, obs) -> None:
        raise NotImplementedError

    def rewards(self) -> np.ndarray:
        raise NotImplementedError


def load_batch(domain: str, task: str, num_envs: int, task_kwargs=None, device=None):
    """(BatchTask, time_limit s, control_timestep s) of ``domain`` / ``task`` with ``num_envs``
    worlds on ``device`` (a Warp device name; None: Warp's default), ``task_kwargs`` as
    ``suite.load``'s (``random``: the first world's seed, world k's is ``random + k``)."""
    from physhand_dmc import suite

    if domain not in _DOMAINS:
        raise ValueError(f"batched domains: {list(_DOMAINS)} (got {domain!r}; jaco_lift is single-env only)")
    if not (isinstance(num_envs, (int, np.integer)) and num_envs >= 1):
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
    module = suite._DOMAINS[domain]
    if task not in module.SUITE:
        raise ValueError(f"unknown task {task!r} in domain {domain!r}; tasks: {sorted(module.SUITE)}")
    kwargs = dict(task_kwargs or {})
    accepted = ["random"] + [p for p in inspect.signature(module.batch_task).parameters
                             if p not in ("task", "num_envs", "device")]
    unknown = sorted(set(kwargs) - set(accepted))
    if unknown:
        raise TypeError(f"unknown task_kwargs {unknown} for batched {domain}/{task}; accepted: {accepted}")
    seed = kwargs.pop("random", None)
    out = module.batch_task(task, int(num_envs), device=device, **kwargs)
    if seed is not None:
        out[0].seed(int(seed) + np.arange(num_envs))
    return out
