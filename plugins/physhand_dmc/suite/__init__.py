"""The soft-hand task suite, registered like ``dm_control.suite``.

    from physhand_dmc import suite
    env = suite.load("hand_hold", "apple", task_kwargs={"random": 0})
    ts = env.reset()
    ts = env.step(np.zeros(env.action_spec().shape))

Domains (one module + XML each): ``hand_hold`` (the soft hand holds each HOI object, free, against
gravity), ``fingertip_press`` (the index fingertip presses a plate to a target force), ``jaco_lift``
(the Jaco gripper with soft pads lifts a cylinder). Tags: ``benchmarking`` (all), ``hoi``,
``press``, ``robot``.
"""

from __future__ import annotations

import collections
import inspect

from physhand_dmc.suite import fingertip_press, hand_hold, jaco_lift

_DOMAINS = {name: module for name, module in (("fingertip_press", fingertip_press), ("hand_hold", hand_hold),
                                              ("jaco_lift", jaco_lift))}


def _get_tasks(tag):
    result = []
    for domain_name in sorted(_DOMAINS):
        suite = _DOMAINS[domain_name].SUITE
        tasks = suite if tag is None else suite.tagged(tag)
        result.extend((domain_name, task_name) for task_name in tasks.keys())
    return tuple(result)


def _get_tasks_by_domain(tasks):
    result = collections.defaultdict(list)
    for domain_name, task_name in tasks:
        result[domain_name].append(task_name)
    return {k: tuple(v) for k, v in result.items()}


ALL_TASKS = _get_tasks(tag=None)
BENCHMARKING = _get_tasks("benchmarking")
TAGS = {tag: _get_tasks(tag) for tag in ("benchmarking", "hoi", "press", "robot")}
TASKS_BY_DOMAIN = _get_tasks_by_domain(ALL_TASKS)


def load(domain_name, task_name, task_kwargs=None, environment_kwargs=None, visualize_reward=False):
    """A ``dm_control.rl.control.Environment`` for ``domain_name`` / ``task_name``.

    ``task_kwargs``: ``random`` (int seed or ``np.random.RandomState``: the task's only source of
    randomness), ``time_limit`` (s), ``control_timestep`` (s), ``settle_frames`` (solver frames the
    soft tissue settles at each reset), ``config`` (a ``physhand_mj.Config``; ``frame_dt`` must be the
    domain's MuJoCo timestep, 0.005 s) and the task's own options (see each domain's docstring).
    ``environment_kwargs``: passed to ``control.Environment`` (e.g. ``time_limit``,
    ``flat_observation``). ``visualize_reward`` is accepted for dm_control compatibility and ignored.
    Raises ValueError for an unknown domain or task, TypeError for unknown kwargs.
    """
    del visualize_reward
    if domain_name not in _DOMAINS:
        raise ValueError(f"unknown domain {domain_name!r}; domains: {sorted(_DOMAINS)}")
    suite = _DOMAINS[domain_name].SUITE
    if task_name not in suite:
        raise ValueError(f"unknown task {task_name!r} in domain {domain_name!r}; tasks: {sorted(suite)}")
    factory = suite[task_name]
    task_kwargs = dict(task_kwargs or {})
    accepted = [p for p in inspect.signature(factory).parameters if p != "environment_kwargs"]
    unknown = sorted(set(task_kwargs) - set(accepted))
    if unknown:
        raise TypeError(f"unknown task_kwargs {unknown} for {domain_name}/{task_name}; accepted: {accepted}")
    if environment_kwargs is not None and not isinstance(environment_kwargs, dict):
        raise TypeError(f"environment_kwargs must be a dict, got {type(environment_kwargs).__name__}")
    env_accepted = set(inspect.signature(_control_environment_init()).parameters) - {"self", "physics", "task"}
    bad = sorted(set(environment_kwargs or {}) - env_accepted)
    if bad:
        raise TypeError(f"unknown environment_kwargs {bad}; accepted: {sorted(env_accepted)}")
    return factory(environment_kwargs=environment_kwargs, **task_kwargs)


def _control_environment_init():
    from dm_control.rl import control

    return control.Environment.__init__
