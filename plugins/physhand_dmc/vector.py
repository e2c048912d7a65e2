"""The suite's tasks as batched environments: W copies of a task stepped together on one device
(issue 54; docs/training.md).

    from physhand_dmc import vector
    env = vector.make("fingertip_press", "index", num_envs=1024, device="cuda:0")
    obs, info = env.reset(seed=0)                     # obs (W, obs_dim) float32
    obs, reward, terminated, truncated, info = env.step(actions)   # actions (W, nu) in [-1, 1]

- :func:`make` returns a ``gymnasium.vector.VectorEnv`` (:class:`SoftVectorEnv`) with flat Box
  observations (the single task's observation dict flattened in its key order, as dm_control's
  ``flat_observation=True``; ``env.obs_keys`` / ``env.obs_slices`` name the parts) and actions in
  [-1, 1] per actuator (the suite's normalised actions). Autoreset: ``SAME_STEP`` (a world whose
  episode ended is reset within the step that ended it; ``info["final_obs"]`` holds its last
  observation). The suite's tasks end by their time limit (``truncated``), so every world ends
  together unless ``reset(options={"reset_mask": m})`` restarted some.
- World k with seed s + k and the same actions is the single environment
  ``suite.load(domain, task, task_kwargs={"random": s + k, ...})`` step for step: the same task
  code (:class:`BatchTask`: resets, observations and rewards on (W, ...) arrays), the soft hands
  batched (BatchedHands), MuJoCo's side in MuJoCo Warp (float32; the single environment's is
  MuJoCo's float64 C step): equal within float32 rounding over the compared steps (tests/test_vector_env.py).
- ``device_arrays=True``: ``step`` / ``reset`` return Warp arrays on the device (DLPack and
  ``__cuda_array_interface__``: ``torch.from_dlpack(obs)``, ``jax.dlpack``) instead of host NumPy.
- Per-episode randomisation through ``task_kwargs`` (each world from its own seed): the object's
  start offset (``object_jitter`` m), and in hand_hold its mass (``mass_range`` kg) and friction
  (``friction_range``), in fingertip_press the target force (``force_range`` N).
"""

from __future__ import annotations

import collections

import numpy as np

from physhand_dmc.batch_task import BatchTask, load_batch


def make(domain: str, task: str, num_envs: int, task_kwargs=None, device=None, device_arrays: bool = False):
    """A :class:`SoftVectorEnv` of ``num_envs`` copies of the suite task (see the module docstring)."""
    t, time_limit, control_timestep = load_batch(domain, task, num_envs, task_kwargs, device)
    return SoftVectorEnv(t, time_limit, control_timestep, device_arrays=device_arrays, name=f"{domain}-{task}")


def flatten(obs: collections.OrderedDict) -> np.ndarray:
    """(W, obs_dim) the observation dict's arrays flattened per world in key order."""
    return np.concatenate([np.asarray(v, np.float64).reshape(v.shape[0], -1) for v in obs.values()], axis=1)


def _vector_env_base():
    import gymnasium

    return gymnasium.vector.VectorEnv


