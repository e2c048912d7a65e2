"""Two-way coupling (Config.two_way; contact/exchange.py, SoftHand): the skin's contact impulses act on
MuJoCo's bodies, with Coulomb friction, checked against analytic references on a flat soft slab
(physhand_mj/bench/slab.py): a box resting on the skin is carried by a force m g and is not inside
it by either measure, its bounces die out, a heavier one sinks deeper, Newton's third law holds every
frame, and on a tilting table it sticks below atan(mu) and slides above it."""

import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.bench.slab import SlabRig, soft_slab

pytest.importorskip("tetgen")  # (the slab is built with the asset builder: the `build` extra)

G = 9.81


@pytest.fixture(scope="module")
def slab():
    return soft_slab()


def run(rig, frames):
    rows = []
    for _ in range(frames):
        s = rig.step()
        w = rig.hand.solver.contact.two_way.wrenches()
        rows.append((s["height"], *s["force"], s["penetration"], s["object_in_skin"],
                     *(w["objects"].sum(0)[:3] + w["bones"].sum(0)[:3]), float(np.abs(w["objects"][:, :3]).max())))
    return np.array(rows)


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_a_box_dropped_on_the_skin_rests_on_it(slab):
    """Dropped from 1 mm: over its last 50 of 200 frames the skin carries m g (within 5 %), no skin
    sample is inside the box and no box point inside the skin, the bounce is smaller than in the
    first 50 frames (no energy gained), and the forces on the box and on the table's core sum to 0."""
    rig = SlabRig(slab, mass=0.1, mu=0.5, gap=1.0e-3)
    r = run(rig, 200)
    assert np.all(np.isfinite(r))
    last = r[-50:]
    assert last[:, 3].mean() == pytest.approx(0.1 * G, rel=0.05)
    assert np.all(last[:, 4] == 0) and np.all(last[:, 5] == 0)
    swing = [np.ptp(r[a: a + 50, 0]) for a in (0, 150)]
    assert swing[1] < 0.5 * swing[0], swing
    assert np.abs(r[:, 6:9]).max() <= 1e-5 * max(r[:, 9].max(), 1e-9)  # Newton's third law, to float rounding


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
def test_a_heavier_box_sinks_deeper(slab):
    """50 g, 100 g and 200 g boxes laid on the skin: each settles deeper, and the skin's force tracks
    m g in each."""
    sink = []
    for mass in (0.05, 0.1, 0.2):
        rig = SlabRig(slab, mass=mass, mu=0.5, gap=-2.0e-4)
        r = run(rig, 120)
        sink.append(rig.half[2] - r[-40:, 0].mean())
        assert r[-40:, 3].mean() == pytest.approx(mass * G, rel=0.08)
    assert sink[0] < sink[1] < sink[2], sink


def test_a_box_far_from_the_skin_falls_as_in_mujoco_alone(slab):
    """A box 5 cm over the skin (no contact stage runs: nothing within the frame margin) falls exactly
    as MuJoCo alone moves it: the frame's stage-less substeps move it on with its velocity."""
    import mujoco

    rig = SlabRig(slab, mass=0.1, mu=0.5, gap=0.05)
    m2 = mujoco.MjModel.from_xml_string("""<mujoco><option timestep="0.005"/><worldbody><body name="box" pos="0 0 0">
      <freejoint/><geom type="box" size="0.015 0.015 0.01" mass="0.1"/></body></worldbody></mujoco>""")
    d2 = mujoco.MjData(m2)
    d2.qpos[:3] = rig.data.qpos[:3]
    z0 = rig.data.qpos[2]
    for _ in range(10):
        rig.step()
        mujoco.mj_step(m2, d2)
    assert rig.data.qpos[2] < z0 - 0.01  # it fell
    np.testing.assert_allclose(rig.data.qpos[:3], d2.qpos[:3], atol=1e-9)
    np.testing.assert_allclose(rig.data.qvel[:3], d2.qvel[:3], atol=1e-9)


def test_two_way_needs_the_models_timestep(slab):
    """A solver frame other than MuJoCo's step is refused with what to change."""
    import mujoco

    m = mujoco.MjModel.from_xml_string("""<mujoco><option timestep="0.002"/><worldbody><body name="table" mocap="true"/>
      <body name="box" pos="0 0 0.1"><freejoint/><geom type="box" size="0.01 0.01 0.01"/></body></worldbody></mujoco>""")
    with pytest.raises(ValueError, match="frame_dt"):
        ph.SoftHand(m, mujoco.MjData(m), ph.Config(two_way=True), asset=slab, writeback=False, settle_frames=1)


