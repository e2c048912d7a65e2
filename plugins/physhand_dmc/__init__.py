"""physhand_dmc: the soft hand in dm_control tasks.

- :mod:`physhand_dmc.suite`: ``load(domain, task, task_kwargs=..., environment_kwargs=...)``,
  ``ALL_TASKS``, ``BENCHMARKING``, ``TAGS`` (like ``dm_control.suite``); docs/dm_control.md.
- :class:`SoftPhysics`: ``dm_control.mujoco.Physics`` running a SoftHand frame after each MuJoCo
  step and re-uploading the deformed skin before rendering.
- :class:`SoftTask`: the tasks' base (normalised actions, soft-contact observations).
- :mod:`physhand_dmc.vector` (``pip install -e ".[train]"``): ``make(domain, task, num_envs, ...)``,
  W copies of ``hand_hold`` / ``fingertip_press`` batched on one device behind gymnasium's
  ``VectorEnv`` (:mod:`physhand_dmc.batch_physics`: MuJoCo Warp + BatchedHands;
  :mod:`physhand_dmc.batch_task`); :mod:`physhand_dmc.ppo`: a NumPy PPO over it (docs/training.md).
"""

import physhand_mj as _ph  # noqa: F401  (picks MuJoCo's GL backend before mujoco is imported)

from physhand_dmc.physics import SoftPhysics  # noqa: E402
from physhand_dmc.sensing import HAND_REGIONS, SensedHand, SoftSensor, regions  # noqa: E402
from physhand_dmc.task import SoftTask  # noqa: E402

__all__ = ["HAND_REGIONS", "SensedHand", "SoftPhysics", "SoftSensor", "SoftTask", "regions"]
