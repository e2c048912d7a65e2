"""Config.contact_linear (physhand_mj/contact/linear.py): between contact stages the skin is held on
the planes the last stage linearised the SDF to at its decision points. Checked against the box's
exact SDF taken here in numpy (not the planes' own numbers) and the skin measure per substep."""

import numpy as np
import pytest
import warp as wp

from activity_helpers import _solver, _step, scene  # noqa: F401  (scene: a module fixture)
from test_batch import _beside_serial, setup  # noqa: F401  (setup: a module fixture)
from physhand_mj.hand_mjcf import bone_poses_at
from physhand_mj.contact.linear import Planes, hold_planes, roll_planes
from physhand_mj.contact.query import apply_contact
from physhand_mj.launch import Recorder
from physhand_mj.types import Config, GeomType

HALF = np.array([0.02, 0.02, 0.005])  # m, the box's half extents
PRESS = 0.002  # m, its bottom face below the back of the hand's highest skin point
TILT = 0.15  # rad, the box turned about x (so that a plane's frame shows: world and geom frames differ)


def _quat_x(angle: float) -> tuple:
    return (float(np.cos(angle / 2)), float(np.sin(angle / 2)), 0.0, 0.0)  # w x y z


def _rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _box_sdf(p: np.ndarray, centre: np.ndarray, angle: float = TILT) -> np.ndarray:
    """Exact signed distance (m) of points p (N, 3) to the box at ``centre`` turned ``angle`` about x."""
    q = np.abs((p - centre) @ _rot_x(angle)) - HALF  # R^T (p - c), row-wise
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def _pressed(scene, frames=2, **config):  # noqa: F811
    solver, state, objects, top = _solver(scene, GeomType.BOX, tuple(HALF), **config)
    centre = top + _rot_x(TILT) @ [0.0, 0.0, HALF[2] - PRESS]
    objects.set_pose(0, centre, _quat_x(TILT))
    outs = [_step(solver, state, scene[2]) for _ in range(frames)]
    return solver, state, objects, centre, outs


def _hold_once(solver, state, plane_state=None) -> int:
    """One hold pass (hold_planes + apply_contact) launched here on the contact's planes (or with the
    flags ``plane_state``); returns how many vertices it corrected."""
    c, o, m = solver.contact, solver.contact.objects, solver.model
    count = wp.zeros(1, dtype=int, device="cpu")
    planes = c.hold.data.planes
    if plane_state is not None:  # (a copy of the struct with those flags)
        planes = Planes()
        planes.tri, planes.bary, planes.geom, planes.eq = (c.hold.data.tri, c.hold.data.bary, c.hold.data.geom,
                                                           c.hold.data.eq)
        planes.state = plane_state
    wp.launch(hold_planes, c.n_tris, inputs=[m.skin_faces, planes, o.geoms, solver.config.contact_offset, state.x],
              outputs=[c.acc.sums, count], device="cpu")
    shift, shifted = c.space.apply_shift(state)
    wp.launch(apply_contact, m.n_vertices, inputs=[c.acc.sums, count, 10_000, shift, c.bone_hold, c.exchange],
              outputs=[state.x, c.push, c.acc.moved, c.acc.disp, c.lists.pass_move, shifted], device="cpu")
    return int(count.numpy()[0])


def _next_frame_flags(solver) -> wp.array:
    """The planes' flags as the next frame's start leaves them (roll_planes on a copy)."""
    flags = wp.clone(solver.contact.hold.data.state)
    wp.launch(roll_planes, 1, inputs=[flags], device="cpu")
    return flags


def _planes(contact):
    n = int(contact.hold.data.state.numpy()[0])
    return (contact.hold.data.tri.numpy()[:n], contact.hold.data.bary.numpy()[:n], contact.hold.data.geom.numpy()[:n],
            contact.hold.data.eq.numpy()[:n])


