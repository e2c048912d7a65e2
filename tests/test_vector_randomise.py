"""hand_hold's per-episode domain randomisation (``mass_range``, ``friction_range``) on the CPU:
nothing drawn by default; the single task draws into the model (inertia scaled from the model's,
the skin's friction coefficient refreshed); batched world k draws what the single environment with
seed s + k draws and follows it over two-way steps; a partial reset changes only its worlds;
MuJoCo Warp's step reads the per-world mass, inertia and friction; bad ranges are refused."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import physhand_mj as ph

pytest.importorskip("mujoco_warp")
pytest.importorskip("gymnasium")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from physhand_dmc import suite, vector  # noqa: E402
from vector_vs_single import actions  # noqa: E402

CPU = ph.Config(frame_dt=0.005, device="cpu")
TWO_WAY = ph.Config(frame_dt=0.005, device="cpu", two_way=True)
# friction above the hand's coefficient 1 (MuJoCo's rule keeps the larger: below 1 nothing changes)
RAND = dict(mass_range=(0.05, 0.5), friction_range=(1.2, 2.0))
JITTER = 0.002


def expected_draws(seed: int, episodes: int = 1):
    """(mass kg, friction) of each episode as the task's RNG draws them: start offset, mass, friction."""
    rng = np.random.RandomState(seed)
    out = []
    for _ in range(episodes):
        rng.uniform(-JITTER, JITTER, 3)
        out.append((rng.uniform(*RAND["mass_range"]), rng.uniform(*RAND["friction_range"])))
    return out


def object_values(model, body: int):
    geoms = np.flatnonzero(model.geom_bodyid == body)
    return float(model.body_mass[body]), np.array(model.body_inertia[body]), np.array(model.geom_friction[geoms, 0])


def test_defaults_draw_nothing_and_change_nothing():
    """Without the options (or with None) the episode is the one before them, bit for bit: the same
    RNG state after the reset, the same observation, the model's mass and friction; the batched
    task keeps MuJoCo Warp's shared (unbatched) fields."""
    envs = [suite.load("hand_hold", "apple", task_kwargs=dict(random=3, config=CPU, **kw))
            for kw in ({}, dict(mass_range=None, friction_range=None))]
    ts = [e.reset() for e in envs]
    for k in ts[0].observation:
        assert np.array_equal(ts[0].observation[k], ts[1].observation[k]), k
    assert all(np.array_equal(a, b) for a, b in zip(envs[0].task.random.get_state(), envs[1].task.random.get_state()))
    m = envs[1].physics.model
    b = m.name2id("apple", "body")
    assert object_values(m, b)[0] == 0.12 and np.all(object_values(m, b)[2] == 1.0)
    env = vector.make("hand_hold", "apple", num_envs=2, task_kwargs={"config": CPU}, device="cpu")
    env.reset(seed=0)
    assert env.physics._fields == {} and env.physics.m.body_mass.shape[0] == 1
    env.close()


def test_single_env_draws_mass_and_friction_into_the_model():
    """Each episode's draws (after the start offset's, mass then friction) land in the model: the
    body's mass, its inertia scaled from the model's (not compounded over episodes), its geoms'
    sliding friction; the skin's two-way coefficient follows the new friction."""
    env = suite.load("hand_hold", "apple", task_kwargs=dict(random=11, gravity="down", config=TWO_WAY,
                                                              float_frames=0, **RAND))
    m = env.physics.model
    b = m.name2id("apple", "body")
    i0 = 7.68e-05  # the apple's principal moments at its 0.12 kg (the model's)
    seen = []
    for mass, mu in expected_draws(11, 2):
        env.reset()
        got_mass, inertia, friction = object_values(m, b)
        assert got_mass == mass and 0.05 <= mass <= 0.5
        assert np.allclose(inertia, i0 * mass / 0.12, rtol=1e-4)
        assert np.all(friction == mu) and 1.2 <= mu <= 2.0
        env.step(env.task.normalise_ctrl(env.physics, env.physics.data.ctrl.copy()))
        assert np.allclose(env.physics.soft._mu, mu)  # (max(skin's 1, the object's))
        seen.append((mass, mu))
    assert seen[0][0] != seen[1][0] and seen[0][1] != seen[1][1]
    other = suite.load("hand_hold", "apple", task_kwargs=dict(random=12, config=CPU, **RAND))
    other.reset()
    assert object_values(other.physics.model, b)[0] != seen[0][0]  # (another seed, another mass)


def single(kw, seed, acts):
    env = suite.load("hand_hold", "apple", task_kwargs=dict(kw, random=seed),
                     environment_kwargs={"flat_observation": True})
    ts = env.reset()
    obs = [ts.observation["observations"]]
    for a in acts:
        obs.append(env.step(a).observation["observations"])
    return env, np.array(obs)


@pytest.fixture(scope="module")
def batch():
    kw = dict(gravity="down", config=TWO_WAY, float_frames=0, **RAND)
    env = vector.make("hand_hold", "apple", num_envs=2, task_kwargs=kw, device="cpu")
    yield env, kw
    env.close()


