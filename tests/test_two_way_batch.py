"""Two-way coupling in BatchedHands (Config.two_way; batch.BatchTwoWay): W worlds of the soft slab
(physhand_mj/bench/slab.py), each with its own box and table motion, stepped by one batch and a
MuJoCo model per world, against SoftHand's own run of each world alone (the reference: the same
exchange through SoftHand._send_objects / _apply_wrenches). Per world: the batch's boxes move as
SoftHand's do (float tolerance on the CPU), Newton's third law holds every frame, and a world whose
box is far from its skin falls exactly as MuJoCo alone moves it."""

import mujoco
import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.bench.slab import SlabRig, soft_slab
from physhand_mj.coupling import rest_placement
from physhand_mj.types import GeomType

pytest.importorskip("tetgen")  # (the slab is built with the asset builder: the `build` extra)

FRAMES = 40
# per world: box mass kg, gap over the skin m, the table's rise m/s (its bones move: their velocities
# reach the exchange), the friction coefficient
WORLDS = [(0.1, 1.0e-3, 0.0, 0.5), (0.2, 2.0e-3, 0.01, 0.8), (0.1, 0.25, 0.0, 0.5)]


@pytest.fixture(scope="module")
def slab():
    return soft_slab()


def rigs(slab):
    return [SlabRig(slab, mass=m, mu=mu, gap=gap) for m, gap, _, mu in WORLDS]


def free_velocity(m, d, b, start=False):
    """[linear m/s of the centre, angular rad/s], world frame, of free body ``b`` after mj_step
    (as SoftHand._send_objects reads it); ``start``: before it (qvel - qacc dt)."""
    dof = m.jnt_dofadr[m.body_jntadr[b]]
    qv = d.qvel - d.qacc * m.opt.timestep if start else d.qvel
    w = d.xmat[b].reshape(3, 3) @ qv[dof + 3: dof + 6]
    return np.r_[qv[dof: dof + 3] + np.cross(w, d.xipos[b] - d.xpos[b]), w]


def quat_of(mat):
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(mat, float).ravel())
    return q


def apply(m, d, box, table, tw, w, frame_dt):
    """Per world, what SoftHand._apply_wrenches does: the impulses into qvel (M^-1 J^T), the free box
    at its in-frame pose."""
    qimp = np.zeros(m.nv)
    imp = tw["wrench"][w, 0] * frame_dt
    mujoco.mj_applyFT(m, d, imp[:3], imp[3:], d.xipos[box], box, qimp)
    imp = tw["bones"][w, 0] * frame_dt
    mujoco.mj_applyFT(m, d, imp[:3], imp[3:], d.xipos[table], table, qimp)
    dq = np.zeros(m.nv)
    mujoco.mj_solveM(m, d, dq.reshape(1, -1), qimp.reshape(1, -1))
    d.qvel[:] += dq
    one = {k: v[w: w + 1] for k, v in tw.items()}
    p, q = ph.BatchedHands.two_way_poses(one, d.xpos[box][None, None], d.xquat[box][None, None])
    d.qpos[:3], d.qpos[3:7] = p[0, 0], q[0, 0]


def run_serial(slab):
    out = []
    for (mass, gap, rise, mu), rig in zip(WORLDS, rigs(slab)):
        rows = []
        for f in range(FRAMES):
            rig.data.mocap_pos[0][2] += rise * rig.model.opt.timestep
            rig.step()
            w = rig.hand.solver.contact.two_way.wrenches()
            rows.append(np.r_[rig.data.qpos[:7], rig.data.qvel[:6], w["objects"][0], w["bones"][0]])
        out.append(np.array(rows))
    return np.stack(out)  # (W, frames, 7 + 6 + 6 + 6)


def run_batched(slab):
    rs = rigs(slab)  # (their models and data at the start; their SoftHands are not stepped)
    W = len(rs)
    cfg = ph.Config(two_way=True)
    m0 = rs[0].model
    place = [rest_placement(slab, r.data.xpos[r.model.body("table").id], r.data.xquat[r.model.body("table").id])
             for r in rs]
    box = dict(gtype=GeomType.BOX, size=np.array(rs[0].half), name="box")
    inertia = np.array([r.model.body_inertia[r.box] for r in rs])
    hands = ph.BatchedHands(slab, W, cfg, pos=np.array([p for p, _ in place]), quat=np.array([q for _, q in place]),
                            objects=[box], object_mass=np.array([[m] for m, *_ in WORLDS]),
                            object_inertia=inertia[:, None], object_friction=np.array([[mu] for *_, mu in WORLDS]))
    table = m0.body("table").id
    bone = lambda: (np.array([[r.data.xpos[table]] for r in rs]), np.array([[r.data.xquat[table]] for r in rs]))
    hands.settle(*bone(), frames=2)
    rows = [[] for _ in rs]
    for f in range(FRAMES):
        for (mass, gap, rise, mu), r in zip(WORLDS, rs):
            r.data.mocap_pos[0][2] += rise * r.model.opt.timestep
            mujoco.mj_step(r.model, r.data)
        g = rs[0].model.geom("box").id
        out = hands.step(*bone(), np.array([[r.data.geom_xpos[g]] for r in rs]),
                         np.array([[quat_of(r.data.geom_xmat[g])] for r in rs]),
                         object_vel=np.array([[free_velocity(r.model, r.data, r.box)] for r in rs]),
                         object_vel_start=np.array([[free_velocity(r.model, r.data, r.box, True)] for r in rs]),
                         object_com=np.array([[r.data.xipos[r.box]] for r in rs]),
                         object_iquat=np.array([[quat_of(r.data.ximat[r.box])] for r in rs]),
                         bone_com=np.array([[r.data.xipos[table]] for r in rs]))
        tw = out["two_way"]
        for w, r in enumerate(rs):
            apply(r.model, r.data, r.box, table, tw, w, cfg.frame_dt)
            rows[w].append(np.r_[r.data.qpos[:7], r.data.qvel[:6], tw["wrench"][w, 0], tw["bones"][w, 0]])
        third = tw["wrench"][..., :3].sum(1) + tw["bones"][..., :3].sum(1)  # per world
        scale = max(float(np.abs(tw["wrench"][..., :3]).max()), 1e-9)
        assert np.abs(third).max() <= 1e-5 * scale, third  # Newton's third law, per world, every frame
    return np.array(rows)


