"""A contact stage's list skips the frame-list triangles that the frame broadphase's bound still
proves out of reach (broadphase.stage_skip, contact.STAGE_SKIP): the bound is sound against the
exact test for moved and deformed triangles near a mesh, a box and a sphere, and a pressing box gives
the same skin bit for bit, the same lists and the same report with the skip as without it (CPU)."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from mesh_shapes import bowl_mesh
from physhand_mj.contact import Objects
from physhand_mj.contact.broadphase import reach_clear, reach_mask, stage_skip
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config, GeomType

MARGIN = 5.0e-4  # m, Config.contact_margin's default
FRAME_MARGIN = 1.0e-2  # m, Config.contact_frame_margin's default


@wp.kernel
def _bound_and_exact(faces: wp.array2d(dtype=int), x0: wp.array(dtype=wp.vec3), x1: wp.array(dtype=wp.vec3),
                     gtype: wp.array(dtype=int), size: wp.array(dtype=wp.vec3), inv_pose: wp.array(dtype=wp.transform),
                     radius: wp.array(dtype=float), mesh: wp.array(dtype=wp.vec2ul), count: wp.array(dtype=int),
                     flags: wp.array2d(dtype=int), values: wp.array2d(dtype=float)):
    # flags: [listed by the frame test at x0, skipped at x1, reaches at x1 by the exact test];
    # values: [the frame test's bound at x0, the exact phi(m) - r at x1]
    t = wp.tid()
    mask, clear = reach_clear(t, -1, faces, x0, gtype, size, inv_pose, radius, mesh, count, 1 << 30, 1 << 20,
                              FRAME_MARGIN)
    flags[t, 0] = wp.where(mask != 0, 1, 0)
    flags[t, 1] = wp.where(stage_skip(t, faces, x1, x0, clear, MARGIN), 1, 0)
    flags[t, 2] = wp.where(reach_mask(t, mask, faces, x1, gtype, size, inv_pose, radius, mesh, count, 1 << 30, 1 << 20,
                                      MARGIN) != 0, 1, 0)
    every, now = reach_clear(t, -1, faces, x1, gtype, size, inv_pose, radius, mesh, count, 1 << 30, 1 << 20, 1.0e6)
    values[t, 0] = clear
    values[t, 1] = now


@pytest.mark.parametrize("shape", ["bowl", "box", "sphere"])
def test_the_skip_never_drops_a_triangle_the_exact_test_keeps(shape):
    """Small triangles 0-12 mm about an object (its frame list), each vertex then moved by up to
    2 mm: at random, or the worst way (two vertices straight at the object, the third out from the
    centroid: the centroid nears the object and the radius grows). For every listed triangle its
    exact phi(m) - r now is at least the frame test's bound less 3 d (d its largest vertex move), the
    inequality the skip stands on, which d alone would break; every triangle the skip leaves out is
    out of reach by the exact test; and the skip leaves out most of those out of reach."""
    rng = np.random.default_rng(4)
    objs = Objects("cpu", 2)
    if shape == "bowl":
        mesh = bowl_mesh()
        objs.add(GeomType.MESH, None, vertices=mesh.vertices, faces=mesh.faces, name="m", mesh_range=1.0)
        surface, idx = mesh.sample(3000, return_index=True)
        normals = mesh.face_normals[idx]
    elif shape == "box":
        objs.add(GeomType.BOX, (0.02, 0.015, 0.01), pos=(0.01, 0.0, 0.0), quat=(0.9, 0.1, 0.3, 0.0), name="b")
        surface, normals = _box_surface(rng, 3000)
    else:
        objs.add(GeomType.SPHERE, (0.02, 0.0, 0.0), pos=(0.0, 0.01, 0.0), name="s")
        d = rng.normal(size=(3000, 3))
        normals = d / np.linalg.norm(d, axis=1, keepdims=True)
        surface = np.array([0.0, 0.01, 0.0]) + 0.02 * normals
    objs.upload()
    n = len(surface)
    centre = surface + normals * rng.uniform(-0.002, 0.012, (n, 1))
    tri0 = centre[:, None, :] + rng.normal(scale=1.5e-3, size=(n, 3, 3))
    step = rng.uniform(0, 2e-3, (n, 1))
    moves = rng.normal(size=(n, 3, 3))
    moves *= step[:, None] / np.linalg.norm(moves, axis=2, keepdims=True)
    worst = n // 2  # the second half: the worst way
    out = tri0[worst:, 0] - tri0[worst:].mean(1)
    moves[worst:, 0] = step[worst:] * out / np.linalg.norm(out, axis=1, keepdims=True)
    moves[worst:, 1:] = -step[worst:, None] * normals[worst:, None]
    x0, x1 = tri0.reshape(-1, 3), (tri0 + moves).reshape(-1, 3)
    dmax = np.linalg.norm(moves, axis=2).max(1)
    faces = np.arange(3 * n).reshape(n, 3)
    flags = wp.zeros((n, 3), dtype=int)
    values = wp.zeros((n, 2), dtype=float)
    a = lambda v: wp.array(np.asarray(v, np.float32), dtype=wp.vec3)  # noqa: E731
    wp.launch(_bound_and_exact, n, [wp.array(faces, dtype=int), a(x0), a(x1), objs.gtype, objs.size, objs.inv_pose,
                                    objs.radius, objs.mesh, objs.count], [flags, values])
    listed, skipped, reaches = flags.numpy().T.astype(bool)
    bound, now = values.numpy().T.astype(float)
    assert listed.sum() > 0.5 * n
    slack = now[listed] - (bound[listed] - 3 * dmax[listed])
    assert slack.min() > -1e-6, f"phi(m) - r fell {-slack.min() * 1e6:.2f} um past the bound"
    assert (now[listed] < bound[listed] - dmax[listed] - 1e-6).any(), "no case where d alone would fail"
    assert not (listed & skipped & reaches).any(), f"{(listed & skipped & reaches).sum()} skipped triangles reach"
    far = listed & ~reaches
    assert skipped[listed].sum() > 0.5 * far.sum(), (skipped[listed].sum(), far.sum())


def _box_surface(rng, n):
    """Points on the rotated box of the test with their outward normals (world frame)."""
    half = np.array([0.02, 0.015, 0.01])
    axis = rng.integers(0, 3, n)
    sign = rng.choice([-1.0, 1.0], n)
    p = rng.uniform(-1, 1, (n, 3)) * half
    p[np.arange(n), axis] = sign * half[axis]
    nrm = np.zeros((n, 3))
    nrm[np.arange(n), axis] = sign
    q = np.array([0.9, 0.1, 0.3, 0.0])
    q = q / np.linalg.norm(q)
    w, v = q[0], q[1:]
    rot = lambda y: y + 2 * w * np.cross(v, y) + 2 * np.cross(v, np.cross(v, y))  # noqa: E731
    return rot(p) + np.array([0.01, 0.0, 0.0]), rot(nrm)


@pytest.fixture(scope="module")
def hand():
    wp.init()
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    poses = bone_poses_at(model, data, model.key("open").qpos, body_ids(model, asset.body_names))
    return asset, mount_pose(model, data), poses


def test_a_pressing_box_gives_the_same_skin_and_lists_with_the_skip(hand, monkeypatch):
    """A box approaching, touching and pressing 3.5 mm a frame into the back of the hand: the skip on
    and off give the same skin bit for bit, the same stage lists (lengths per stage and frame) and the
    same report; and the bound had triangles to skip (listed, out of the stage's reach)."""
    from physhand_mj.contact import contact as contact_module

    asset, mount, poses = hand
    runs = []
    for skip in (True, False):
        monkeypatch.setattr(contact_module, "STAGE_SKIP", skip)
        cfg = Config(device="cpu")
        objects = Objects(cfg.device, 1)
        objects.add(GeomType.BOX, (0.015, 0.015, 0.015), pos=(1.0, 1.0, 1.0), name="box")
        solver = Solver(make_model(asset, cfg), cfg, objects=objects)
        state = solver.make_state(*mount)
        top = state.x.numpy()[: asset.n_skin]
        top = top[np.argmax(top[:, 2])].astype(float)
        lists, outs, far = [], [], 0
        for k in range(12):
            objects.set_pose(0, top + [0.0, 0.0, 0.015 + 0.03 - 0.0035 * k], (1.0, 0.0, 0.0, 0.0))
            solver.set_body_poses(state, *poses)
            outs.append(solver.step(state))
            c = solver.contact
            lists.append(c.counters.numpy().copy())
            if skip:
                n = int(c.cand_count.numpy()[0])
                far += int((c.frame_clear.numpy()[c.cand.numpy()[:n]] > 2 * MARGIN).sum())
        runs.append((state.x.numpy().copy(), lists, outs, far))
    (x1, l1, o1, far), (x2, l2, o2, _) = runs
    assert np.array_equal(x1, x2), float(np.abs(x1 - x2).max())
    assert all(np.array_equal(a, b) for a, b in zip(l1, l2))
    keys = ("penetration_count", "penetration_max_um", "triangles_frame", "triangles_stage", "triangles_tested")
    assert [[o[k] for k in keys] for o in o1] == [[o[k] for k in keys] for o in o2]
    assert o1[-1]["penetration_count"] == 0 and o1[-1]["triangles_stage"] > 0
    assert far > 1000, far  # frame-list triangles the bound could leave out of a stage
