"""Batched task environments (physhand_dmc.vector, issue 54) on the CPU: world k against the single
environment with the same seed and actions, worlds independent of each other, per-world resets,
the time limit and autoreset, DLPack arrays, and clear errors."""

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

from physhand_dmc import vector  # noqa: E402
from vector_vs_single import actions, single_run  # noqa: E402

CPU = ph.Config(frame_dt=0.005, device="cpu")
TWO_WAY = ph.Config(frame_dt=0.005, device="cpu", two_way=True)


def run(env, acts, seed):
    obs, _ = env.reset(seed=seed)
    out, rew = [obs], []
    for a in acts:
        obs, r, *_ = env.step(a)
        out.append(obs)
        rew.append(r)
    return np.array(out), np.array(rew)


@pytest.fixture(scope="module")
def press():
    env = vector.make("fingertip_press", "index", num_envs=2, task_kwargs={"config": CPU}, device="cpu")
    yield env
    env.close()


def test_world_k_is_the_single_env_with_seed_plus_k(press):
    """One-way (the press): each world follows the single environment (MuJoCo's float64 C step) to
    MuJoCo Warp's float32 rounding: joints within 1e-6 rad, rewards within 1e-3, over 4 steps; the
    two worlds draw different targets (their own seeds)."""
    obs, _ = press.reset(seed=7)
    acts = actions(press.task.normalise_ctrl(press.physics.host("ctrl")), 4)
    batch_obs, batch_rew = run(press, acts, 7)
    s = press.obs_slices
    assert batch_obs[0, 0, s["target_force"]] != batch_obs[0, 1, s["target_force"]]
    for w in range(2):
        o, r = single_run("fingertip_press", "index", dict(config=CPU, random=7 + w), acts[:, w])
        assert o.shape == batch_obs[:, w].shape
        assert np.abs(o[:, s["target_force"]] - batch_obs[:, w, s["target_force"]]).max() < 1e-6
        assert np.abs(o[:, s["joint_pos"]] - batch_obs[:, w, s["joint_pos"]]).max() < 1e-6
        assert np.abs(o[:, s["object_contact"]][:, 1] - batch_obs[:, w, s["object_contact"]][:, 1]).max() < 1e-3  # N
        assert np.abs(r - batch_rew[:, w]).max() < 1e-3
        assert np.ptp(r) > 0  # (the reward moves: the comparison is not of constants)


def test_two_way_world_follows_the_single_env_frame_by_frame():
    """Two-way (hand_hold along the palm, no floating frames at the reset): the batched exchange is
    the single one's (object pushed, bones pushed back, qvel += M^-1 J^T impulses); over two env
    steps (four frames) the joints stay within 1e-4 rad and the object within 0.01 mm of the single
    environment's (the exchange amplifies float32's rounding frame by frame: docs/training.md)."""
    kw = dict(gravity="down", config=TWO_WAY, float_frames=0)
    env = vector.make("hand_hold", "apple", num_envs=1, task_kwargs=kw, device="cpu")
    env.reset(seed=4)
    acts = actions(env.task.normalise_ctrl(env.physics.host("ctrl")), 2)
    batch_obs, batch_rew = run(env, acts, 4)
    o, r = single_run("hand_hold", "apple", dict(kw, random=4), acts[:, 0])
    s = env.obs_slices
    assert np.abs(o[:, s["joint_pos"]] - batch_obs[:, 0, s["joint_pos"]]).max() < 1e-4
    assert np.abs(o[:, s["object_offset"]] - batch_obs[:, 0, s["object_offset"]]).max() < 1e-5
    assert np.abs(r - batch_rew[:, 0]).max() < 1e-3
    assert np.abs(batch_obs[:, 0, s["object_contact"]][:, 1]).max() > 0.1  # (in contact: the skin holds it)
    env.close()


def test_worlds_with_one_seed_are_identical_and_a_partial_reset_leaves_the_others(press):
    """Worlds never interact: two worlds with one seed are bit for bit alike, and restarting one of
    them (``reset_mask``) leaves the other's trajectory as it was."""
    acts = actions(press.task.normalise_ctrl(press.physics.host("ctrl")), 4)
    acts[:, 1] = acts[:, 0]
    obs, rew = run(press, acts, [5, 5])
    assert np.array_equal(obs[:, 0], obs[:, 1]) and np.array_equal(rew[:, 0], rew[:, 1])
    press.reset(seed=[5, 5])
    for a in acts[:2]:
        press.step(a)
    first, _ = press.reset(seed=[9, 9], options={"reset_mask": [True, False]})
    s = press.obs_slices
    assert np.array_equal(first[1], obs[2, 1])  # (the kept world's observation, not the reset's)
    assert first[0, s["target_force"]] != obs[0, 0, s["target_force"]]  # (world 0 drew seed 9's target)
    kept = []
    for a in acts[2:]:
        o, *_ = press.step(a)
        kept.append(o[1])
    assert np.abs(np.array(kept) - obs[3:, 1]).max() < 1e-5


