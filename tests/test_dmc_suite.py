"""The dm-control task suite (plugins/physhand_dmc), like dm_control's suite_test: every task's
observations match their specs and are finite, rewards lie in [0, 1], a seed fixes the trajectory,
reset restores the soft tissue whatever came before, and a random policy runs an episode. Real
MuJoCo and Warp (CPU), short episodes and 3 substeps per frame to keep the run short."""

import numpy as np
import pytest

import physhand_mj as ph  # noqa: F401  (GL backend before mujoco)
from physhand_dmc import HAND_REGIONS, regions, suite
from physhand_dmc.physics import SoftPhysics

CONFIG = dict(substeps=3, frame_dt=0.005)
STEPS = 5  # env steps per test episode (control_timestep 0.01 s)
SEED = 7


def _load(domain, task, seed=SEED, **kw):
    kwargs = dict(random=seed, settle_frames=3, config=ph.Config(**CONFIG), time_limit=STEPS * 0.01)
    kwargs.update(kw)
    return suite.load(domain, task, task_kwargs=kwargs)


def _check_timestep(env, ts):
    spec = env.observation_spec()
    assert list(spec) == list(ts.observation), (list(spec), list(ts.observation))
    for name, value in ts.observation.items():
        spec[name].validate(value)  # shape and dtype
        assert np.all(np.isfinite(value)), (name, value)
    if ts.reward is not None:
        assert 0.0 <= ts.reward <= 1.0, ts.reward


def test_registry():
    assert len(suite.ALL_TASKS) >= 9
    assert {t for d, t in suite.ALL_TASKS if d == "hand_hold"} == {
        "apple", "bowl", "box", "glass1", "glass2", "phone", "toothpaste"}
    assert ("fingertip_press", "index") in suite.ALL_TASKS and ("jaco_lift", "lift") in suite.ALL_TASKS
    assert set(suite.BENCHMARKING) == set(suite.ALL_TASKS)
    assert set(suite.TAGS["hoi"]) == {t for t in suite.ALL_TASKS if t[0] == "hand_hold"}


@pytest.mark.parametrize("domain,task", suite.ALL_TASKS, ids=[f"{d}-{t}" for d, t in suite.ALL_TASKS])
def test_task(domain, task):
    env = _load(domain, task)
    spec_before_reset = env.observation_spec()
    aspec = env.action_spec()
    assert aspec.shape == (env.physics.model.nu,)
    np.testing.assert_array_equal(aspec.minimum, -1.0)
    np.testing.assert_array_equal(aspec.maximum, 1.0)
    policy = np.random.RandomState(0)

    # a random-policy episode
    ts = env.reset()
    _check_timestep(env, ts)
    assert spec_before_reset == env.observation_spec()
    assert set(ts.observation) >= {"joint_pos", "joint_vel", "region_contact", "object_contact"}
    trajectory, actions = [], []
    while not ts.last():
        actions.append(policy.uniform(-1, 1, aspec.shape))
        ts = env.step(actions[-1])
        _check_timestep(env, ts)
        trajectory.append((ts.reward, ts.observation, env.physics.soft.skin_vertices))
    assert len(trajectory) == STEPS
    ctrl = env.physics.data.ctrl
    lo, hi = env.physics.model.actuator_ctrlrange.T
    np.testing.assert_allclose(ctrl, 0.5 * (lo + hi) + actions[-1] * 0.5 * (hi - lo))  # actions span the ranges
    end_skin = env.physics.soft.skin_vertices
    env.reset()
    second_reset_skin = env.physics.soft.skin_vertices
    assert np.max(np.abs(end_skin - second_reset_skin)) > 1e-4  # the episode moved the skin

    # same seed: same trajectory; reset after a different history: the same soft tissue
    env2 = _load(domain, task)
    env2.reset()
    for k in range(2):
        ts2 = env2.step(actions[k])
        reward, obs, skin = trajectory[k]
        assert ts2.reward == pytest.approx(reward, abs=1e-9)
        for name in obs:
            np.testing.assert_allclose(ts2.observation[name], obs[name], atol=1e-9, err_msg=name)
        np.testing.assert_allclose(env2.physics.soft.skin_vertices, skin, atol=1e-9)
    env2.reset()
    np.testing.assert_allclose(env2.physics.soft.skin_vertices, second_reset_skin, atol=1e-6,
                               err_msg="the soft tissue after reset depends on the previous episode")