def test_one_way_is_unchanged_and_reports_no_applied_force(slab):
    """Without two_way the box falls through the slab's skin (the skin pushes nothing) and the
    contact report has no applied force."""
    rig = SlabRig(slab, mass=0.1, mu=0.5, gap=1.0e-3, config=ph.Config(two_way=False))
    rig.hand.solver.warn_feature_slack = False  # (the box falls through the skin: fast, on purpose)
    for _ in range(40):
        rig.step()
    assert rig.state()["height"] < -0.01
    assert "force" not in rig.hand.contacts()["objects"]["box"]


@pytest.mark.slow  # three ramps, ~600-900 frames each (~20-30 s each on a 2-core CPU)
@pytest.mark.parametrize("mu", [0.3, 0.6, 1.0])
def test_a_box_on_a_tilting_table_slides_at_atan_mu(slab, mu):
    """The pattern of Newton's test_rigid_friction_ramp: the box sticks while the table tilts (up to 2
    degrees under atan(mu) it has moved less than 4 mm since the slow tilt began, the 6 mm flesh's
    shear under it, and not slid) and slides from 2 degrees under atan(mu) to 5 over it. The bound
    above is the looser one: a slide too early is what a weak or missing friction gives, while the
    criterion (20 mm/s over 10 frames) lags the onset, and by how much depends on the host: the slab
    is remeshed at run time and at mu 0.6 the box creeps on the flesh before the criterion sees a
    slide. mu 0.6 slid at 32.5 degrees on the host docs/coupling.md reports, at 34.5 on a 2-core AMD
    EPYC host of 2026-11-29 and at 35.1 on another of 2026-12-03 (atan(mu) 31.0; there it had moved 2
    mm at 30.7 degrees and 5 mm at 34.8; the same code, deterministic on each host)."""
    from physhand_mj.bench.slab import slide_angle

    rig = SlabRig(slab, mass=0.1, mu=mu, gap=-3.5e-4)
    r = slide_angle(rig, np.arctan(mu) - np.radians(8.0))
    assert -2.0 <= np.degrees(r["angle"] - np.arctan(mu)) <= 5.0, np.degrees(r["angle"])
    track = r["track"]  # (table angle rad, m moved down the slope since the slow tilt began)
    stuck = track[track[:, 0] <= np.arctan(mu) - np.radians(2.0)]
    assert len(stuck) > 0 and stuck[-1, 1] < 4.0e-3, stuck[-1] if len(stuck) else "no frame under atan(mu) - 2 deg"


@pytest.mark.soak  # 10,000 frames (~4 min on a 2-core CPU): `pytest -m soak tests/test_two_way.py`
def test_a_box_resting_for_10000_frames_stays_put(slab):
    """A 100 g box on the skin for 50 s of simulated time: finite, no drift (under 0.05 mm between
    frames 1,000 and 10,000), no growing jitter (the height's range over the last 1,000 frames no
    more than over frames 1,000-2,000, plus 1 um), both measures 0 at the end."""
    rig = SlabRig(slab, mass=0.1, mu=0.5, gap=-3.0e-4)
    pos, h = [], []
    for f in range(10_000):
        s = rig.step()
        pos.append(s["pos"])
        h.append(s["height"])
    pos, h = np.array(pos), np.array(h)
    assert np.all(np.isfinite(pos))
    assert np.linalg.norm(pos[-1] - pos[999]) < 5.0e-5, np.linalg.norm(pos[-1] - pos[999])
    assert np.ptp(h[-1000:]) <= np.ptp(h[1000:2000]) + 1.0e-6, (np.ptp(h[-1000:]), np.ptp(h[1000:2000]))
    assert s["penetration"] == 0 and s["object_in_skin"] == 0
    print(f"soak: drift {np.linalg.norm(pos[-1] - pos[999]) * 1e3:.4f} mm, jitter {np.ptp(h[1000:2000]) * 1e3:.4f} -> "
          f"{np.ptp(h[-1000:]) * 1e3:.4f} mm, force {s['force'][2]:.4f} N")
