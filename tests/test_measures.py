"""The skin measure's two layouts (physhand_mj/contact/metrics.py): the triangles near an object culled into a
list and measured a thread each (batched worlds' layout, forced here on one hand) give the one-kernel
measure's rows, on a hand pressed deep into a
sphere and into a mesh (the bowl's kind of object) at once."""

import numpy as np
import pytest
import trimesh
import warp as wp

import physhand_mj as ph
from physhand_mj.contact import Objects
from physhand_mj.hand_mjcf import mount_pose, open_hand_scene
from physhand_mj.contact import metrics
from physhand_mj.contact.metrics import penetration_samples
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config, GeomType

DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])


def _open_hand(device, capacity):
    """The open hand at rest (a solver, its state, room for ``capacity`` objects, the skin's
    positions) for the cases below to place objects into."""
    wp.init()
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    cfg = Config(device=device)
    objects = Objects(device, capacity)
    solver = Solver(make_model(asset, cfg), cfg, objects=objects)
    state = solver.make_state(*mount_pose(model, data))
    return solver, state, objects, state.x.numpy()[: asset.n_skin].astype(float)


def _pressed(device):
    """The open hand at rest with a 2 cm sphere sunk 6 mm into the back of the hand and a 3 cm mesh
    box sunk 4 mm into the palm (no step: the measure sees the deep start as it is)."""
    solver, state, objects, skin = _open_hand(device, 2)
    top, bottom = skin[np.argmax(skin[:, 2])], skin[np.argmin(skin[:, 2])]
    objects.add(GeomType.SPHERE, (0.02,), pos=top + [0.0, 0.0, 0.02 - 0.006], name="ball")
    box = trimesh.creation.box((0.03, 0.03, 0.03))
    objects.add(GeomType.MESH, None, pos=bottom - [0.0, 0.0, 0.015 - 0.004], vertices=box.vertices,
                faces=box.faces, name="block")
    return solver, state


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("order", [5, 9])
def test_the_culled_skin_measure_equals_the_one_kernel_measure(device, order):
    solver, state = _pressed(device)
    contact = solver.contact
    assert not contact.cull_measure  # one hand: the one-kernel layout by default
    contact.cull_measure = True
    listed = contact.measure_worlds(state, order=order, objects_side=False)[0]
    # the same kernel without a list: every triangle asks its bound itself, one thread each
    m = contact.model
    out = wp.zeros((1, 6), dtype=float, device=device)
    none = wp.zeros(0, dtype=int, device=device)
    wp.launch(penetration_samples, contact.n_tris,
              [m.skin_faces, state.x, contact.objects.geoms, contact.geoms_per_world, -1, 0, order,
               contact.tris_per_world, 1, none, none, metrics.SKIP_MARGIN], [out], device=device)
    whole = out.numpy()[0].astype(float)
    assert whole[0] > 50 and whole[2] > 3e-3, "the hand is not pressed in: the test would compare nothing"
    assert listed[0] == whole[0] and listed[2] == whole[2]  # counts and the deepest: exact on every device
    if device == "cpu":  # the list in ascending order: the same additions in the same order
        assert listed[1] == whole[1]
    else:
        assert listed[1] == pytest.approx(whole[1], rel=1e-5)
    # and each object alone (the filtered measure keeps the one-kernel layout) adds up to the same count
    per_object = sum(contact.measure_worlds(state, obj=o, order=order, objects_side=False)[0][0] for o in (0, 1))
    assert per_object == whole[0]


