"""Batched worlds (physhand_mj/batch.py): W hands in one solver step equal W serial runs, world by
world; the replicated asset keeps every world's skin first and its constraints inside the world."""

import dataclasses

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.batch import BatchedHands, replicate_asset
from physhand_mj.config import Execution, Tuning
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config, Layer


@pytest.fixture(scope="module")
def setup():
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    return asset, model, data, body_ids(model, asset.body_names), mount_pose(model, data)


def test_replicated_asset_layout(setup):
    asset = setup[0]
    rep = replicate_asset(asset, 3)
    n, ns = asset.n_vertices, asset.n_skin
    assert rep.n_vertices == 3 * n and rep.n_skin == 3 * ns
    assert np.all(rep.layer[: 3 * ns] == Layer.SKIN)  # all skins lead, as the solver expects
    assert len(rep.tets) == 3 * len(asset.tets) and len(rep.body_names) == 3 * len(asset.body_names)
    # world 1's skin is its own copy, and its faces and tets stay inside world 1's vertices
    np.testing.assert_array_equal(rep.positions[ns:2 * ns], asset.positions[:ns])
    f1 = rep.skin_faces[len(asset.skin_faces):2 * len(asset.skin_faces)]
    assert f1.min() >= ns and f1.max() < 2 * ns
    t1 = rep.tets[len(asset.tets):2 * len(asset.tets)]
    world = np.where(t1 < 3 * ns, t1 // ns, (t1 - 3 * ns) // (n - ns))
    assert np.all(world == 1)
    vb = rep.vertex_body[rep.vertex_body >= 0]
    assert vb.max() == 3 * len(asset.body_names) - 1
    # every vertex's carrier bone and every skin vertex's tether bone lie in its own world (the
    # worlds share rest positions: nearest-vertex ties must not cross them)
    from physhand_mj.solver.model import vertex_world

    m = make_model(rep, Config(device="cpu"))
    nb = len(asset.body_names)
    world = vertex_world(rep.n_vertices, rep.n_skin, 3)
    np.testing.assert_array_equal(m.vertex_carrier.numpy() // nb, world)
    np.testing.assert_array_equal(m.skin_body.numpy() // nb, world[: rep.n_skin])
    with pytest.raises(ValueError, match="worlds"):
        replicate_asset(asset, 0)
    for bad in (0, -1, 2.0):
        with pytest.raises(ValueError, match="worlds"):
            BatchedHands(asset, bad, Config(device="cpu"))


def test_tiled_model_is_the_replicated_assets_model(setup):
    """BatchedHands builds its model from one world's arrays tiled (solver.worlds.tile_model_arrays), not
    from the replicated asset: every per-vertex array equals the replicated build's, every
    constraint family holds the same constraints per world (the edge family lists each world's
    edges and attachments together: the order within a world is kept), and the gather lists sum
    the same slots per vertex (solver/gather.py)."""
    from physhand_mj.solver.model import model_arrays
    from physhand_mj.solver.worlds import tile_model_arrays

    asset = setup[0]
    W = 3
    cfg = Config(device="cpu", execution=Execution(jacobi_gather=True)).validate()
    t = tile_model_arrays(model_arrays(asset, cfg), W)
    r = model_arrays(replicate_asset(asset, W), cfg)
    with pytest.raises(ValueError, match="colored"):  # its colours span the body: not tileable
        tile_model_arrays(model_arrays(asset, Config(device="cpu", tuning=Tuning(scheme=ph.Scheme.COLORED)).validate()), W)
    t_atomic = tile_model_arrays(model_arrays(asset, Config(device="cpu", execution=Execution(jacobi_gather=False)).validate()), W)
    f32 = ("rest_x", "inv_mass", "body_local", "skin_local", "skin_anchor", "vertex_count")
    for k in ("vertex_body", "vertex_carrier", "vertex_world", "skin_body", "skin_faces", "guard_tets",
              "tet_ids", "dih_ids", "body_rest_pos", "body_rest_quat") + f32:
        a, b = np.asarray(t[k]), np.asarray(r[k])
        if k in f32:
            b = b.astype(np.float32)
        np.testing.assert_array_equal(a, b, err_msg=k)
    assert t["body_names"] == tuple(r["body_names"]) and t["n_vertices"] == r["n_vertices"] and t["worlds"] == W
    np.testing.assert_array_equal(t["tet_rest6v"], np.asarray(r["tet_rest6v"], np.float32))
    np.testing.assert_array_equal(t["dih_rest"], np.asarray(r["dih_rest"], np.float32))
    # the edge family: the same (ids, rest, compliance, is-attachment) rows, world by world
    rows = lambda a: np.unique(np.c_[np.asarray(a["edge_ids"], np.float64), np.asarray(a["edge_rest"], np.float32),  # noqa: E731
                                     np.asarray(a["edge_alpha"], np.float32), a["edge_is_att"]], axis=0)
    np.testing.assert_array_equal(rows(t), rows(r))
    assert len(t["edge_ids"]) == len(r["edge_ids"])
    n = t["n_vertices"]
    for g, (off_t, off_r) in enumerate(zip(t["gather_off"], r["gather_off"])):
        np.testing.assert_array_equal(off_t, off_r)  # the same number of slots per vertex
        slots = np.asarray(t["gather_slot"][g])
        # each slot names its vertex: slot -> (family, corner, row) -> vertex id, rows ascending per vertex
        fam = {0: "edge", 1: "tet", 2: "dih"}[g]
        ids = np.asarray(t[f"{fam}_ids"])
        corner, row = np.divmod(slots - t["slot_base"][fam], len(ids))
        owner = np.repeat(np.arange(n), np.diff(off_t))
        np.testing.assert_array_equal(ids[row, corner], owner)
        # the atomics' order on the CPU: the family's rows as the atomic model stores them, then corner
        # (the gather stores tets in space-filling-curve order and sums them in the asset's)
        plain = np.asarray(t_atomic[f"{fam}_ids"])
        rank = np.arange(len(ids))
        if fam == "tet":  # (tets are unique rows; edges may repeat as tet edge and attachment)
            key = lambda v: np.ascontiguousarray(v, np.int64).view([("", np.int64)] * v.shape[1]).ravel()  # noqa: E731
            srt = np.argsort(key(plain))
            rank = srt[np.searchsorted(key(plain)[srt], key(ids))]
        assert np.array_equal(plain[rank], ids)
        flat = rank[row] * ids.shape[1] + corner
        inside = np.ones(len(flat) - 1, bool)  # pairs of neighbours within one vertex's list
        inside[off_t[1:-1][(off_t[1:-1] > 0) & (off_t[1:-1] < len(flat))] - 1] = False
        assert np.all(np.diff(flat)[inside] > 0)


@pytest.mark.parametrize("device", ["cpu"] + (["cuda"] if wp.is_cuda_available() else []))
@pytest.mark.parametrize("gather", [False, True], ids=["atomics", "gather"])
def test_model_tiled_on_the_device_equals_the_host_tiling(setup, gather, device):
    """solver.worlds.tile_model (one world uploaded, W copies written by kernels; what BatchedHands
    uses) gives the Model of upload_model(tile_model_arrays(...)) field by field, every array equal
    in dtype, shape and value."""
    import dataclasses

    from physhand_mj.solver.model import model_arrays, upload_model
    from physhand_mj.solver.worlds import tile_model, tile_model_arrays

    cfg = Config(device=device, execution=Execution(jacobi_gather=gather)).validate()
    a = model_arrays(setup[0], cfg, batch=True)
    ref, got = upload_model(tile_model_arrays(a, 3), cfg), tile_model(a, 3, cfg)
    assert bool(got.gather_off) == gather
    for f in dataclasses.fields(ref):
        x, y = getattr(ref, f.name), getattr(got, f.name)
        if isinstance(x, wp.array):
            assert (x.dtype, x.shape) == (y.dtype, y.shape), f.name
            np.testing.assert_array_equal(x.numpy(), y.numpy(), err_msg=f.name)
        elif isinstance(x, list):
            assert len(x) == len(y), f.name
            for u, v in zip(x, y):
                np.testing.assert_array_equal(u.numpy(), v.numpy(), err_msg=f.name)
        elif isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name
    with pytest.raises(ValueError, match="int32"):  # the host tiling's checks
        tile_model(a, 2**31 // a["n_vertices"] + 1, cfg)


@pytest.mark.parametrize("gather", [False, True], ids=["atomics", "gather"])
def test_batched_worlds_equal_serial_runs(setup, gather):
    """Two worlds, one holding the hand open, one bending the index finger: each equals its own
    serial solver's run (bit for bit on the CPU: the same constraints in the same order), with the
    Jacobi corrections added by atomics or gathered per vertex (Config.execution.jacobi_gather)."""
    asset, model, data, ids, mount = setup
    q0 = model.key("open").qpos.copy()
    q1 = q0.copy()
    q1[model.jnt_qposadr[model.joint("mcp2_flexion_r").id]] += 0.6
    open_, bent = (bone_poses_at(model, data, q, ids) for q in (q0, q1))
    cfg = Config(device="cpu", execution=Execution(jacobi_gather=gather))
    batch = BatchedHands(asset, 2, cfg, *mount)
    serial = []
    for _ in range(2):
        s = Solver(make_model(asset, cfg), cfg)
        serial.append((s, s.make_state(*mount)))
    for f in range(8):
        a = min((f + 1) / 4, 1.0)
        poses = [open_, (bent[0] * a + open_[0] * (1 - a), bent[1])]
        out = batch.step(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]))
        assert out["nonfinite"] == 0
        for (s, st), p in zip(serial, poses):
            s.set_body_poses(st, *p)
            s.step(st)
    for w, (_, st) in enumerate(serial):
        assert np.abs(batch.positions(w) - st.x.numpy()).max() <= 1e-7
        assert np.array_equal(batch.skin(w), st.x.numpy()[: asset.n_skin])
    assert np.abs(batch.skin(0) - batch.skin(1)).max() > 1e-3  # the worlds did differ
    with pytest.raises(ValueError, match="bone poses"):
        batch.step(np.stack([open_[0]]), np.stack([open_[1]]))


def _beside_serial(batch, asset, cfg, mount, poses, where, geom: dict, serial_worlds: int, frames: int = 4):
    """Step ``batch`` (every world at ``poses``, world w's one object at ``where[w]``) and, beside it,
    a serial solver with its own copy of the object ``geom`` (Objects.add's arguments) for each of
    the first ``serial_worlds`` worlds; returns the batch's last frame dict and the (solver, state)
    pairs."""
    from physhand_mj.contact import Objects

    W = batch.worlds
    serial = []
    for w in range(serial_worlds):
        objs = Objects("cpu", 1)
        g = dict(geom)
        objs.add(g.pop("gtype"), g.pop("size"), where[w], name="ball", **g)
        s = Solver(make_model(asset, cfg), cfg, objects=objs)
        serial.append((s, s.make_state(*mount)))
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * W)
    for _ in range(frames):
        out = batch.step(np.stack([poses[0]] * W), np.stack([poses[1]] * W), np.stack(where)[:, None], ident)
        for s, st in serial:
            s.set_body_poses(st, *poses)
            s.step(st)
    return out, serial


def test_batched_worlds_with_their_own_objects(setup):
    """Two worlds, each with its own sphere: world 1's presses the back of its hand, world 0's
    waits 10 cm away. Each ends exactly as a serial solver given the same sphere (all worlds are
    solved at the origin; an analytic sphere has no object-side features), world 1 pressed, world 0
    untouched, and nothing penetrates."""
    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = Config(device="cpu")
    batch = BatchedHands(asset, 2, cfg, *mount, objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = [top + [0.0, 0.1, 0.05], top + [0.0, 0.0, 0.02 - 0.002]]  # world 0: away; world 1: 2 mm in
    out, serial = _beside_serial(batch, asset, cfg, mount, poses, where, dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0)),
                                 serial_worlds=2)
    assert out["penetration_count"] == 0 and out["triangles_tested"] > 0
    # checked by measures the contact does not use: an order-9 skin lattice and the spheres' surface
    # points inside the closed skin of every world
    from physhand_mj.contact.metrics import summarize

    dense = summarize(batch.solver.contact.measure(batch.state, order=9))
    assert dense["penetration_count"] == 0 and dense["object_in_skin_count"] == 0, dense
    rest = serial[0][1].x.numpy()
    for w, (_, st) in enumerate(serial):
        np.testing.assert_array_equal(batch.positions(w), st.x.numpy())
    moved = np.abs(batch.skin(1) - rest[: asset.n_skin]).max()
    assert moved > 1e-3 > np.abs(batch.skin(0) - rest[: asset.n_skin]).max() * 10  # world 1 pressed, world 0 not
    skins = batch.skins()  # every world's skin in one copy, each in its own frame (worlds here sit 1 m apart)
    assert skins.shape == (2, asset.n_skin, 3) and all(np.array_equal(skins[w], batch.skin(w)) for w in range(2))


