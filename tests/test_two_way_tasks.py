"""Two-way coupling (Config.two_way) where the hand is used: `physhand rollout --two-way` (its
forces.csv), the dm-control suite (SoftPhysics steps whole mj_steps, a soft frame each) and the
MyoSuite wrapper (a soft frame after every MuJoCo step of the env's frame skip). Short CPU runs:
that each works end to end, reports the wrench it applied, keeps Newton's third law, and moves a
free object far from the skin exactly as MuJoCo alone does (no double move of the step)."""

import csv
import json

import mujoco
import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.cli import main


def third_law(hand):
    w = hand.solver.contact.two_way.wrenches()
    total = w["objects"][:, :3].sum(0) + w["bones"][:, :3].sum(0)
    return float(np.abs(total).max()), float(np.abs(w["objects"][:, :3]).max())


# -- physhand rollout ---------------------------------------------------------------------------------
def test_rollout_two_way_logs_the_force_on_each_object(tmp_path, capsys):
    assert main(["rollout", "hoi_apple", "--steps", "3", "--two-way", "--device", "cpu", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["two_way"] is True and summary["finite"] and summary["forces"] == str(tmp_path / "forces.csv")
    rows = list(csv.DictReader(open(tmp_path / "forces.csv")))
    apple = [r for r in rows if r["object"] == "apple"]
    assert [int(r["step"]) for r in apple] == [1, 2, 3]
    f = np.array([[float(r[f"force_{a}_n"]) for a in "xyz"] for r in apple])
    # the grasp keyframe starts with the skin in the apple: the skin pushes it (docs/coupling.md)
    assert np.all(np.isfinite(f)) and np.all(np.linalg.norm(f, axis=1) > 0.1)
    assert all(int(r["contacts"]) > 0 for r in apple)


def test_rollout_without_two_way_writes_no_forces(tmp_path, capsys):
    assert main(["rollout", "hoi_apple", "--steps", "1", "--device", "cpu", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "two_way" not in summary and not (tmp_path / "forces.csv").exists()


def test_batched_two_way_rollout_moves_each_world_as_the_serial_rollout(tmp_path, capsys):
    """--two-way --batch 2: two worlds of the apple grasp (world 1's queries 1 m away) against the
    serial two-way rollout: the same forces on the apple each frame (each frame's wrenches went into
    that world's MuJoCo before its next step: a missed or doubled exchange changes the next frames'
    forces), friction and contact counts included."""
    runs = tmp_path / "runs.txt"
    apple = ph.scene_path("hoi_apple")
    runs.write_text(f"{apple} grasp\n{apple} grasp\n")
    assert main(["rollout", str(runs), "--two-way", "--batch", "2", "--steps", "3", "--device", "cpu",
                 "--out", str(tmp_path / "batch")]) == 0
    assert main(["rollout", "hoi_apple", "--two-way", "--steps", "3", "--device", "cpu",
                 "--out", str(tmp_path / "serial")]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    assert [r.get("two_way") for r in rows] == [True] * 3

    def forces(path):
        table = [r for r in csv.DictReader(open(path)) if r["object"] == "apple"]
        return np.array([[float(r[c]) for c in r if c not in ("object", "time_s")] for r in table])

    serial = forces(tmp_path / "serial" / "forces.csv")
    assert serial.shape == (3, 11) and np.all(np.abs(serial[:, 1:4]).max(1) > 0.1)
    for name in ("hoi_apple-grasp", "hoi_apple-grasp-1"):
        batch = forces(tmp_path / "batch" / name / "forces.csv")
        np.testing.assert_allclose(batch[:, :-1], serial[:, :-1], atol=1e-3)  # step, force, torque, friction
        assert np.all(np.abs(batch[:, -1] - serial[:, -1]) <= 2)  # skin vertices touching it


# -- dm-control suite ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def dmc():
    pytest.importorskip("dm_control")
    from physhand_dmc import suite

    return suite


CONFIG = dict(substeps=3, frame_dt=0.005, two_way=True)


@pytest.mark.parametrize("domain,task,obj", [("hand_hold", "apple", "apple"), ("fingertip_press", "index", "plate")])
def test_dmc_task_runs_two_way(dmc, domain, task, obj):
    """A control step (2 physics steps of 5 ms) runs two soft frames; the object's wrench is reported,
    finite, and balanced by the bones' reaction."""
    env = dmc.load(domain, task, task_kwargs=dict(random=0, settle_frames=3, config=ph.Config(**CONFIG),
                                                   time_limit=0.03))
    ts = env.reset()
    steps = env.physics.timing["steps"]
    for _ in range(2):
        ts = env.step(np.zeros(env.action_spec().shape))
        for v in ts.observation.values():
            assert np.all(np.isfinite(v))
    hand = env.physics.soft
    assert env.physics.timing["steps"] - steps == 2 * round(env.control_timestep() / 0.005)
    w = hand.applied_wrenches()[obj]
    assert np.all(np.isfinite(w["force"])) and np.all(np.isfinite(w["torque"]))
    err, scale = third_law(hand)
    assert err <= 1e-5 * max(scale, 1e-9)
    if domain == "hand_hold":  # the keyframe's overlap: the skin pushes the apple
        assert np.linalg.norm(w["force"]) > 0.1


def test_dmc_two_way_moves_a_far_object_as_mujoco_alone(dmc):
    """The apple lifted 0.3 m out of the hand: with two_way it moves over 4 physics steps exactly as
    dm_control's own Physics (without the soft hand) moves it, the step not taken twice."""
    # (the reset's squeeze and gravity-free float left out: their joint-limit constraints make MuJoCo's
    # own legacy and whole steps differ by a warm start, which is not what this compares)
    env = dmc.load("hand_hold", "apple", task_kwargs=dict(random=0, settle_frames=3, config=ph.Config(**CONFIG),
                                                          gravity="down", squeeze=1.0, float_frames=0))
    env.reset()
    p = env.physics
    j = p.model.body_jntadr[p.model.name2id("apple", "body")]
    a, v = p.model.jnt_qposadr[j], p.model.jnt_dofadr[j]
    p.data.qpos[a + 2] += 0.3
    p.data.qvel[v: v + 6] = [0.05, -0.02, 0.1, 0.5, -0.3, 0.2]
    p.forward()
    alone = p.copy()  # (dm_control's Physics: no soft hand)
    p.step(4)
    alone.step(4)
    np.testing.assert_allclose(p.data.qpos[a: a + 7], alone.data.qpos[a: a + 7], atol=1e-9)
    np.testing.assert_allclose(p.data.qvel[v: v + 6], alone.data.qvel[v: v + 6], atol=1e-9)
    np.testing.assert_allclose(p.data.xpos, alone.data.xpos, atol=1e-9)  # (data in sync, as dm_control's)


# -- MyoSuite -----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def myo():
    pm = pytest.importorskip("physhand_myosuite")
    pytest.importorskip("myosuite")
    return pm


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_myosuite_objhold_two_way_steps_a_soft_frame_per_mujoco_step(myo):
    env = myo.make("myoHandObjHoldFixed-v0", two_way=True, settle_frames=3)
    u = env.unwrapped
    assert env.config.two_way and env.config.frame_dt == pytest.approx(u.model.opt.timestep)
    env.reset(seed=0)
    frames = env.hand.metrics()["frames"]
    for _ in range(2):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0)
        assert np.all(np.isfinite(obs)) and info["physhand"]["finite"]
    assert env.hand.metrics()["frames"] - frames == 2 * u.frame_skip
    applied = {o: d["applied"] for o, d in info["physhand"]["objects"].items()}
    assert applied and all(np.all(np.isfinite(a["force"])) for a in applied.values())
    err, scale = third_law(env.hand)
    assert err <= 1e-5 * max(scale, 1e-9)
    env.close()


def test_myosuite_two_way_moves_a_far_object_as_mujoco_alone(myo):
    """The held object lifted 0.3 m out of the hand moves over an env step as MuJoCo alone moves it."""
    env = myo.make("myoHandObjHoldFixed-v0", two_way=True, settle_frames=3)
    env.reset(seed=0)
    m, d = env.model, env.data
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert free
    a, v = m.jnt_qposadr[free[0]], m.jnt_dofadr[free[0]]
    d.qpos[a + 2] += 0.3
    d.qvel[v: v + 6] = [0.05, -0.02, 0.1, 0.5, -0.3, 0.2]
    mujoco.mj_forward(m, d)
    d2 = mujoco.MjData(m)
    d2.qpos[:], d2.qvel[:], d2.act[:], d2.time = d.qpos, d.qvel, d.act, d.time
    action = np.zeros(env.action_space.shape)
    env.step(action)
    d2.ctrl[:] = d.ctrl
    mujoco.mj_step(m, d2, env.unwrapped.frame_skip)
    np.testing.assert_allclose(d.qpos[a: a + 7], d2.qpos[a: a + 7], atol=1e-9)
    np.testing.assert_allclose(d.qvel[v: v + 6], d2.qvel[v: v + 6], atol=1e-9)
    env.close()