def _plane_points(solver, state, tri, bary):
    faces = solver.model.skin_faces.numpy()[tri]
    x = state.x.numpy()
    return np.einsum("nk,nkd->nd", bary, x[faces]).astype(np.float64)


def test_the_planes_are_the_box_faces_at_their_points(scene):  # noqa: F811
    """After a frame pressing a box into the back of the hand, every plane the frame's last stage
    made is the box's exact SDF at its point, with a unit normal (most of them the bottom face's),
    its point within contact_margin."""
    solver, state, _, centre, outs = _pressed(scene, contact_every=2, contact_linear=True)
    assert outs[-1]["penetration_count"] == 0
    tri, bary, geom, eq = _planes(solver.contact)
    assert len(tri) > 20 and np.all(geom == 0)
    assert np.allclose(bary.sum(axis=1), 1.0, atol=1e-5) and np.all(bary >= 0.0)
    p = _plane_points(solver, state, tri, bary)
    exact = _box_sdf(p, centre)
    local = (p - centre) @ _rot_x(TILT)  # the planes live in the box's frame
    by_plane = np.einsum("nd,nd->n", eq[:, :3].astype(np.float64), local) + eq[:, 3]
    assert np.abs(by_plane - exact).max() < 1.0e-6, np.abs(by_plane - exact).max()
    assert np.all(exact < Config().validate().contact_margin)
    g = eq[:, :3]
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-5)
    assert np.mean(g[:, 2] < -0.9999) > 0.9  # most on the bottom face, pressing on the back of the hand


def test_the_hold_follows_the_box_when_it_moves(scene):  # noqa: F811
    """The planes live in the box's frame: lowered 0.3 mm into the skin and turned 0.02 rad more
    after a frame, one hold pass lifts the skin so that no plane point is inside the box by its
    exact SDF, where they were ~0.3 mm inside before it."""
    solver, state, objects, centre, _ = _pressed(scene, contact_every=2, contact_linear=True)
    tri, bary, _, _ = _planes(solver.contact)
    turn = TILT + 0.02
    moved = centre - _rot_x(turn) @ [0.0, 0.0, 3.0e-4]  # (the box sits on the back of the hand: into the skin)
    objects.set_pose(0, moved, _quat_x(turn))
    before = _box_sdf(_plane_points(solver, state, tri, bary), moved, turn)
    assert before.min() < -2.5e-4
    assert _hold_once(solver, state) > 0
    after = _box_sdf(_plane_points(solver, state, tri, bary), moved, turn)
    assert after.min() > -1.0e-6, after.min()


