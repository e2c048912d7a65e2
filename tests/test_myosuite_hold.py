"""MyoSuite's ObjHold held by the skin (physhand_myosuite.hold, benchmarks/myosuite_hold.py): the stored
grasp is an action of the env; with the object out of MyoHand's capsule collisions nothing in MuJoCo
holds it, and with two-way coupling the skin alone carries it (short run, default set) and holds it
through the grasp for 2 s (slow)."""

import mujoco
import numpy as np
import pytest

pm = pytest.importorskip("physhand_myosuite")
pytest.importorskip("myosuite")
import gymnasium  # noqa: E402

from physhand_myosuite import hold  # noqa: E402

ENV = "myoHandObjHoldFixed-v0"


def _env(two_way: bool, skin_only: bool = True, **kw):
    base = gymnasium.make(ENV)
    if skin_only:
        hold.skin_only(base.unwrapped.model)
    return pm.SoftSkin(base, two_way=two_way, **kw)


def test_grasp_is_an_action_of_the_env():
    from myosuite.terms.base_action import sigmoid_muscle_activation

    env = gymnasium.make(ENV)
    a = hold.grasp_action(env)
    assert a.shape == env.action_space.shape and env.action_space.contains(a)
    g = hold.load_grasp()
    m = env.unwrapped.model
    act = np.array([g["activation"][m.actuator(i).name] for i in range(m.nu)])
    np.testing.assert_allclose(hold.activation(a), sigmoid_muscle_activation(a.astype(np.float64), np), atol=1e-12)
    np.testing.assert_allclose(hold.activation(a), act, atol=1e-3)


def test_skin_only_leaves_the_object_to_the_skin():
    """MuJoCo alone, the grasp held 0.3 s: with the capsules the object stays in the hand; without
    them it falls through the hand (to the table) and no hand geom touches it, the floor still does
    its part (collisions kept)."""
    out = {}
    for skin_only in (False, True):
        env = gymnasium.make(ENV)
        m, d = env.unwrapped.model, env.unwrapped.data
        if skin_only:
            hold.skin_only(m)
        b = m.body("object").id
        a = hold.grasp_action(env)
        env.reset(seed=0)
        z0 = d.xpos[b, 2]
        hand = False
        for _ in range(15):
            env.step(a)
            hand |= any(b in (m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]) and
                        0 not in (m.body_rootid[m.geom_bodyid[c.geom1]], m.body_rootid[m.geom_bodyid[c.geom2]])
                        and m.geom_bodyid[c.geom1] != m.geom_bodyid[c.geom2] for c in d.contact[: d.ncon])
        out[skin_only] = (z0 - d.xpos[b, 2], hand)
    assert out[False][0] < 0.03 and out[False][1]
    assert out[True][0] > 0.2 and not out[True][1]  # free fall for 0.3 s: 0.44 m, stopped by the table


def _carry(two_way: bool, steps: int = 5):
    """The grasp for ``steps`` env steps with the object out of the capsules' collisions."""
    env = _env(two_way, settle_frames=3)
    m, d = env.model, env.data
    b = m.body("object").id
    a = hold.grasp_action(env)
    env.reset(seed=0)
    p0 = d.xpos[b].copy()
    forces = []
    for _ in range(steps):
        _, _, _, _, info = env.step(a)
        forces.append(info["physhand"]["objects"]["object"].get("applied", {}).get("force", np.zeros(3)))
    c = env.hand.contacts()["objects"]["object"]
    row = dict(offset=d.xpos[b] - p0, force=np.mean(forces, 0), contact=c, weight=m.body_mass[b] * 9.81,
               metrics=env.hand.metrics())
    env.close()
    return row


def test_skin_alone_carries_the_object_two_way_not_one_way():
    """0.1 s of the grasp (50 soft frames): two-way, the skin holds the object up (it moves < 10 mm)
    with an upward force of the order of its weight, reported with its friction part and contact
    points on the object's surface; one-way, the same action, it falls through the skin (> 30 mm)."""
    two = _carry(True)
    assert np.linalg.norm(two["offset"]) < 0.010, two["offset"]
    f = two["force"]
    assert f[2] > 0.5 * two["weight"] and np.linalg.norm(f) < 5 * two["weight"], f
    c = two["contact"]
    assert c["points"].shape == (len(c["vertices"]), 3) and len(c["vertices"]) > 10
    assert np.all(np.isfinite(c["friction"])) and np.linalg.norm(c["friction"]) < np.linalg.norm(c["force"])
    one = _carry(False)
    assert -one["offset"][2] > 0.030, one["offset"]
    assert "applied" not in one


@pytest.mark.slow
def test_skin_holds_objhold_for_two_seconds():
    """The grasp held 2 s (1,000 soft frames) with the object out of the capsules' collisions: the
    skin alone keeps it within 2 cm of its start, and over the last 0.5 s its force carries the
    weight (vertical part within 25 % of m g: MuJoCo's contacts, floor and table, take none)."""
    env = _env(True)
    r = hold.hold_still(env, hold.grasp_action(env), 2.0)
    env.close()
    assert r["finite"]
    assert r["worst_mm"] < 20.0, r
    assert abs(r["force_n"][2] - r["weight_n"]) < 0.25 * r["weight_n"], r
    assert np.abs(r["capsule_n"]).max() < 1e-6, r