@pytest.mark.parametrize("tiled", [False, True, "scan"], ids=["bvh", "tiled", "scan"])
def test_batched_worlds_share_one_mesh_and_match_serial_runs(setup, monkeypatch, tiled):
    """A mesh object in every world is one wp.Mesh (its BVH built once, not W times), and a world
    pressed by it ends like a serial solver with its own copy of the mesh (within the float32
    rounding of its object-side queries 1 m out), by the contact's own measure and the independent
    ones; with the BVH feature kernels, with CUDA's tiled ones and with CUDA batches' thread per
    feature over its patch (both forced on the CPU)."""
    import trimesh

    from physhand_mj.contact.metrics import summarize
    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    if tiled:  # CUDA's feature kernels (a block per feature over the frame's triangle list), forced on the CPU
        from physhand_mj.contact.contact import Contact

        init = Contact.__init__

        def tiled_init(self, *args, **kw):
            init(self, *args, **kw)
            self.tiled_features = True
            self.feature_scan = tiled == "scan"

        monkeypatch.setattr(Contact, "__init__", tiled_init)
        # a later pass's feature scan reads the object side's shifted copy of the skin, which
        # query.apply_contact keeps current vertex by vertex (no copy of the whole skin per pass)
        record, seen = Contact._record_features, []

        def checked(self, rec, state, p, *rest):
            def same():
                n = self.model.n_skin
                x, shift = state.x.numpy()[:n], self.query_shift.numpy()
                np.testing.assert_array_equal(self.volume(state, winding=False).points.numpy(), x + shift)
                seen.append(p)

            if p and self.query_shift is not None:  # (the batch's; the serial runs query x itself)
                rec.ops.append(same)
            return record(self, rec, state, p, *rest)

        monkeypatch.setattr(Contact, "_record_features", checked)
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = Config(device="cpu")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.02)
    spec = dict(gtype=GeomType.MESH, name="ball", vertices=ball.vertices, faces=ball.faces, mesh_range=0.05)
    batch = BatchedHands(asset, 3, cfg, *mount, objects=[spec])
    objs = batch.objects
    assert batch.solver.contact.tiled_features == bool(tiled)
    assert batch.solver.contact.feature_scan == (tiled == "scan")
    ids = {tuple(r) for r in objs._host["mesh"][:3].tolist()}  # (wp.Mesh id, distance grid id): one of each
    assert len(objs._meshes) == 1 and len(ids) == 1 and min(next(iter(ids))) != 0, ids
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    r_in = float(np.linalg.norm(ball.vertices, axis=1).min())  # the mesh's lowest point lies at least this deep
    where = [top + [0.0, 0.1, 0.05], top + [0.0, 0.0, r_in - 0.002], top + [0.0, 0.1, 0.05]]
    out, serial = _beside_serial(batch, asset, cfg, mount, poses, where,
                                 dict(gtype=GeomType.MESH, size=None, vertices=ball.vertices, faces=ball.faces,
                                      mesh_range=0.05), serial_worlds=2)
    assert out["penetration_count"] == 0 and out["triangles_tested"] > 0
    assert int(batch.solver.contact.features.count.numpy()[0]) > 0  # the mesh's corners and edges were listed
    dense = summarize(batch.solver.contact.measure(batch.state, order=9, check=True))
    assert dense["penetration_count"] == 0 and dense["object_in_skin_count"] == 0, dense
    rest = serial[0][1].x.numpy()
    # world 0 (query offset 0) equals its serial run bit for bit; world 1's object-side queries run
    # 1 m out, where float32 rounds at ~0.06 um: its pushes are computed at the origin
    # (features.at_origin), but the face, sign and stage list still come from the query 1 m out, and
    # a tie decided otherwise there is amplified (measured: 9.1 um BVH / 11.8 um tiled; 23 um when
    # the pushes were computed 1 m out)
    np.testing.assert_array_equal(batch.positions(0), serial[0][1].x.numpy())
    assert np.abs(batch.positions(1) - serial[1][1].x.numpy()).max() < 5e-5
    assert np.abs(batch.skin(1) - rest[: asset.n_skin]).max() > 1e-3  # world 1 was pressed
    assert not tiled or len(seen) > 10  # (the later passes' copies were checked)