def test_time_limit_truncates_and_autoresets_in_the_same_step():
    env = vector.make("fingertip_press", "index", num_envs=2, task_kwargs={"config": CPU, "time_limit": 0.03},
                      device="cpu")
    assert env.metadata["autoreset_mode"].name == "SAME_STEP"
    obs0, _ = env.reset(seed=0)
    a = np.zeros((2, env.physics.model.nu))
    for k in range(3):
        obs, r, term, trunc, info = env.step(a)
        assert not term.any() and trunc.all() == (k == 2)
    assert info["_final_obs"].all() and info["final_obs"].dtype == object  # (gymnasium's SAME_STEP convention)
    final = np.stack(info["final_obs"])
    assert final.shape == obs.shape and not np.array_equal(final, obs)  # (the episode's last observation, then the new one)
    s = env.obs_slices["joint_pos"]
    assert np.abs(obs[:, s] - obs0[:, s]).max() < 1e-6  # the new episode starts where the first did (keyframe)
    obs, r, term, trunc, info = env.step(a)
    assert not trunc.any() and env.steps.tolist() == [1, 1]
    env.close()


def test_device_arrays_and_bad_input(press):
    press.device_arrays = True
    try:
        obs, _ = press.reset(seed=0)
        host = np.from_dlpack(obs)
        assert host.shape == (2, press.single_observation_space.shape[0]) and np.isfinite(host).all()
        assert press.observation_space.shape == host.shape and press.action_space.shape == (2, press.physics.model.nu)
    finally:
        press.device_arrays = False
    with pytest.raises(ValueError, match="actions must be"):
        press.step(np.zeros((3, press.physics.model.nu)))
    with pytest.raises(ValueError, match="NaN"):
        press.step(np.full((2, press.physics.model.nu), np.nan))
    with pytest.raises(ValueError, match="reset_mask"):
        press.reset(options={"reset_mask": [True]})
    with pytest.raises(TypeError, match="unknown task_kwargs"):
        vector.make("fingertip_press", "index", num_envs=1, task_kwargs={"target": 1.0})
    with pytest.raises(ValueError, match="batched domains"):
        vector.make("jaco_lift", "lift", num_envs=1)
    with pytest.raises(ValueError, match="num_envs"):
        vector.make("fingertip_press", "index", num_envs=0)


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_two_way_partial_reset_keeps_the_other_worlds_bones_moving():
    """Two-way, no floating frames: restarting world 0 leaves world 1 on its trajectory (its bones'
    velocities, its feature lists' slack, its friction anchors and its state put back), within 1e-5
    rad of an uninterrupted run over two steps; and a second episode with the same seeds is the first
    (the reset clears the two-way exchange; the single env's too: the test after this)."""
    kw = dict(gravity="down", config=TWO_WAY, float_frames=0)
    env = vector.make("hand_hold", "apple", num_envs=2, task_kwargs=kw, device="cpu")
    acts = actions(np.repeat(env.task.normalise_ctrl(env.physics.host("ctrl"))[:1], 2, 0), 4)
    ref, _ = run(env, acts, [4, 4])
    again, _ = run(env, acts, [4, 4])
    assert np.array_equal(ref, again)  # (episodes repeat: nothing of the last one carried over)
    env.reset(seed=[4, 4])
    for a in acts[:2]:
        env.step(a)
    env.reset(seed=[6, 6], options={"reset_mask": [True, False]})
    kept = [env.step(a)[0][1] for a in acts[2:]]
    s = env.obs_slices["joint_pos"]
    # (1.7e-6 rad measured: the solver's frame count and wake state are the batch's, not per world;
    # before the bones' history, the slack and the friction anchors were put back: 1.8e-3)
    assert np.abs(np.array(kept)[:, s] - ref[3:, 1, s]).max() < 1e-5
    env.close()


def test_a_world_gone_non_finite_ends_alone_without_nan():
    env = vector.make("fingertip_press", "index", num_envs=2, task_kwargs={"config": CPU}, device="cpu")
    with pytest.raises(ValueError, match="first reset"):
        env.reset(options={"reset_mask": [True, False]})
    env.reset(seed=0)
    a = np.zeros((2, env.physics.model.nu))
    env.step(a)
    qvel = env.physics.host("qvel")
    qvel[1] = np.nan
    env.physics.set_host("qvel", qvel)
    obs, r, term, trunc, info = env.step(a)
    assert term.tolist() == [False, True] and np.isfinite(r).all() and r[1] == 0.0
    assert np.isfinite(obs).all() and np.isfinite(info["final_obs"][1]).all() and info["final_obs"][0] is None
    assert env.steps.tolist() == [2, 0]  # (world 1 started over in the step that ended it)
    obs, r, term, trunc, info = env.step(a)
    assert not term.any() and np.isfinite(obs).all()
    env.close()


def test_single_two_way_env_repeats_an_episode_with_its_seed():
    """SoftHand.reset clears the two-way exchange: a second episode from the same RNG state is the
    first (before, its settling frames ran with the last episode's object velocities and friction
    anchors)."""
    kw = dict(gravity="down", config=TWO_WAY, float_frames=0, random=4)
    acts = np.zeros((3, 23))
    from physhand_dmc import suite

    env = suite.load("hand_hold", "apple", task_kwargs=kw, environment_kwargs={"flat_observation": True})
    runs = []
    for _ in range(2):
        env.task._random = np.random.RandomState(4)
        ts = env.reset()
        obs = [ts.observation["observations"]]
        for a in acts:
            obs.append(env.step(a).observation["observations"])
        runs.append(np.array(obs))
    assert np.array_equal(runs[0], runs[1])