def test_batched_world_k_draws_and_follows_the_single_env_seed_plus_k(batch):
    """World k (seed 4 + k) draws the single environment's mass, inertia and friction (MuJoCo Warp's
    per-world fields and the soft side's), and over two two-way env steps stays within the tolerance
    of tests/test_vector_env.py::test_two_way_world_follows_the_single_env_frame_by_frame."""
    env, kw = batch
    p = env.physics
    obs, _ = env.reset(seed=4)
    b = env.task._body
    acts = actions(env.task.normalise_ctrl(p.host("ctrl")), 2)
    out = [obs]
    for a in acts:
        out.append(env.step(a)[0])
    out = np.array(out)
    s = env.obs_slices
    tw = p.hands.two_way
    masses = p.model_field("body_mass")[:, b]
    assert masses[0] != masses[1]
    for w in range(2):
        one, o = single(kw, 4 + w, acts[:, w])
        mass, inertia, friction = object_values(one.physics.model, b)
        assert masses[w] == mass and np.array_equal(p.model_field("body_inertia")[w, b], inertia)
        assert np.array_equal(p.model_field("geom_friction")[w, env.task._geoms, 0], friction)
        assert np.allclose(p.m.body_mass.numpy()[w, b], mass, rtol=1e-6)  # (MuJoCo Warp's, float32)
        assert np.allclose(p.m.geom_friction.numpy()[w, env.task._geoms, 0], friction, rtol=1e-6)
        assert np.allclose(tw.inv_mass[w, 0], 1 / mass) and np.allclose(tw.inv_inertia[w, 0], 1 / inertia)
        assert np.allclose(tw.mu[w], one.physics.soft._mu)
        assert np.abs(o[:, s["joint_pos"]] - out[:, w, s["joint_pos"]]).max() < 1e-4
        assert np.abs(o[:, s["object_offset"]] - out[:, w, s["object_offset"]]).max() < 1e-5
        assert np.abs(o[:, s["object_contact"]][:, 1] - out[:, w, s["object_contact"]][:, 1]).max() < 1e-2  # N


def test_partial_reset_changes_only_its_worlds(batch):
    env, _ = batch
    p = env.physics
    env.reset(seed=4)
    before = {k: p.model_field(k) for k in ("body_mass", "body_inertia", "geom_friction")}
    mu = p.hands.two_way.mu.copy()
    env.reset(seed=[20, 21], options={"reset_mask": [True, False]})
    b, g = env.task._body, env.task._geoms
    mass, fric = expected_draws(20)[0]
    assert p.model_field("body_mass")[0, b] == mass and np.all(p.model_field("geom_friction")[0, g, 0] == fric)
    for k, v in before.items():
        assert np.array_equal(p.model_field(k)[1], v[1]), k
    assert p.hands.two_way.mu[1] == mu[1] and p.hands.two_way.mu[0] == fric


def test_mujoco_warp_steps_each_world_with_its_own_mass_inertia_and_friction(batch):
    """With the same force and torque applied in both worlds to the object moved clear of the hand,
    MuJoCo Warp's accelerations are each world's F / m - g and tau / I (they would be alike if the
    per-world fields were ignored); the contacts of the object in the grasp carry its world's
    friction coefficient."""
    env, _ = batch
    p = env.physics
    env.reset(seed=[1, 2])
    b, a, v = env.task._body, env.task._qadr, env.task._vadr
    qpos = p.host("qpos")
    p.set_host("qpos", qpos[[1, 1]])  # (one pose in both worlds: the same contacts, each with its friction)
    p.forward()
    nacon = int(p.d.nacon.numpy()[0])
    geom = p.d.contact.geom.numpy()[:nacon]
    world = p.d.contact.worldid.numpy()[:nacon]
    fric = p.d.contact.friction.numpy()[:nacon, 0]
    mu = p.model_field("geom_friction")[:, env.task._geoms[0], 0]
    assert abs(mu[0] - mu[1]) > 0.01
    on = np.isin(geom, env.task._geoms).any(1)
    for w in range(2):
        assert np.any(on & (world == w)) and np.allclose(fric[on & (world == w)], mu[w], rtol=1e-6)
    qpos = p.host("qpos")
    qpos[:, a + 2] += 0.5  # 0.5 m up: clear of the hand and the floor
    p.set_host("qpos", qpos)
    p.set_host("qvel", np.zeros_like(p.host("qvel")))
    f = np.zeros_like(p.host("qfrc_applied"))
    f[:, v + 2], f[:, v + 3] = 2.0, 1e-3  # N up, N m about the body's x
    p.set_host("qfrc_applied", f)
    try:
        p.forward()
        qacc = p.host("qacc")
    finally:
        p.set_host("qfrc_applied", np.zeros_like(f))
    mass, inertia = p.model_field("body_mass")[:, b], p.model_field("body_inertia")[:, b, 0]
    assert abs(mass[0] - mass[1]) > 0.05
    assert np.allclose(qacc[:, v + 2], 2.0 / mass - 9.81, rtol=1e-4)
    assert np.allclose(qacc[:, v + 3], 1e-3 / inertia, rtol=1e-3)


@pytest.mark.parametrize("kw", [dict(mass_range=(0.0, 1.0)), dict(mass_range=(0.5, 0.1)), dict(mass_range=(0.1, np.inf)),
                                dict(mass_range=0.1), dict(friction_range=(-1.0, 1.0)),
                                dict(friction_range=(float("nan"), 1.0)), dict(friction_range=(1, 2, 3))])
def test_bad_ranges_are_refused(kw):
    name = next(iter(kw))
    with pytest.raises(ValueError, match=name):
        suite.load("hand_hold", "apple", task_kwargs=dict(kw, config=CPU))
    with pytest.raises(ValueError, match=name):
        vector.make("hand_hold", "apple", num_envs=1, task_kwargs=dict(kw, config=CPU), device="cpu")