CUDA = pytest.param("cuda", marks=pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device"))


@pytest.mark.parametrize("device", ["cpu", CUDA])
def test_holding_keeps_the_skin_out_between_stages(scene, device):  # noqa: F811
    """contact_every=2 on a box pressed into the hand: by the skin measure after every substep
    (Config.substep_metrics: the order-5 lattice, not the planes), the substeps without a stage leave
    the skin far less deep with the hold than without (CPU: ~0.22 mm without, none with); the frames
    end clean either way. On CUDA the frame is a graph with conditional contact passes."""
    subs = Config().substeps
    free = [s for s in range(subs) if (subs - 1 - s) % 2]
    depth = {}
    for linear in (False, True):
        solver, state, _, _, outs = _pressed(scene, frames=3, contact_every=2, contact_linear=linear,
                                             substep_metrics=True, device=device)
        assert outs[-1]["penetration_count"] == 0
        depth[linear] = solver.substep_metrics[free, 2].max()
    assert depth[False] > 1.0e-5, depth
    assert depth[True] < 0.25 * depth[False], depth


def test_no_planes_outlive_a_frame_without_contact_a_wake_or_another_state(scene):  # noqa: F811
    """The next frame's first substeps hold on a frame's planes (with the box lowered 0.5 mm a hold
    moves the skin), but not after a frame whose contact did not run (the box 1 m away), nor after
    Solver.wake, nor for another state of the solver; with the box back, 1 mm aside, frames end clean."""
    solver, state, objects, centre, _ = _pressed(scene, contact_every=2, contact_linear=True)
    lowered = centre - _rot_x(TILT) @ [0.0, 0.0, 5.0e-4]

    def holds_next_frame():
        objects.set_pose(0, lowered, _quat_x(TILT))
        x = state.x.numpy().copy()
        n = _hold_once(solver, state, _next_frame_flags(solver))
        state.x.assign(x)  # (the probe leaves the skin as it was)
        objects.set_pose(0, centre, _quat_x(TILT))
        return n

    assert holds_next_frame() > 0
    objects.set_pose(0, (1.0, 1.0, 1.0), (1.0, 0.0, 0.0, 0.0))
    out = _step(solver, state, scene[2])
    assert out["triangles_tested"] == 0 and holds_next_frame() == 0
    objects.set_pose(0, centre + [0.001, 0.0, 0.0], _quat_x(TILT))
    for _ in range(2):
        out = _step(solver, state, scene[2])
    assert out["penetration_count"] == 0 and holds_next_frame() > 0
    solver.wake(state)
    assert holds_next_frame() == 0
    _step(solver, state, scene[2])
    assert holds_next_frame() > 0
    other = solver.make_state(*scene[1])
    _step(solver, other, scene[2])  # (its frame makes planes of its own skin)
    assert holds_next_frame() > 0 and solver.contact.hold.planes_of is other
    solver.contact.forget_planes(state)  # (what Solver.launch does first for a frame of ``state``)
    assert holds_next_frame() == 0 and solver.contact.hold.planes_of is state
    solver.contact.forget_planes(state)  # (the same state again: nothing dropped)
    assert solver.contact.hold.data.state.numpy().tolist() == [0, 0, 0, 0]


def test_the_option_costs_nothing_where_it_cannot_act(scene):  # noqa: F811
    """contact_every=1 (a stage every substep): nothing to hold, no plane buffers, the skin the same
    bits as without the option."""
    runs = []
    for linear in (False, True):
        solver, state, _, _, _ = _pressed(scene, frames=2, contact_linear=linear)
        assert not solver.contact.holds and solver.contact.hold.data.tri.shape[0] == 0
        runs.append(state.x.numpy().copy())
    assert np.array_equal(runs[0], runs[1])


def test_config_checks():
    with pytest.raises(ValueError, match="contact_linear"):
        Config(contact_linear="yes").validate()


def test_no_planes_outlive_sleep(scene):  # noqa: F811
    """A hand may fall asleep on the frame right after one that made planes (CUDA: the broadphase run
    ahead finds nothing near); its sleeping frames drop them, so it holds on none when it wakes. Here
    the planes of a pressing frame are put back by hand before an asleep frame."""
    solver, state, objects, centre, _ = _pressed(scene, frames=2, contact_every=2, contact_linear=True)
    made = solver.contact.hold.data.state.numpy().copy()
    assert made[0] > 0 and made[1] == 1
    objects.set_pose(0, (1.0, 1.0, 1.0), (1.0, 0.0, 0.0, 0.0))
    for _ in range(400):
        if _step(solver, state, scene[2])["asleep"]:
            break
    else:
        raise AssertionError("the hand did not fall asleep")
    solver.contact.hold.data.state.assign(made)  # (as if the frame before this one had made them)
    assert _step(solver, state, scene[2])["asleep"]
    objects.set_pose(0, centre - _rot_x(TILT) @ [0.0, 0.0, 5.0e-4], _quat_x(TILT))
    assert _hold_once(solver, state, _next_frame_flags(solver)) == 0


def test_batched_worlds_hold_as_their_serial_runs(setup):  # noqa: F811
    """Two batched worlds with contact_linear (world 1's sphere 2 mm into the back of its hand, world
    0's 10 cm away) end every frame as two serial solvers do, bit for bit: the planes of a batch are
    per world (its triangles, its geoms); world 1 made some and nothing penetrates."""
    from physhand_mj.batch import BatchedHands

    asset, model, data, ids, mount = setup
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = Config(device="cpu", contact_every=2, contact_linear=True)
    batch = BatchedHands(asset, 2, cfg, *mount, objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = [top + [0.0, 0.1, 0.05], top + [0.0, 0.0, 0.02 - 0.002]]
    out, serial = _beside_serial(batch, asset, cfg, mount, poses, where,
                                 dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0)), serial_worlds=2)
    assert out["penetration_count"] == 0 and out["triangles_tested"] > 0
    c = batch.solver.contact
    tri = c.hold.data.tri.numpy()[: int(c.hold.data.state.numpy()[0])]
    assert len(tri) > 0 and np.all(tri >= c.tris_per_world)  # world 1's triangles only
    assert serial[1][0].contact.hold.data.state.numpy()[0] == len(tri)
    for w, (_, st) in enumerate(serial):
        np.testing.assert_array_equal(batch.positions(w), st.x.numpy())