class SoftVectorEnv(_vector_env_base()):
    """``gymnasium.vector.VectorEnv`` over a :class:`BatchTask` (see the module docstring)."""

    def __init__(self, task: BatchTask, time_limit: float, control_timestep: float, *, device_arrays: bool = False,
                 name: str = "physhand"):
        import gymnasium
        from dm_control.rl.control import compute_n_steps
        from gymnasium.vector import AutoresetMode

        self.task = task
        self.physics = task.physics
        self.num_envs = task.physics.worlds
        self.n_sub_steps = compute_n_steps(control_timestep, self.physics.dt)
        self.step_limit = time_limit / (self.physics.dt * self.n_sub_steps)  # dm_control's Environment
        self.device_arrays = bool(device_arrays)
        self.metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "name": name}
        self.render_mode = None
        self.steps = np.zeros(self.num_envs, np.int64)
        self._ready = False
        self._last_obs = None  # (W, dim): what the last reset / step returned
        obs = task.observations()  # (shapes: the batch as built)
        self.obs_keys = list(obs)
        sizes = [int(np.prod(v.shape[1:])) for v in obs.values()]
        ends = np.cumsum(sizes)
        self.obs_slices = {k: slice(int(e - s), int(e)) for k, s, e in zip(self.obs_keys, sizes, ends)}
        dim, nu = int(ends[-1]), self.physics.model.nu
        self.single_observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (dim,), np.float32)
        self.single_action_space = gymnasium.spaces.Box(-1.0, 1.0, (nu,), np.float32)
        self.observation_space = gymnasium.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, self.num_envs)

    def _out(self, a: np.ndarray):
        a = np.ascontiguousarray(a, np.float32)
        if not self.device_arrays:
            return a
        import warp as wp

        return wp.array(a, dtype=wp.float32, device=self.physics.device)

    def _reset_worlds(self, mask: np.ndarray) -> None:
        with self.physics.keep_others(mask):
            self.task.initialize_episodes(mask)
        self.steps[mask] = 0

    def reset(self, *, seed=None, options=None):
        """Every world (or ``options["reset_mask"]``'s) starts an episode; ``seed``: world k's RNG
        seed is ``seed + k`` (an int) or ``seed[k]`` (a sequence)."""
        super().reset(seed=None)
        if seed is not None:
            seeds = seed + np.arange(self.num_envs) if np.isscalar(seed) else np.asarray(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed: an int or {self.num_envs} ints, got {len(seeds)}")
            self.task.seed(seeds)
        mask = np.ones(self.num_envs, bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"reset_mask must be ({self.num_envs},) bool, got {mask.shape}")
        if not mask.all() and not self._ready:
            raise ValueError("reset_mask: the first reset() must start every world (no reset_mask)")
        self._reset_worlds(mask)
        self.physics.bad[mask] = False
        self._ready = True
        obs = flatten(self.task.observations())
        if not mask.all():  # (the others' observations as last returned: the reset's frames ran in them too)
            obs = np.where(mask[:, None], obs, self._last_obs)
        self._last_obs = obs
        return self._out(obs), {}

    def step(self, actions):
        if not self._ready:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(actions.numpy() if hasattr(actions, "numpy") else actions, np.float64)
        if a.shape != (self.num_envs, self.physics.model.nu):
            raise ValueError(f"actions must be ({self.num_envs}, {self.physics.model.nu}) in [-1, 1], got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("actions hold NaN or inf")
        self.physics.set_ctrl(self.task.ctrl(a))
        self.physics.step(self.n_sub_steps)
        self.steps += 1
        obs = flatten(self.task.observations())
        reward = self.task.rewards()
        truncated = self.steps >= self.step_limit
        terminated = self.physics.bad.copy()
        if terminated.any():  # (a world whose MuJoCo state turned non-finite: no NaN to the learner)
            reward = np.where(terminated, 0.0, reward)
            obs = np.where(terminated[:, None], np.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0), obs)
        info = {}
        done = truncated | terminated
        if np.any(done):  # gymnasium's SAME_STEP convention: object arrays, None where not ended
            final = np.full(self.num_envs, None, dtype=object)
            for w in np.flatnonzero(done):
                final[w] = obs[w].astype(np.float32)
            info["final_obs"], info["_final_obs"] = final, done.copy()
            info["final_info"] = np.array([{} if d else None for d in done], dtype=object)
            info["_final_info"] = done.copy()
            self._reset_worlds(done)
            self.physics.bad[done] = False
            obs = np.where(done[:, None], flatten(self.task.observations()), obs)
        self._last_obs = obs
        return (self._out(obs), reward.astype(np.float32), terminated, truncated, info)

    def close_extras(self, **kwargs):
        self.physics.close()
