"""physhand_dmc: the soft hand in dm_control tasks.

- :mod:`physhand_dmc.suite`: ``load(domain, task, task_kwargs=..., environment_kwargs=...)``,
  ``ALL_TASKS``, ``BENCHMARKING``, ``TAGS`` (like ``dm_control.suite``); docs/dm_control.md.
- :class:`SoftPhysics`: ``dm_control.mujoco.Physics`` running a SoftHand frame after each MuJoCo
  step and re-uploading the deformed skin before rendering.
- :class:`SoftTask`: the tasks' base (normalised actions, soft-contact observations).
"""

import physhand_mj as _ph  # noqa: F401  (picks MuJoCo's GL backend before mujoco is imported)

from physhand_dmc.physics import SoftPhysics  # noqa: E402
from physhand_dmc.sensing import HAND_REGIONS, SensedHand, SoftSensor, regions  # noqa: E402
from physhand_dmc.task import SoftTask  # noqa: E402

__all__ = ["HAND_REGIONS", "SensedHand", "SoftPhysics", "SoftSensor", "SoftTask", "regions"]