def test_the_hold_before_the_solve(scene):  # noqa: F811
    """Placement.BEFORE (the stage before the substep's solve, whose frames end with what the last
    solve did) holds before the solve too: planes are made, the hold changes the skin (a run without
    it ends elsewhere), nothing turns non-finite."""
    runs = []
    for linear in (False, True):
        solver, state, _, _, outs = _pressed(scene, frames=3, contact_every=2, contact_linear=linear,
                                             contact_placement="before")
        assert outs[-1]["nonfinite"] == 0 and np.isfinite(state.x.numpy()).all()
        runs.append(state.x.numpy().copy())
    assert solver.contact.hold.data.state.numpy()[0] > 0
    assert np.abs(runs[0] - runs[1]).max() > 1.0e-6


def test_the_feature_points_are_held_too(scene):  # noqa: F811
    """A cube's corner 1 mm into the back of the hand, then lowered 0.3 mm: 7 of its points are
    inside the skin by the independent measures (order 9, the object's points). One hold on the
    decision points' planes alone leaves one of them inside (~56 um); with the kept feature points
    pushed first and last (the stage's order) none is, nor any skin sample."""
    from physhand_mj.contact.metrics import summarize

    h = 0.005  # m, the cube's half edge
    angle, axis = np.arccos(1.0 / np.sqrt(3.0)), np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    quat = (float(np.cos(angle / 2)), *(axis * np.sin(angle / 2)))  # (1, 1, 1) to +z: the (-1, -1, -1) corner down
    solver, state, objects, top = _solver(scene, GeomType.BOX, (h, h, h), contact_every=2, contact_linear=True)
    centre = top + [0.0, 0.0, h * np.sqrt(3.0) - 0.001]
    objects.set_pose(0, centre, quat)
    for _ in range(3):
        out = _step(solver, state, scene[2])
    c = solver.contact
    assert out["penetration_count"] == 0 and c.hold.data.state.numpy()[3] > 0  # feature points kept
    objects.set_pose(0, centre - [0.0, 0.0, 3.0e-4], quat)
    x0 = state.x.numpy().copy()

    def measured():
        return summarize(c.measure(state, order=9))

    assert measured()["object_in_skin_count"] > 3

    def hold(features: bool):
        state.x.assign(x0)
        c.counters.zero_()  # (the frame's lists are read; the hold's touched counts start from zero)
        slot, lists = c._slot, c.features
        if not features:
            c.features = None  # (no feature list: the hold keeps no feature points)
        rec = Recorder("cpu")
        c.record_hold(rec, state)
        rec.run()
        c.features, c._slot = lists, slot
        assert np.isfinite(state.x.numpy()).all()
        return measured()

    planes_only, both = hold(False), hold(True)
    assert planes_only["object_in_skin_count"] > 0, planes_only
    assert both["object_in_skin_count"] == 0 and both["penetration_count"] == 0, both