def test_check_points_measured_in_pieces_equal_the_whole(monkeypatch):
    """A batch's check points are W copies of each object's (the HOI bowl's 212,271 a world did not
    fit an H100 at W = 4,096): past measures.CHECK_POINTS_AT_ONCE they are made and asked a few
    worlds at a time. Three worlds of two geoms each (a sphere and a box), the sphere 2 mm into world
    1's hand and 3 mm into world 2's: one world a piece gives each world's row of the whole set, and
    no piece is kept."""
    import physhand_mj.contact.measures as measures
    from physhand_mj.batch import BatchedHands

    wp.init()
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    batch = BatchedHands(asset, 3, Config(device="cpu"), *mount_pose(model, data),
                         objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball"),
                                  dict(gtype=GeomType.BOX, size=(0.01, 0.02, 0.005), name="block")])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    ball = np.stack([top + [0.0, 0.1, 0.05], top + [0.0, 0.0, 0.018], top + [0.0, 0.0, 0.017]])
    block = ball + [0.0, 0.3, 0.0]  # 30 cm aside: its points count, none inside
    batch.set_object_poses(np.stack([ball, block], 1), np.array([[[1.0, 0.0, 0.0, 0.0]] * 2] * 3))
    contact = batch.solver.contact
    assert contact.geoms_per_world == 2
    one_world = len(contact.measures.check_piece(range(2)))
    monkeypatch.setattr(measures, "CHECK_POINTS_AT_ONCE", one_world)
    assert [list(r) for r in contact.measures.check_pieces()] == [[0, 1], [2, 3], [4, 5]]
    pieces = contact.measure_worlds(batch.state, order=9, check=True)
    assert contact.measures._check_points is None  # nothing kept
    monkeypatch.setattr(measures, "CHECK_POINTS_AT_ONCE", 2 * one_world)  # two worlds, then one
    assert [list(r) for r in contact.measures.check_pieces()] == [[0, 1, 2, 3], [4, 5]]
    assert np.array_equal(contact.measure_worlds(batch.state, order=9, check=True), pieces)
    monkeypatch.setattr(measures, "CHECK_POINTS_AT_ONCE", 3 * one_world)
    assert contact.measures.check_pieces() is None
    whole = contact.measure_worlds(batch.state, order=9, check=True)
    assert pieces[0, 3] == 0 and pieces[1, 3] > 0 and pieces[2, 3] > pieces[1, 3], pieces
    np.testing.assert_array_equal(pieces[:, [0, 1, 2, 3, 5]], whole[:, [0, 1, 2, 3, 5]])
    np.testing.assert_allclose(pieces[:, 4], whole[:, 4], rtol=1e-6)


def _corner_poke(device):
    """The open hand at rest with a 3 cm mesh cube standing on a corner, that corner 1 mm into the
    back of the hand (a sharp feature inside a triangle's interior: its corners outside)."""
    solver, state, objects, skin = _open_hand(device, 1)
    top = skin[np.argmax(skin[:, 2])]
    cube = trimesh.creation.box((0.03, 0.03, 0.03))
    axis = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)  # the (1, 1, 1) diagonal turned onto -z
    rot = trimesh.geometry.align_vectors(-axis, [0.0, 0.0, -1.0])
    cube.apply_transform(rot)
    tip = cube.vertices[np.argmin(cube.vertices[:, 2])]
    objects.add(GeomType.MESH, None, pos=top - tip - [0.0, 0.0, 0.001], vertices=cube.vertices, faces=cube.faces,
                name="cube")
    return solver, state


def _open_box(device):
    """The open hand at rest with a 3 cm mesh box whose bottom face is cut away (signed by its
    winding number, closed over the hole), pressed 4 mm into the back of the hand opening first: the
    skin crosses the hole, where phi jumps from the rim's distance outside to the walls' inside."""
    solver, state, objects, skin = _open_hand(device, 1)
    top = skin[np.argmax(skin[:, 2])]
    box = trimesh.creation.box((0.03, 0.03, 0.03))
    keep = box.face_normals[:, 2] > -0.5  # (the bottom's two triangles cut away)
    objects.add(GeomType.MESH, None, pos=top + [0.0, 0.0, 0.015 - 0.004], vertices=box.vertices,
                faces=box.faces[keep], name="open box")
    return solver, state


def _rows_by_margin(monkeypatch, contact, state, orders) -> dict:
    """The skin measure's row (count, depth sum, deepest) by (SKIP_MARGIN off / on, culled layout or
    not, lattice order)."""
    rows = {}
    for margin in (0.0, metrics.SKIP_MARGIN):
        monkeypatch.setattr(metrics, "SKIP_MARGIN", margin)
        for culled in (False, True):
            contact.cull_measure = culled
            for order in orders:
                rows[margin, culled, order] = contact.measure_worlds(state, order=order, objects_side=False)[0][:3]
    return rows


