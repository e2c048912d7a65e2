"""physhand_myosuite: the soft skin on MyoSuite's hand environments (a gymnasium wrapper).

    import physhand_myosuite as pm
    env = pm.make("myoHandObjHoldFixed-v0")              # MyoSuite env + soft skin
    obs, info = env.reset(seed=0)
    obs, r, term, trunc, info = env.step(env.action_space.sample())
    info["physhand"]["region_force_n"], env.log[-1]["penetration_max_um"], env.render()

Needs the ``myosuite`` extra (``pip install -e ".[myosuite]"``, MyoSuite 3.x). See docs/tasks.md.
"""

from physhand_myosuite.wrapper import HAND_ENVS, SoftSkin, colliding_objects, env_dt, make

__all__ = ["HAND_ENVS", "SoftSkin", "colliding_objects", "env_dt", "make"]