@pytest.fixture(scope="module")
def runs(slab):
    return run_serial(slab), run_batched(slab)


def test_batched_worlds_move_their_boxes_as_softhand_does(runs):
    """Every world's box, its velocity and the wrenches as SoftHand's run of that world alone gives
    them, to float32 tolerance: the batch's float32 in-frame motion of a box (and of world 2's, moved
    over stages the other worlds' contact runs, where SoftHand's host moves it in float64) differs in
    the last digits, and contact amplifies those a little; the box's small inertia (3e-5 kg m^2)
    turns torque differences of uN m into mrad/s."""
    serial, batched = runs
    assert np.all(np.isfinite(batched))
    # worlds 0 and 1 rest on their skin (it carries m g), world 2's box never reaches it
    assert batched[0, -10:, 15].mean() == pytest.approx(0.1 * 9.81, rel=0.1)
    assert batched[1, -10:, 15].mean() == pytest.approx(0.2 * 9.81, rel=0.1)
    assert np.all(batched[2, :, 13:] == 0)
    first = int(np.argmax(np.abs(serial[0, :, 15]) > 0))  # the first frame with contact: float rounding only
    np.testing.assert_allclose(batched[:, first, 13:16], serial[:, first, 13:16], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(batched[:, :, :3], serial[:, :, :3], atol=1e-6)  # box positions, m
    # orientations (quaternion components; the friction's owed slip carries each skin vertex's last
    # digits from substep to substep: 2.3e-5 seen)
    np.testing.assert_allclose(batched[:, :, 3:7], serial[:, :, 3:7], atol=5e-5)
    np.testing.assert_allclose(batched[:, :, 7:10], serial[:, :, 7:10], atol=5e-5)  # m/s (2.7e-5 seen: the owed slip)
    np.testing.assert_allclose(batched[:, :, 10:13], serial[:, :, 10:13], atol=5e-3)  # rad/s
    np.testing.assert_allclose(batched[:, :, 13:16], serial[:, :, 13:16], atol=1e-3)  # N
    np.testing.assert_allclose(batched[:, :, 16:19], serial[:, :, 16:19], atol=5e-5)  # N m (2.7e-5 seen: the owed slip)
    np.testing.assert_allclose(batched[:, :, 19:22], serial[:, :, 19:22], atol=1e-3)  # the bones' reaction, N


def test_a_world_without_contact_falls_as_in_mujoco_alone(runs):
    """World 2's box (25 cm over its skin) falls as MuJoCo alone moves it while the other worlds'
    boxes land on their skins (the batch moves it in float32 over their stages: to 1e-8 m)."""
    batched = runs[1]
    m2 = mujoco.MjModel.from_xml_string("""<mujoco><option timestep="0.005"/><worldbody><body name="box" pos="0 0 0">
      <freejoint/><geom type="box" size="0.015 0.015 0.01" mass="0.1"/></body></worldbody></mujoco>""")
    d2 = mujoco.MjData(m2)
    d2.qpos[:3] = [0.0, 0.0, 0.1 + float(soft_slab().skin_vertices[:, 2].max()) + 0.01 + 0.25]
    for f in range(FRAMES):
        mujoco.mj_step(m2, d2)
        np.testing.assert_allclose(batched[2, f, :3], d2.qpos[:3], atol=1e-8)
        np.testing.assert_allclose(batched[2, f, 7:13], d2.qvel[:6], atol=1e-12)
    assert batched[2, -1, 2] < d2.qpos[2] + 1e-8 and d2.qpos[2] < 0.1 + 0.25 - 0.1  # (it fell ~20 cm)


def test_two_way_batch_inputs_are_checked(slab):
    """Two-way inputs without two_way, and mis-shaped ones, are refused with what to pass."""
    box = dict(gtype=GeomType.BOX, size=np.array([0.015, 0.015, 0.01]), name="box")
    with pytest.raises(ValueError, match="two_way"):
        ph.BatchedHands(slab, 2, ph.Config(), objects=[box], object_mass=[0.1])
    with pytest.raises(ValueError, match="object_inertia"):
        ph.BatchedHands(slab, 2, ph.Config(two_way=True), objects=[box], object_mass=[0.1])
    hands = ph.BatchedHands(slab, 2, ph.Config(two_way=True), objects=[box], object_mass=[0.1],
                            object_inertia=[[1e-5, 1e-5, 1e-5]])
    pos, quat = np.zeros((2, 1, 3)), np.tile([1.0, 0, 0, 0], (2, 1, 1))
    with pytest.raises(ValueError, match="object_vel"):
        hands.step(pos, quat, np.full((2, 1, 3), 0.5), np.tile([1.0, 0, 0, 0], (2, 1, 1)), object_vel=np.zeros((2, 6)))