def test_other_seed_differs():
    a = _load("hand_hold", "box", seed=1).reset().observation
    b = _load("hand_hold", "box", seed=2).reset().observation
    assert not np.allclose(a["object_contact"], b["object_contact"]) or not np.allclose(
        a["region_contact"], b["region_contact"])


def test_pooled_contact_matches_softhand_report():
    """The device-side pooling gives SoftHand.contacts()'s area and force, and runs once per frame."""
    env = _load("hand_hold", "apple")
    env.reset()
    hand = env.physics.soft
    frames = hand.sensor.frames
    a = env.task.normalise_ctrl(env.physics, env.physics.data.ctrl)
    for _ in range(2):
        ts = env.step(a)
    assert hand.sensor.frames == frames + 4  # two MuJoCo steps (two solver frames) per env step
    report = hand.contacts()["objects"]["apple"]
    obs = ts.observation["object_contact"]
    assert report["force_n"] > 0.1, report
    assert obs[1] == pytest.approx(report["force_n"], rel=1e-4)
    assert obs[0] == pytest.approx(report["area_m2"] * 1e4, rel=1e-3)
    assert obs[2] == report["penetration_count"]
    region = ts.observation["region_contact"]
    assert region[:, 1].sum() == pytest.approx(report["force_n"], rel=1e-4)  # regions partition the skin
    assert region[:, 2].sum() == len(report["vertices"])


def test_regions_cover_the_hand(asset):
    names, region = regions(asset)
    assert names == HAND_REGIONS
    assert region.shape == (asset.n_skin,) and region.min() == 0
    counts = np.bincount(region, minlength=len(names))
    assert np.all(counts > 20), dict(zip(names, counts))
    # fingertips are the most distal skin along the asset's finger axis
    axis = np.asarray(asset.meta["finger_axis"])
    along = asset.skin_vertices @ axis
    assert np.mean(along[region == names.index("middle_tip")]) > np.mean(along[region == names.index("palm")]) + 0.05


def test_render_shows_deformed_skin():
    """physics.render re-uploads the skin mesh: it matches a fresh renderer; without it, stale."""
    import mujoco
    from dm_control import mujoco as dm_mujoco

    env = _load("hand_hold", "apple")
    env.reset()
    physics = env.physics
    physics.render(120, 160, camera_id="side")  # the context caches the skin as it is now
    for _ in range(3):
        env.step(-np.ones(physics.model.nu))  # the whole hand moves
    stale = dm_mujoco.Physics.render(physics, 120, 160, camera_id="side")
    shown = physics.render(120, 160, camera_id="side")
    renderer = mujoco.Renderer(physics.model.ptr, 120, 160)
    try:
        renderer.update_scene(physics.data.ptr, camera="side")
        fresh = renderer.render()
    finally:
        renderer.close()
    physics.free()  # the GL contexts now, not at interpreter exit
    moved = np.mean(np.any(stale != shown, axis=2))
    assert moved > 0.005, moved
    assert np.mean(np.any(np.abs(shown.astype(int) - fresh.astype(int)) > 8, axis=2)) < 0.002


@pytest.mark.parametrize("call,message", [
    (lambda: suite.load("nope", "apple"), "unknown domain 'nope'"),
    (lambda: suite.load("hand_hold", "pear"), "unknown task 'pear'"),
    (lambda: suite.load("hand_hold", "apple", task_kwargs={"colour": 1}), "unknown task_kwargs \\['colour'\\]"),
    (lambda: suite.load("hand_hold", "apple", environment_kwargs={"speed": 2}), "unknown environment_kwargs"),
    (lambda: suite.load("hand_hold", "apple", task_kwargs={"config": ph.Config(frame_dt=0.002)}), "frame_dt"),
    (lambda: suite.load("hand_hold", "apple", task_kwargs={"object_jitter": -1}), "object_jitter .* \\(m\\)"),
    (lambda: suite.load("hand_hold", "apple", task_kwargs={"gravity": "up"}), "gravity must be one of"),
    (lambda: suite.load("fingertip_press", "index", task_kwargs={"force_range": (2.0, 1.0)}), "low <= high"),
    (lambda: suite.load("jaco_lift", "lift", task_kwargs={"time_limit": 0}), "time_limit .* \\(s\\)"),
])
def test_bad_input(call, message):
    with pytest.raises((ValueError, TypeError), match=message) as err:
        call()
    assert "\n" not in str(err.value)


def test_physics_without_soft_hand_says_so():
    physics = SoftPhysics.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    physics.step()  # plain MuJoCo
    with pytest.raises(RuntimeError, match="no soft hand"):
        physics.soft