def _assert_same_rows(rows: dict, device, orders, what) -> None:
    """The bound on and off give the same rows: bit for bit on the CPU, on CUDA the counts and the
    deepest (the triangles add their sums in the atomics' order), and something inside to compare."""
    for culled in (False, True):
        for order in orders:
            off, on = rows[0.0, culled, order], rows[metrics.SKIP_MARGIN, culled, order]
            assert off[0] > 0, (what, order, "nothing inside: the test would compare nothing")
            if device == "cpu":
                assert np.array_equal(on, off), (what, culled, order, on, off)
            else:
                assert on[0] == off[0] and on[2] == off[2] and on[1] == pytest.approx(off[1], rel=1e-5)


@pytest.mark.parametrize("device", DEVICES)
def test_the_corner_bound_is_off_for_a_mesh_signed_by_its_winding_number(device, monkeypatch):
    """An open mesh signed by its winding number is not 1-Lipschitz across its holes (phi jumps from
    the rim's distance outside to the walls' inside), so the corner bound must not leave any sample
    out there: the rows are the same with the bound on and off."""
    solver, state = _open_box(device)
    rows = _rows_by_margin(monkeypatch, solver.contact, state, orders=(5,))
    _assert_same_rows(rows, device, (5,), "open box")


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("case", ["pressed", "corner"])
def test_samples_left_out_by_the_corner_bound_change_no_row(device, case, monkeypatch):
    """metrics.SKIP_MARGIN: a kept triangle's corners are asked first and a sample whose bound from
    a corner (phi(corner) - distance, SDFs being 1-Lipschitz) shows it outside is not asked. Every
    row (count, depth sum, deepest) is the same bits with the bound on and off, on both layouts,
    for orders 5 and 9: a sphere and a mesh box pressed deep in, and a cube's corner poking 1 mm
    into a triangle whose corners are outside; and they match every lattice sample's phi taken one
    by one without any bound (Contact.penetrating_samples)."""
    solver, state = (_pressed if case == "pressed" else _corner_poke)(device)
    contact = solver.contact
    rows = _rows_by_margin(monkeypatch, contact, state, orders=(5, 9))
    for order in (5, 9):  # a reference that skips nothing: every lattice sample's phi (lattice_phi, world_phi)
        pts, depth = contact.penetrating_samples(state, order)
        ref = rows[metrics.SKIP_MARGIN, True, order]
        assert ref[0] == len(depth) and ref[2] == np.float32(depth.max()), (case, order, ref, len(depth))
        assert ref[1] == pytest.approx(depth.sum(), rel=1e-5)
    _assert_same_rows(rows, device, (5, 9), case)


@pytest.mark.parametrize("device", DEVICES)
def test_a_triangle_with_a_nonfinite_corner_counts_nothing(device, monkeypatch):
    """A skin vertex that turned non-finite makes every lattice sample of its triangles NaN, so those
    triangles count nothing, with the corner bound on and off, as every sample asked one by one."""
    solver, state = _pressed(device)
    contact = solver.contact
    before = contact.measure_worlds(state, objects_side=False)[0][:3]
    pts, depth = contact.penetrating_samples(state, 5)
    x = state.x.numpy()
    inside = np.argmin(np.linalg.norm(x[: contact.model.n_skin] - pts[np.argmax(depth)], axis=1))
    x[inside] = np.nan  # the vertex nearest the deepest sample
    state.x.assign(x)
    rows = []
    for margin in (0.0, metrics.SKIP_MARGIN):
        monkeypatch.setattr(metrics, "SKIP_MARGIN", margin)
        rows.append(contact.measure_worlds(state, objects_side=False)[0][:3])
    _, depth_nan = contact.penetrating_samples(state, 5)
    assert rows[0][0] == rows[1][0] == len(depth_nan) < before[0], (rows, len(depth_nan), before)