def test_metrics_and_guards_per_world(setup):
    """Per-world reports: a sphere 2 mm into world 1's hand shows in world 1's two measures only; a
    non-finite vertex set in world 1 is reset and counted in world 1 alone; the batch's frame
    counts are the worlds' sums."""
    import warp as wp

    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    batch = BatchedHands(asset, 2, Config(device="cpu"), *mount,
                         objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = np.stack([top + [0.0, 0.1, 0.05], top + [0.0, 0.0, 0.02 - 0.002]])[:, None]
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
    batch.set_object_poses(where, ident)
    pen = batch.penetration()
    assert pen[0]["penetration_count"] == 0 and pen[0]["object_in_skin_count"] == 0, pen
    assert pen[1]["penetration_count"] > 0 and 1500 < pen[1]["penetration_max_um"] <= 2100, pen
    assert pen[1]["object_in_skin_count"] > 0, pen
    # the object side tests a point only within its own world's skin box (inside.object_points_inside):
    # one box per world, each its world's queried skin's bounds
    vol = batch.solver.contact.volume(batch.state)
    box, pts = vol.box.numpy().reshape(2, 2, 3), vol.points.numpy().reshape(2, -1, 3)
    np.testing.assert_array_equal(box[:, 0], pts.min(axis=1))
    np.testing.assert_array_equal(box[:, 1], pts.max(axis=1))
    both = batch.solver.contact.measure(batch.state)  # the batch's row: the worlds' sum / maximum
    assert int(both[0]) == pen[1]["penetration_count"] and abs(both[2] * 1e6 - pen[1]["penetration_max_um"]) < 1e-3
    x = batch.state.x.numpy()
    x[asset.n_skin + 5] = np.nan  # a skin vertex of world 1
    batch.state.x.assign(wp.array(x, dtype=wp.vec3, device="cpu"))
    out = batch.step(np.stack([poses[0]] * 2), np.stack([poses[1]] * 2), where, ident)
    w0, w1 = out["worlds"]
    assert w0["nonfinite"] == 0 and w1["nonfinite"] >= 1 and out["nonfinite"] == w1["nonfinite"], out["worlds"]
    assert out["penetration_count"] == w0["penetration_count"] + w1["penetration_count"]
    m = batch.metrics()
    assert m[0]["finite"] and m[1]["finite"] and m[1]["nonfinite"] == w1["nonfinite"] and m[0]["nonfinite"] == 0


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not wp.is_cuda_available(), reason="no CUDA device"))])
def test_a_batch_without_frame_metrics_measures_on_demand(setup, device):
    """Config.frame_metrics=False: the batch's frames report no skin measure (no column rather than a
    zero), its skins are those of a batch that measures every frame (bit for bit on the CPU; CUDA's
    contact sums with float atomics in no fixed order), and ``penetration()`` measures per world what
    the frame measured: world 1 holds a 1 mm sphere 0.5 mm inside a skin triangle, which the vertex
    strategy's decision points (corners, edge midpoints) do not see, world 0 nothing near."""
    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    faces = asset.skin_faces
    runs = []
    for on in (True, False):
        batch = BatchedHands(asset, 2, Config(device=device, contact="vertex", frame_metrics=on), *mount,
                             objects=[dict(gtype=GeomType.SPHERE, size=(0.001, 0, 0), name="ball")])
        skin = batch.skin(1)
        top = skin[np.argmax(skin[:, 2])].astype(float)
        x = skin[faces].astype(float)
        t = np.argmin(np.linalg.norm(x.mean(axis=1) - top, axis=1))
        n = np.cross(x[t, 1] - x[t, 0], x[t, 2] - x[t, 0])
        where = np.stack([top + [0.0, 0.1, 0.05], x[t].mean(axis=0) - 5e-4 * n / np.linalg.norm(n)])[:, None]
        ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
        out = batch.step(np.stack([poses[0]] * 2), np.stack([poses[1]] * 2), where, ident)
        runs.append((out, batch.skins(), batch.penetration()))
    (o1, x1, p1), (o2, x2, p2) = runs
    assert "penetration_count" in o1 and "penetration_count" in o1["worlds"][1]
    assert not any(k.startswith("penetration") for k in [*o2, *o2["worlds"][1]]), o2["worlds"]
    if device == "cpu":
        assert np.array_equal(x1, x2)
        assert p1 == p2
    else:
        np.testing.assert_allclose(x1, x2, atol=2e-5)
    assert o1["worlds"][0]["penetration_count"] == 0 < o1["worlds"][1]["penetration_count"], o1["worlds"]
    assert [w["penetration_count"] for w in p2] == [w["penetration_count"] for w in o1["worlds"]], (p2, o1["worlds"])


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not wp.is_cuda_available(), reason="no CUDA device"))])
def test_reused_outside_answers_per_world(setup, device):
    """Config.execution.reuse_outside in a batch: each world's skin patches and objects bound its own points.
    Frame by frame the hands close towards a pinch (their skins move, the balls held away), then
    the measure runs with world 1's ball (r 12 mm) put 1 mm further into its skin each frame and
    world 0's coming closer without touching: both worlds' object-side counts and depths equal
    asking every point, world 1's growing from zero, and most points were not asked again."""
    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    q_open, q_pinch = model.key("open").qpos.copy(), model.key("pinch").qpos.copy()
    batch = BatchedHands(asset, 2, Config(device=device), *mount,
                         objects=[dict(gtype=GeomType.SPHERE, size=(0.012, 0.0, 0.0), name="ball")])
    c = batch.solver.contact
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    ident = np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2)
    away = np.stack([top + [0.0, 0.0, 0.2]] * 2)[:, None]
    counts = []
    for f in range(5):
        pos, quat = bone_poses_at(model, data, q_open + (f + 1) / 8 * (q_pinch - q_open), ids)
        batch.step(np.stack([pos] * 2), np.stack([quat] * 2), away, ident)
        batch.set_object_poses(np.stack([top + [0.0, 0.0, 0.03 - 0.002 * f],
                                         top + [0.0, 0.0, 0.012 - 0.001 * f]])[:, None], ident)
        kept = c.measure_worlds(batch.state)
        c.measures.config = dataclasses.replace(c.measures.config, reuse_outside=False)
        every = c.measure_worlds(batch.state)
        c.measures.config = dataclasses.replace(c.measures.config, reuse_outside=True)
        # counts and maxima exactly; the depth sums within float rounding (CUDA's atomics add in any order)
        np.testing.assert_array_equal(kept[:, [0, 2, 3, 5]], every[:, [0, 2, 3, 5]])
        np.testing.assert_allclose(kept[:, [1, 4]], every[:, [1, 4]], rtol=1e-6)
        counts.append(every[:, 3])
    counts = np.array(counts)
    assert counts[0, 1] == 0 and counts[-1, 1] > 20 and not counts[:, 0].any(), counts
    assert any(int((m.slack.numpy() > 0).sum()) > 1000 for m in c.measures.reuse_memory.values())


