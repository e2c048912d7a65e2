"""Tuning.flesh_carry (solver/carry.py): the flesh under contact-moved skin takes a share of the
contact stage's move, so deep pushes do not shear the skin layer's tets inside out."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.bench.cases import press_case, run_case
from physhand_mj.solver import Solver
from physhand_mj.solver.carry import carry_flesh, flesh_neighbours

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device"))]


def test_neighbours_are_the_movable_flesh_sharing_a_tet_with_skin():
    # skin 0-2; flesh 3 (movable), 4 (kinematic: a bone's), 5 (movable, no skin in its tet)
    tets = np.array([[0, 1, 3, 4], [1, 2, 3, 5], [3, 4, 5, 6]])
    inv_mass = np.array([1, 1, 1, 1, 0, 1, 1.0])
    flesh, off, skin = flesh_neighbours(tets, 3, inv_mass)
    assert flesh.tolist() == [3, 5]
    assert skin[off[0]:off[1]].tolist() == [0, 1, 2]
    assert skin[off[1]:off[2]].tolist() == [1, 2]


@pytest.mark.parametrize("d", DEVICES)
def test_a_flesh_vertex_takes_the_share_of_its_skin_neighbours_mean_move(d):
    before = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1], [5, 5, 5]], np.float32)
    x = before.copy()
    x[0] += [0, 0, 0.003]  # the stage moved two of the three skin neighbours
    x[1] += [0, 0, 0.006]
    flesh, off, skin = np.array([3, 4]), np.array([0, 3, 4]), np.array([0, 1, 2, 0])
    inv_mass = np.array([1, 1, 1, 1, 0], np.float32)  # vertex 4 kinematic: it stays
    xw = wp.array(x, dtype=wp.vec3, device=d)
    wp.launch(carry_flesh, 2, inputs=[wp.array(flesh, dtype=int, device=d), wp.array(off, dtype=int, device=d),
                                      wp.array(skin, dtype=int, device=d), wp.array(before, dtype=wp.vec3, device=d),
                                      wp.array(inv_mass, dtype=float, device=d), 0.5,
                                      wp.zeros(0, dtype=int, device=d), 0.5], outputs=[xw], device=d)
    out = xw.numpy()
    assert np.allclose(out[3], before[3] + [0, 0, 0.5 * (0.003 + 0.006) / 3], atol=1e-7)
    assert np.array_equal(out[4], before[4])
    assert np.array_equal(out[:3], x[:3])  # the skin (the contact's result) is untouched


@pytest.mark.parametrize("d", DEVICES)
def test_the_wall_share_applies_to_the_skin_near_a_wall_only(d):
    # Tuning.wall_carry: skin vertex 1 lies near a wall (its move taken by 0.8), vertex 0 not (0.1)
    before = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, -1]], np.float32)
    x = before.copy()
    x[0] += [0, 0, 0.003]
    x[1] += [0, 0, 0.006]
    xw = wp.array(x, dtype=wp.vec3, device=d)
    wp.launch(carry_flesh, 1, inputs=[wp.array([3], dtype=int, device=d), wp.array([0, 3], dtype=int, device=d),
                                      wp.array([0, 1, 2], dtype=int, device=d), wp.array(before, dtype=wp.vec3, device=d),
                                      wp.array(np.ones(4, np.float32), dtype=float, device=d), 0.1,
                                      wp.array([0, 1, 0], dtype=int, device=d), 0.8], outputs=[xw], device=d)
    assert np.allclose(xw.numpy()[3], before[3] + [0, 0, (0.1 * 0.003 + 0.8 * 0.006) / 3], atol=1e-7)


def test_mark_near_walls_reads_the_frame_lists_wall_bits():
    # triangles 0 and 1 listed, triangle 0 near geom 1 (a wall), triangle 1 near geom 0 (not); a
    # world of 40 geoms: triangle 2's bit 30 stands for geoms 30-39, of which 35 is a wall
    from physhand_mj.contact.broadphase import tri_list
    from physhand_mj.solver.carry import mark_near_walls

    faces = wp.array(np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]]), dtype=int)
    lst = tri_list(wp.array([0, 1, 2], dtype=int), wp.array([1 << 1, 1 << 0, 1 << 30], dtype=int))
    wall = np.zeros(40, np.int32)
    wall[[1, 35]] = 1
    for count, expect in ((2, [1, 1, 1, 0, 0, 0, 0, 0, 0]), (3, [1, 1, 1, 0, 0, 0, 1, 1, 1])):
        near = wp.zeros(9, dtype=int)
        wp.launch(mark_near_walls, 3, inputs=[faces, lst, wp.array([count], dtype=int), 3, 40, wp.array(wall, dtype=int)],
                  outputs=[near])
        assert near.numpy().tolist() == expect
    # batched worlds of one triangle and two geoms each: bit b is geom b of the triangle's own world
    # (world 1's geom 1, global 3, a wall; world 0's geom 1 none; world 2's geom 0 none, its geom 1 a wall)
    lst = tri_list(wp.array([0, 1, 2], dtype=int), wp.array([1 << 1, 1 << 1, 1 << 0], dtype=int))
    near = wp.zeros(9, dtype=int)
    wp.launch(mark_near_walls, 3, inputs=[faces, lst, wp.array([3], dtype=int), 1, 2,
                                          wp.array([0, 0, 0, 1, 0, 1], dtype=int)], outputs=[near])
    assert near.numpy().tolist() == [0, 0, 0, 1, 1, 1, 0, 0, 0]


def wall_or_sphere(wall: bool, wall_carry: float, frames: int = 3):
    from physhand_mj.bench.cases import wall_case

    case = wall_case(0.008, 0.001, 0.004) if wall else press_case("bone", site="palm", depth=0.003)
    return run_case(case, ph.Config(device="cpu", tuning=ph.Tuning(wall_carry=wall_carry)), frames=frames)


def test_wall_carry_acts_only_in_a_scene_with_a_wall():
    """Tuning.wall_carry (on by default): a 16 mm plate 4 mm into the palm is a wall, its flesh
    follows the pushed skin (the flesh ends elsewhere than with the share at 0); a sphere pressed
    into the palm is none: its frames record no carry launch and end bit for bit as with the share
    at 0."""
    on, off = wall_or_sphere(True, 0.5), wall_or_sphere(True, 0.0)
    carry = on["solver"].carry
    assert carry.walls(on["solver"].contact) and carry.near_wall.numpy().sum() > 100
    assert off["solver"].carry is None
    n = on["solver"].model.n_skin
    assert np.abs(on["state"].x.numpy()[n:] - off["state"].x.numpy()[n:]).max() > 1e-5
    on, off = wall_or_sphere(False, 0.5), wall_or_sphere(False, 0.0)
    assert not on["solver"].carry.acts(on["solver"].contact)
    assert on["solver"].carry.flesh is None  # (its lists are not even built)
    np.testing.assert_array_equal(on["state"].x.numpy(), off["state"].x.numpy())


def test_the_larger_share_applies():
    """flesh_carry at or above wall_carry: every skin vertex takes flesh_carry, no wall is marked."""
    from physhand_mj.bench.cases import wall_case

    r = run_case(wall_case(0.008, 0.001, 0.004), ph.Config(device="cpu", tuning=ph.Tuning(flesh_carry=0.5)), frames=2)
    assert not r["solver"].carry.walls(r["solver"].contact) and r["solver"].carry.near_wall.shape[0] == 0
    with pytest.raises(ValueError, match="wall_carry"):
        ph.Config(tuning=ph.Tuning(wall_carry=-0.1)).validate()


def test_flesh_carry_is_checked():
    with pytest.raises(ValueError, match="flesh_carry"):
        ph.Config(tuning=ph.Tuning(flesh_carry=1.5)).validate()
    with pytest.raises(ValueError, match="flesh_carry"):
        ph.Config(tuning=ph.Tuning(flesh_carry=float("nan"))).validate()


def press(share, device="cpu", frames=12):
    """A 3 mm capsule pressed 3 mm into the palm (past its axis, 6 mm flesh): inverted tets per frame
    and the four penetration measures."""
    inverted = []
    orig = Solver.step

    def step(self, state, *a, **k):
        out = orig(self, state, *a, **k)
        inverted.append(out["inverted"])
        return out

    Solver.step = step
    try:
        r = run_case(press_case("capsule", site="palm", depth=0.003), ph.Config(device=device, tuning=ph.Tuning(
            flesh_carry=share)), frames=frames)
    finally:
        Solver.step = orig
    return r, np.asarray(inverted)


@pytest.mark.parametrize("device", DEVICES)
def test_the_palm_pressed_deep_keeps_its_tets_with_the_flesh_carried(device):
    r0, inv0 = press(0.0, device)
    r1, inv1 = press(0.5, device)
    assert not r0["solver"].carry.acts(r0["solver"].contact) and r1["solver"].carry.acts(r1["solver"].contact)
    assert r1["finite"]
    for key in ("skin_count", "dense_count", "obj_count", "check_count"):  # contact as good as without
        assert np.all(r1[key][-3:] == 0), (key, r1[key].tolist())
    # measured: 21-22 inverted over the last frames without, 1 with (CPU and H200)
    assert inv0[-3:].min() >= 10
    assert inv1[-3:].max() <= 4
    # the skin ends where the contact puts it either way and goes no farther from rest (measured,
    # CPU: within 3.35 mm of where it ends without the carry at 36 vertices over 1 mm, 0.06 mm on
    # average; 2.44 / 0.08 mm without touch damping, which slows the pushed skin's settling: 2.78 mm
    # after 24 frames; the capsule lies past its axis in the flesh, where the end state is the path's)
    diff = np.linalg.norm(r1["skin"] - r0["skin"], axis=1)
    assert diff.max() < 4e-3 and diff.mean() < 1e-4 and (diff > 1e-3).sum() < 60, (diff.max(), diff.mean())
    assert r1["max_disp_mm"][-1] < r0["max_disp_mm"][-1] + 1.0


def test_batched_worlds_carry_each_world_as_one_hand():
    """Two worlds, each with its own sphere (world 1's 2 mm into the back of its hand, world 0's 10 cm
    away), with the carry: each ends bit for bit as a serial solver with the same sphere and option
    (CPU), and world 1's flesh is not where it ends without the carry."""
    from physhand_mj.batch import BatchedHands
    from physhand_mj.contact import Objects
    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
    from physhand_mj.solver import make_model
    from physhand_mj.types import GeomType

    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    ids, mount = body_ids(model, asset.body_names), mount_pose(model, data)
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = ph.Config(device="cpu", tuning=ph.Tuning(flesh_carry=0.5))
    batch = BatchedHands(asset, 2, cfg, *mount, objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
    assert batch.solver.carry.acts(batch.solver.contact)
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = [top + [0.0, 0.1, 0.05], top + [0.0, 0.0, 0.02 - 0.002]]
    serial = []
    for w, c in ((0, cfg), (1, cfg), (1, ph.Config(device="cpu", tuning=ph.Tuning(flesh_carry=0.0)))):
        objs = Objects("cpu", 1)
        objs.add(GeomType.SPHERE, (0.02, 0, 0), where[w], name="ball")
        s = Solver(make_model(asset, c), c, objects=objs)
        serial.append((s, s.make_state(*mount)))
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
    for _ in range(4):
        batch.step(np.stack([poses[0]] * 2), np.stack([poses[1]] * 2), np.stack(where)[:, None], ident)
        for s, st in serial:
            s.set_body_poses(st, *poses)
            s.step(st)
    for w in range(2):
        np.testing.assert_array_equal(batch.positions(w), serial[w][1].x.numpy())
    flesh = slice(asset.n_skin, None)
    assert np.abs(batch.positions(1)[flesh] - serial[2][1].x.numpy()[flesh]).max() > 1e-5  # the carry acted
