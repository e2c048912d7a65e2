"""hand_hold with Config(two_way=True) (issue 52, item 5): the skin holds the object against gravity
along the palm (``gravity="down"``), from the reset's squeezed, floated grasp (hand_hold.py); with
one-way coupling the same grasp lets the apple fall, and one-way defaults stay as they were."""

import numpy as np
import pytest

pytest.importorskip("dm_control")

import physhand_mj as ph  # noqa: E402
from physhand_dmc import suite  # noqa: E402
from physhand_dmc.suite import hand_hold  # noqa: E402


def hold(obj, config=None, seconds=2.0, **kw):
    """Run the episode holding the reset's ctrl: (largest offset from the start, m; the env)."""
    env = suite.load("hand_hold", obj, task_kwargs=dict(random=0, gravity="down", config=config, time_limit=seconds, **kw))
    ts = env.reset()
    act = env.task.normalise_ctrl(env.physics, env.physics.data.ctrl.copy())
    worst = 0.0
    while not ts.last():
        ts = env.step(act)
        worst = max(worst, float(np.linalg.norm(ts.observation["object_offset"])))
    return worst, env


def test_one_way_defaults_are_unchanged():
    """Without two-way the reset keeps the keyframe (no squeeze, no float) and dm_control's legacy step
    (with two-way SoftPhysics.step runs whole mj_steps itself: tests/test_two_way_tasks.py)."""
    env = suite.load("hand_hold", "apple", task_kwargs=dict(random=0))
    assert env.task.squeeze == 1.0 and env.task.float_frames == 0
    assert env.physics.legacy_step
    env = suite.load("hand_hold", "apple", task_kwargs=dict(random=0, config=ph.Config(two_way=True)))
    assert env.task.squeeze == hand_hold.SQUEEZE and env.task.float_frames == hand_hold.FLOAT_FRAMES


def test_the_skin_holds_the_apple_with_gravity_along_the_palm():
    """Two-way: the apple stays within 2 cm for 1 s, carried by the skin (its force on the apple
    points up), and not entered by the skin's samples."""
    worst, env = hold("apple", ph.Config(two_way=True), seconds=1.0)
    assert worst < 0.02, worst
    c = env.physics.soft.contacts()["objects"]["apple"]
    assert c["force"][2] > 0.3  # N, against gravity (the proxies carry the rest of m g = 1.18 N)
    assert c["penetration_count"] <= 5


@pytest.mark.slow
def test_two_way_holds_what_one_way_drops():
    """The same squeezed, floated grasp for 2 s: one-way coupling drops the apple, two-way holds the
    apple and the box within 2 cm."""
    worst, _ = hold("apple", None, squeeze=hand_hold.SQUEEZE, float_frames=hand_hold.FLOAT_FRAMES)
    assert worst > 0.05, worst
    for obj in ("apple", "box"):
        worst, _ = hold(obj, ph.Config(two_way=True))
        assert worst < 0.02, (obj, worst)