def test_broadphase_tests_only_the_triangles_own_world(setup):
    """Worlds on top of each other (every world is solved at the origin): world 0's sphere pressing the hand activates
    world 0's triangles only; world 1's triangles test world 1's sphere (far away) alone."""
    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    batch = BatchedHands(asset, 2, Config(device="cpu"), *mount,
                         objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = np.stack([top + [0.0, 0.0, 0.02 - 0.002], top + [0.0, 0.3, 0.3]])[:, None]
    batch.set_object_poses(where, np.array([[[1.0, 0.0, 0.0, 0.0]]] * 2))
    c = batch.solver.contact
    decision = c.run_stage(batch.state)
    f = len(asset.skin_faces)
    hit = decision[:, 3] < 1.0  # triangles the stage queried (skipped ones keep phi = 1e6)
    assert hit[:f].sum() > 0 and hit[f:].sum() == 0, (hit[:f].sum(), hit[f:].sum())


def test_masks_world_relative_past_31_geoms(setup):
    """40 worlds with a sphere each (40 geoms: past the 31 mask bits), all solved at the origin
    (their object-side queries 1 m apart, up to (4, 5, 0) m for world 39): every triangle's
    broadphase mask is relative to its world's geoms (bit 0 = its own sphere, in every world, the
    31st on included), and the farthest world ends exactly as a serial solver with that world's hand
    and sphere: same skin and all positions, same active triangles and corrected vertices per stage
    (no other world's geom took part), and the batch's broadphase work is exactly W times one hand's."""
    from physhand_mj.contact import Objects
    from physhand_mj.types import GeomType

    asset, model, data, ids, mount = setup
    W, far = 40, 39
    poses = bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = Config(device="cpu", substeps=3)  # (3: 1.7 ms substeps, no stability warning)
    batch = BatchedHands(asset, W, cfg, *mount, objects=[dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = top + [0.0, 0.0, 0.02 - 0.002]  # 2 mm into the back of every world's hand
    assert batch.solver.contact.geoms_per_world == 1 and np.linalg.norm(batch.query_offsets[far]) > 6.0
    assert not np.any(batch.offsets)  # solved at the origin
    objs = Objects("cpu", 1)
    objs.add(GeomType.SPHERE, (0.02, 0, 0), where, name="ball")
    s = Solver(make_model(asset, cfg), cfg, objects=objs)
    st = s.make_state(*mount)
    for _ in range(2):
        out = batch.step(np.stack([poses[0]] * W), np.stack([poses[1]] * W), np.tile(where, (W, 1))[:, None],
                         np.array([[[1.0, 0.0, 0.0, 0.0]]] * W))
        s.set_body_poses(st, *poses)
        ref = s.step(st)
    c = batch.solver.contact
    n = int(c.cand_count.numpy()[0])
    tris, masks = c.lists.cand.numpy()[:n], c.lists.cand_mask.numpy()[:n]
    world = tris // c.tris_per_world
    assert len(np.unique(world)) == W, np.unique(world)  # every world's sphere is near its hand
    np.testing.assert_array_equal(masks, 1)  # bit 0: the world's own (only) geom, also past geom 31
    # the far world equals its serial run bit for bit (the same constraints and queries, in order)
    np.testing.assert_array_equal(batch.positions(far), st.x.numpy())
    np.testing.assert_array_equal(c.stage_counts_worlds()[far], s.contact.stage_counts())
    assert s.contact.stage_counts()[0, 0] > 0
    assert out["triangles_tested"] == W * ref["triangles_tested"]


def test_batched_hands_refuse_worlds_queried_too_close():
    """With objects, the object side's queries need the worlds' grid at least 0.3 m apart."""
    from physhand_mj.types import GeomType

    with pytest.raises(ValueError, match="spacing must be at least 0.3 m with objects"):
        BatchedHands(ph.load_asset(), 2, Config(device="cpu"), objects=[dict(gtype=GeomType.SPHERE, size=(0.01, 0, 0))],
                     spacing=0.1)


def test_batched_hands_refuse_a_nonfinite_policy_that_stops_every_world():
    import physhand_mj as ph
    from physhand_mj.batch import BatchedHands
    from physhand_mj.types import NonFinite

    with pytest.raises(ValueError, match="BatchedHands needs Config.nonfinite=NonFinite.RECOVER"):
        BatchedHands(ph.load_asset(), 2, ph.Config(device="cpu", nonfinite=NonFinite.RAISE))


def test_kernel_choices_follow_the_batch(setup):
    """Config's None defaults pick per use: batched worlds gather their Jacobi corrections and run
    multires and the feature queries a thread per triangle / feature on CUDA (faster there,
    docs/scale.md), one hand keeps the atomics and the tiled kernels; explicit values win; anything
    else is refused."""
    import warp as wp

    asset = setup[0]
    for bad in (dict(tiled_contact="yes"), dict(jacobi_gather=1.0), dict(tiled_features=0)):
        with pytest.raises(ValueError, match=list(bad)[0]):
            Config.from_dict(bad).validate()
    cpu = BatchedHands(asset, 2, Config(device="cpu"))  # the CPU keeps the atomics (cheaper there)
    assert not cpu.solver.model.gather_off and cpu.solver.model.n_slots == 0
    if not wp.is_cuda_available():
        pytest.skip("no CUDA device: the choices are CUDA's")
    from physhand_mj.types import GeomType

    ball = [dict(gtype=GeomType.SPHERE, size=(0.02, 0.0, 0.0), name="ball")]
    batch = BatchedHands(asset, 2, Config(device="cuda"), objects=ball)
    assert batch.solver.model.gather_off and not batch.solver.contact.tiled
    assert batch.solver.contact.tiled_features and not batch.solver.contact.feature_scan  # a block per feature
    from physhand_mj.contact.contact import FEATURE_SCAN_WORLDS

    big = BatchedHands(asset, FEATURE_SCAN_WORLDS, Config(device="cuda"), objects=ball)
    assert big.solver.contact.tiled_features and big.solver.contact.feature_scan  # a thread per feature
    lone = BatchedHands(asset, 1, Config(device="cuda"), objects=ball)  # a batch of one is one hand
    assert not lone.solver.model.gather_off and lone.solver.contact.tiled
    assert lone.solver.contact.tiled_features and not lone.solver.contact.feature_scan  # a block per feature
    forced = BatchedHands(asset, 2, Config(device="cuda", execution=Execution(tiled_contact=True, jacobi_gather=False)), objects=ball)
    assert not forced.solver.model.gather_off and forced.solver.contact.tiled
    from physhand_mj.contact import Objects

    objects = Objects("cuda", 1)
    objects.add(GeomType.SPHERE, (0.02, 0.0, 0.0), (0.0, 0.0, 1.0), name="ball")
    cfg = Config(device="cuda")
    one = Solver(make_model(asset, cfg), cfg, objects=objects)
    assert not one.model.gather_off and one.contact.tiled


def test_a_closed_batch_frees_its_solver_and_says_so():
    """BatchedHands.close (and ``with``) releases the solver (with its recorded frame), state and
    objects at once (weak references to them die) and a closed batch refuses to step with the fix."""
    import weakref

    from physhand_mj.types import GeomType

    asset = ph.load_asset()
    spec = dict(gtype=GeomType.SPHERE, size=[0.02], name="ball")
    with BatchedHands(asset, 2, Config(device="cpu"), objects=[spec]) as batch:
        b = batch.n_bodies
        rest = batch.state.pose_host[1].astype(float)  # the bones where they are: [p, q x y z w] per body
        pos, quat = rest[:, :3].reshape(2, b, 3), rest[:, [6, 3, 4, 5]].reshape(2, b, 4)
        far = (np.zeros((2, 1, 3)) + 1.0, np.tile([1.0, 0.0, 0.0, 0.0], (2, 1, 1)))  # the ball 1 m away
        batch.step(pos, quat, *far)  # a recorded frame holds the arrays too
        solver, state = weakref.ref(batch.solver), weakref.ref(batch.state)
    assert solver() is None and state() is None and batch.objects is None
    with pytest.raises(RuntimeError, match="closed"):
        batch.step(pos, quat, *far)
    batch.close()  # twice is fine


def _summarize_reference(row) -> dict:
    """A metrics row summarized one value at a time in Python (what metrics.summarize did before it
    became summarize_rows of one row): the reference for the column-wise version."""
    out = {}
    for prefix, k in (("penetration", 0), ("object_in_skin", 3)):
        if k + 2 >= len(row):
            break
        count = int(round(float(row[k])))
        out.update({f"{prefix}_count": count, f"{prefix}_max_um": float(row[k + 2]) * 1e6,
                    f"{prefix}_avg_um": float(row[k + 1]) / count * 1e6 if count else 0.0})
    return out


def test_summarize_rows_is_summarize_row_by_row():
    """metrics.summarize_rows (the batch's per-world reports, all rows at once) and metrics.summarize
    (one row) give what a row summarized one Python value at a time gives: the same keys, values and
    types, for 3- and 6-column rows, with zero counts and counts on the float32 halves (rounded to
    even, as round() does)."""
    from physhand_mj.contact.metrics import summarize, summarize_rows

    rng = np.random.default_rng(1)
    for cols in (3, 6):
        rows = (rng.random((300, cols)) * 1e-3).astype(np.float32)
        rows[:, 0] = rng.integers(0, 4, 300)
        rows[:, cols - 3] = rng.integers(0, 3, 300)
        rows[:3, 0] = [0.5, 1.5, 2.5]
        one, each = summarize_rows(rows), [_summarize_reference(r) for r in rows]
        assert one == each
        assert all(type(a[k]) is type(b[k]) for a, b in zip(one, each) for k in a)
        assert [summarize(r) for r in rows] == each
