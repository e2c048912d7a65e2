"""SoftHand in MuJoCo scenes: write-back, bones, contact report, errors."""

import mujoco
import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.coupling import SoftHand
from physhand_mj.hand_mjcf import skin_geom_id


def _scene(name="grasp_glass", key="approach"):
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path(name)))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key(key).id)
    mujoco.mj_forward(model, data)
    return model, data


@pytest.fixture(scope="module")
def glass_grasp():
    """The demo's grasp (grasp_glass from `approach`, Config()) after 60 frames, and per frame the
    measures test_the_demo_grasp_is_clean_by_every_measure asserts on: (order-5 skin samples' max
    depth, order-9's, the contact points' max depth in the skin, the check points'), m. Measuring
    changes nothing the other tests read (checked: the same skin, mesh, qpos and reports, bit for bit)."""
    model, data = _scene()
    hand = SoftHand(model, data, ph.Config(device="cpu"))
    c, state = hand.solver.contact, hand.state
    rows = []
    for _ in range(60):
        mujoco.mj_step(model, data)
        hand.step()
        o5, o9, chk = c.measure(state, order=5), c.measure(state, order=9, objects_side=False), c.measure(state, check=True)
        rows.append((o5[2], o9[2], o5[5], chk[5]))
    return model, data, hand, np.array(rows)


def test_written_back_mesh_equals_the_skin(glass_grasp):
    model, data, hand, _ = glass_grasp
    gid = skin_geom_id(model)
    mid = model.geom_dataid[gid]
    local = model.mesh_vert[model.mesh_vertadr[mid]: model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
    world = local @ data.geom_xmat[gid].reshape(3, 3).T + data.geom_xpos[gid]
    assert np.abs(world - hand.skin_vertices).max() < 1e-6
    normals = model.mesh_normal[model.mesh_normaladr[mid]: model.mesh_normaladr[mid] + model.mesh_normalnum[mid]]
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)


@pytest.mark.skipif(not __import__("warp").is_cuda_available(), reason="no CUDA device")
def test_the_write_back_inside_the_cuda_frame_graph_writes_the_frame_s_skin():
    """On CUDA the write-back's device half runs at the end of the solver's frame graph
    (Solver.set_frame_tail) with the skin geom's pose set before the frame: after each step
    MuJoCo's mesh maps back onto the solver's skin of that frame, and equals an immediate write."""
    model, data = _scene()
    hand = SoftHand(model, data, ph.Config(device="cuda"), settle_frames=2)
    assert hand._tail_writer and hand.solver._tail
    gid = skin_geom_id(model)
    mid = model.geom_dataid[gid]
    adr, n = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
    for f in range(12):
        mujoco.mj_step(model, data)
        hand.step()
        x = hand.state.x.numpy()[:n].astype(float)
        world = model.mesh_vert[adr: adr + n] @ data.geom_xmat[gid].reshape(3, 3).T + data.geom_xpos[gid]
        assert np.abs(world - x).max() < 1e-6 and np.abs(hand.skin_vertices - x).max() < 1e-6, f
    tail = model.mesh_vert[adr: adr + n].copy(), model.mesh_normal[model.mesh_normaladr[mid]:][:n].copy()
    hand._write_back()  # the immediate path, same skin and pose
    assert np.array_equal(tail[0], model.mesh_vert[adr: adr + n])
    assert np.abs(tail[1] - model.mesh_normal[model.mesh_normaladr[mid]:][:n]).max() < 1e-6


def test_skeleton_vertices_follow_their_bodies(glass_grasp):
    model, data, hand, _ = glass_grasp
    asset = hand.asset
    skel = np.flatnonzero(asset.layer == ph.Layer.SKELETON)
    b = asset.vertex_body[skel]
    from physhand_mj.rotations import quat_to_mat
    local = np.einsum("kji,kj->ki", quat_to_mat(asset.body_rest_quat)[b], asset.positions[skel] - asset.body_rest_pos[b])
    bones = hand.bones[b]
    want = np.einsum("kij,kj->ki", data.xmat[bones].reshape(-1, 3, 3), local) + data.xpos[bones]
    assert np.abs(hand.state.x.numpy()[skel] - want).max() < 2e-6


def test_glass_grasp_contact_report(glass_grasp):
    _, _, hand, _ = glass_grasp
    report = hand.contacts()
    glass = report["objects"]["glass"]
    assert len(glass["vertices"]) > 30 and glass["area_m2"] > 1e-4 and glass["force_n"] > 0.5, glass
    m = hand.metrics()
    assert m["finite"] and m["nonfinite"] == 0
    assert m["penetration_max_um"] < 100.0, m
    p = report["pressure_pa"]
    assert p.shape == (hand.asset.n_skin,) and (p > 0).sum() == len(glass["vertices"])
    # the bones' clearance (contact/bones.py): with the proxies' margin (Config.tuning.proxy_margin, one-way:
    # 2.5 mm) MuJoCo stops them clear of the glass (before it, two bones ended 0.64 mm inside); the report
    # agrees with the skeleton's vertices measured against the glass's cylinder here, and no skin is held
    model, data = glass_grasp[0], glass_grasp[1]
    g = model.geom("glass").id
    r, h = model.geom_size[g][:2]
    q = hand.state.x.numpy()[np.asarray(hand.asset.layer) == 0] - data.geom_xpos[g]  # (the glass stands upright)
    rad, ax = np.hypot(q[:, 0], q[:, 1]) - r, np.abs(q[:, 2]) - h
    sdf = np.hypot(np.maximum(rad, 0), np.maximum(ax, 0)) + np.minimum(np.maximum(rad, ax), 0)
    assert abs(glass["bone_clearance_mm"] - sdf.min() * 1e3) < 0.01, (glass["bone_clearance_mm"], sdf.min())
    assert 1.0 < glass["bone_clearance_mm"] < 5.0 and not glass["bones_inside"], glass
    assert glass["skin_held"] == 0 and report["bone_clearance_mm"] == glass["bone_clearance_mm"]
    assert hand.proxy_margin == ph.hand_mjcf.PROXY_INSET and len(hand.proxies) == 16
    assert np.all(model.geom_margin[hand.proxies] == ph.hand_mjcf.PROXY_INSET)
    # the proxies keep the bones out, so a bone inside is an infeasible start: held from 0.5 mm (bones.py)
    from physhand_mj.contact.bones import KEPT_OUT_DEPTH

    assert hand.solver.contact.hold_depth == KEPT_OUT_DEPTH


PAPER = dict(feature_contact=False, side_aware=False, skin_tether=0.0)  # the paper's contact: Eq. 9 at multires decision points


def _close_on(kind, free=True, **config):
    """grasp_glass with the glass swapped for a static sphere or box (MjSpec); the hand closes on it
    under position control, once with the skin's contact (``config``: Config fields) and, with
    ``free``, once without (the same bone motion; else None: the hand's run is the same either way,
    both only read the MuJoCo data)."""
    spec = mujoco.MjSpec.from_file(str(ph.scene_path("grasp_glass")))
    geom = spec.geom("glass")
    if kind == "sphere":
        geom.type, geom.size = mujoco.mjtGeom.mjGEOM_SPHERE, [0.04, 0, 0]
    elif kind == "box":
        geom.type, geom.size = mujoco.mjtGeom.mjGEOM_BOX, [0.03, 0.03, 0.06]
    else:  # a compound object: the glass with a box handle where the fingertips close
        spec.body("glass").add_geom(name="handle", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.006, 0.006, 0.02],
                                    pos=[0.036, -0.012, 0.01])
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = SoftHand(model, data, ph.Config.from_dict(dict(device="cpu", **config)), object_bodies=["glass"])
    free = SoftHand(model, data, ph.Config(device="cpu"), object_geoms=[]) if free else None
    for _ in range(50):
        mujoco.mj_step(model, data)
        hand.step()
        if free:
            free.step()
    return model, data, hand, free


@pytest.fixture(scope="module")
def closed():
    """``_close_on`` made once per module for each (kind, the paper's contact?): the closing tests
    only read the runs (the box with the paper's contact serves both)."""
    runs = {}

    def get(kind, paper=False, free=False, bare=False):
        key = (kind, paper, bare)  # (bare: the proxies without their margin, Config.tuning.proxy_margin 0)
        if key not in runs or (free and runs[key][3] is None):
            runs[key] = _close_on(kind, free=free, **(PAPER if paper else {}), **(dict(proxy_margin=0.0) if bare else {}))
        return runs[key]

    yield get
    runs.clear()


def test_the_demo_grasp_is_clean_by_every_measure(glass_grasp):
    """The demo (grasp_glass from `approach`, Config()): in each of 60 frames, closing and holding,
    no skin sample inside the glass on the metric's order-5 lattice nor on an order-9 lattice (no
    strategy samples it), no contact feature point inside the skin, and the denser check points
    (none of them a point the contact pushes) within 25 um: between two feature points (0.25 mm
    apart) the skin can rest on the glass's rim edge a little inside it (CPU: up to 12.3 um in this
    test's 60 frames; benchmarks/demo_residue.py, removed; in git history at a33bd78, 80 frames: 3 frames, up to 7.5 um). Before the scene's closing targets stopped at the glass
    (2026-11-25) MuJoCo drove the thumb's bone into it and 33 of 80 frames had order-5 residue."""
    _, _, hand, rows = glass_grasp
    r = 1e6 * rows
    assert hand.contacts()["objects"]["glass"]["force_n"] > 1.0  # the hand holds the glass
    assert r[:, :3].max() == 0.0 and r[:, 3].max() <= 25.0, r.max(axis=0)


@pytest.mark.parametrize("kind", ["sphere", "box", "compound"])
def test_closing_on_a_static_object_ends_without_penetration(closed, kind):
    """The paper's claim on its own metric (order-5 samples), with the paper's contact; the default
    contact is checked by both independent measures in the next test."""
    model, data, hand, free = closed(kind, paper=True, free=True)
    m = hand.metrics()
    assert m["finite"] and m["penetration_count"] == 0, m
    touched = hand.contacts()["objects"]["glass"]
    assert len(touched["vertices"]) > 20 and touched["force_n"] > 0.1, touched
    if kind == "compound":  # both geoms of the object are touched, and neither is penetrated
        assert len(hand.objects.names) == 2 and len(hand.penetrating_samples()[0]) == 0
        g = model.geom("handle").id
        local = (hand.skin_vertices[touched["vertices"]] - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
        q = np.abs(local) - model.geom_size[g]
        near_handle = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0) < 1e-3
        assert near_handle.sum() > 10 and (~near_handle).sum() > 50, (near_handle.sum(), (~near_handle).sum())
        return
    # away from the contact (> 15 mm from the object) the skin is where the contact-free run has it
    g = model.geom("glass").id
    local = (hand.skin_vertices - data.geom_xpos[g]) @ data.geom_xmat[g].reshape(3, 3)
    if kind == "sphere":
        dist = np.linalg.norm(local, axis=1) - 0.04
    else:
        q = np.abs(local) - [0.03, 0.03, 0.06]
        dist = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    far = dist > 0.015
    diff = np.linalg.norm(hand.skin_vertices - free.skin_vertices, axis=1)
    assert far.sum() > 1000 and np.percentile(diff[far], 99) < 1.5e-3 and diff[far].max() < 3.0e-3, (
        np.percentile(diff[far], 99), diff[far].max())


@pytest.mark.slow  # 12-41 s on a 2-core CPU (2026-12-03): the slow set keeps the default run under 15 min
@pytest.mark.parametrize("kind", ["sphere", "box"])
def test_closing_by_both_measures(closed, kind):
    """The default contact (features + side-aware) against an order-9 lattice and the denser check
    points (Contact.check_points: none of them a feature the contact pushes). On the sphere both are
    zero. On the box, with the proxies' margin off (``proxy_margin=0``, the model as shipped; with
    the one-way default of 2.5 mm MuJoCo stops every bone outside the box, asserted too), the
    position controller keeps closing the hand and MuJoCo's soft contacts let
    the bones themselves into the box (at frame 50 the thumb's proximal bone mesh 5.1 mm, its
    collision proxy 4.1 mm, the ring fingertip's bone 0.8 mm): no penetration-free skin exists
    there, and the skin's residue follows how far the bones go in (the issue's "bone inside the
    object" start; docs/contact.md). Asserted: bones inside, the residue bounded (order 9: 0.09-1.25
    mm per frame over frames 40-79 on the CPU, 0.35 mm at frame 50; 0.04-1.13 mm with the settings
    before 2026-11-25, when the bound was 0.3 mm at frame 50), and fewer object points in the skin
    than the paper's contact leaves."""
    box = kind == "box"
    model, data, hand, _ = closed(kind, bare=box)
    m = hand.penetration(order=9, check=True)
    if kind == "sphere":
        assert m["penetration_count"] == 0 and m["object_in_skin_count"] == 0, m
        return

    def bone_depth(model, data):
        g = model.geom("glass").id
        return -min(mujoco.mj_geomDistance(model, data, k, g, 0.05, np.zeros(6)) for k in range(model.ngeom)
                    if model.geom_bodyid[k] not in (0, model.geom_bodyid[g]) and model.geom(k).name.endswith("_bone"))

    assert bone_depth(model, data) > 1.0e-3, bone_depth(model, data)  # a bone mesh more than 1 mm inside the box
    margin_model, margin_data, _, _ = closed(kind, paper=True)  # (the margin on: MuJoCo alone, the same either contact)
    assert bone_depth(margin_model, margin_data) < 0.0, bone_depth(margin_model, margin_data)
    _, _, paper, _ = closed(kind, paper=True, bare=True)
    p = paper.penetration(order=9, check=True)
    assert np.all(np.isfinite(hand.skin_vertices))
    assert m["penetration_max_um"] < 1500 and m["object_in_skin_max_um"] < 1500, m
    assert m["object_in_skin_count"] < p["object_in_skin_count"], (m, p)


def _palm_press(depth):
    """hand_only + a static sphere pressed ``depth`` m into the palm, built with MjSpec."""
    asset = ph.load_asset()
    spec = mujoco.MjSpec.from_file(str(ph.scene_path("hand_only")))
    model0 = spec.compile()
    data0 = mujoco.MjData(model0)
    mujoco.mj_resetDataKeyframe(model0, data0, model0.key("open").id)
    mujoco.mj_forward(model0, data0)
    n = np.asarray(asset.meta["palm_normal"])
    names = list(asset.body_names)
    c = asset.body_rest_pos[names.index("3proxph_r")] - 0.02 * np.asarray(asset.meta["finger_axis"])
    skin = asset.skin_vertices
    lateral = np.linalg.norm((skin - c) - np.outer((skin - c) @ n, n), axis=1)
    s = skin[lateral < 0.01][np.argmax((skin[lateral < 0.01] - c) @ n)]
    pos, quat = ph.mount_pose(model0, data0)
    from physhand_mj.rotations import quat_to_mat
    rot = quat_to_mat(quat)
    centre = rot @ s + pos + rot @ n * (0.02 - depth)
    body = spec.worldbody.add_body(name="ball", pos=centre)
    body.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.02, 0, 0], contype=0, conaffinity=0)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("open").id)
    mujoco.mj_forward(model, data)
    hand = SoftHand(model, data, ph.Config(device="cpu", gravity=(0.0, 0.0, 0.0)), object_geoms=["ball"],
                    settle_frames=5)
    for _ in range(15):
        mujoco.mj_step(model, data)
        hand.step()
    return hand


def test_force_estimate_grows_with_press_depth():
    forces = [_palm_press(d).contacts()["objects"]["ball"]["force_n"] for d in (0.001, 0.003)]
    assert 0 < forces[0] < forces[1], forces


def test_model_without_the_hand_is_refused():
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom type='sphere' size='0.1'/></worldbody></mujoco>")
    with pytest.raises(ValueError, match="physhand_skin"):
        SoftHand(model, mujoco.MjData(model))


def test_unsupported_object_geom_is_refused_with_the_fix():
    spec = mujoco.MjSpec.from_file(str(ph.scene_path("hand_only")))
    hf = spec.add_hfield(name="terrain", size=[0.1, 0.1, 0.01, 0.01], nrow=4, ncol=4)
    hf.userdata = [0.0] * 16
    spec.worldbody.add_geom(name="ground_hf", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="terrain")
    model = spec.compile()
    data = mujoco.MjData(model)
    with pytest.raises(ValueError, match="HFIELD.*object_geoms"):
        SoftHand(model, data, settle_frames=0)
    SoftHand(model, data, settle_frames=0, object_geoms=["floor"])  # filtered out: fine


@pytest.mark.parametrize("kw, want", [
    (dict(object_geoms=["glass", "bal"]), "object_geoms: no geom 'bal' outside the hand; the model's geoms outside "
                                          "the hand: floor, glass"),
    (dict(object_geoms=[999]), "object_geoms: no geom 999 outside the hand"),
    (dict(object_bodies=["glas"]), "object_bodies: no body 'glas' outside the hand; the model's bodies outside the "
                                   "hand: glass, world"),
    (dict(object_groups=[4]), "object_groups: no geom group 4 outside the hand; the model's geom groups outside the "
                              "hand: 0"),
    (dict(object_geoms=["2proxph_r_bone"]), "no geom '2proxph_r_bone' outside the hand"),  # a hand geom is no object
])
def test_object_names_that_match_nothing_are_refused_in_one_line(kw, want):
    """A misspelt object name would turn contact off without a word: it raises, naming what exists."""
    model, data = _scene()
    with pytest.raises(ValueError) as e:
        SoftHand(model, data, ph.Config(device="cpu"), settle_frames=0, **kw)
    assert want in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_a_lone_object_name_is_one_name_not_its_letters():
    model, data = _scene()
    glass = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "glass")
    assert SoftHand(model, data, ph.Config(device="cpu"), settle_frames=0, object_geoms="glass").object_geoms == [glass]


def test_non_finite_pose_is_reported():
    model, data = _scene("hand_only", "open")
    hand = SoftHand(model, data, ph.Config(device="cpu"), settle_frames=0)
    data.qpos[3] = np.nan
    mujoco.mj_kinematics(model, data)
    with pytest.raises(ph.SolverError, match="non-finite"):
        hand.step()


def test_view_without_display_says_so(monkeypatch, capsys):
    from physhand_mj.cli import main

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(ph.scene_path("grasp_glass"))]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "display" in err
    assert main(["view", "missing_scene.xml"]) == 1
    assert "scene file not found" in capsys.readouterr().err


def test_pads_asset_is_built_by_the_same_builder():
    """The shipped Jaco pads asset rebuilds from dm-control's model (build extra): the same skin
    exactly; the cores' remesh (VTK) and TetGen's Steiner points vary a little across library
    versions, so the interior is compared by counts (within 3 %)."""
    from physhand_mj.build.pads import build_pads
    from physhand_mj.robots import PAD_BODIES, PADS_ASSET, jaco_hand_xml

    model = mujoco.MjModel.from_xml_path(str(jaco_hand_xml()))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    fresh = build_pads(model, data, list(PAD_BODIES))
    shipped = ph.load_asset(PADS_ASSET)
    assert fresh.n_skin == shipped.n_skin
    assert np.array_equal(fresh.skin_faces, shipped.skin_faces)
    assert np.allclose(fresh.positions[:fresh.n_skin], shipped.positions[:shipped.n_skin], atol=1e-7)
    assert abs(fresh.n_vertices - shipped.n_vertices) <= 0.03 * shipped.n_vertices
    assert abs(len(fresh.tets) - len(shipped.tets)) <= 0.03 * len(shipped.tets)
    assert list(shipped.body_names) == list(PAD_BODIES)


def test_a_frame_faster_than_the_broadphase_margin_is_reported():
    model, data = _scene()
    hand = SoftHand(model, data, ph.Config(device="cpu"), settle_frames=2)
    mujoco.mj_step(model, data)
    hand.step()
    data.mocap_pos[0] += [0.0, 0.0, 0.02]  # the whole hand jumps 2 cm within one frame
    mujoco.mj_step(model, data)
    with pytest.warns(RuntimeWarning, match="contact_frame_margin"):
        hand.step()


def test_the_proxy_margin_follows_the_coupling_and_touches_only_the_object_proxies():
    """Config.tuning.proxy_margin: None gives hand_mjcf.PROXY_INSET with one-way coupling and 0 (the
    shipped proxies' own) with two_way, so a model follows the last SoftHand made on it; a number is
    used either way; a negative or non-finite one is refused.
    set_proxy_margin writes it into the 16 object proxies (``*_proxy``) only, not their self copies."""
    from physhand_mj.coupling import proxy_margin
    from physhand_mj.hand_mjcf import PROXY_INSET, set_proxy_margin

    assert proxy_margin(ph.Config().validate()) == PROXY_INSET
    assert proxy_margin(ph.Config(two_way=True).validate()) == 0.0
    assert proxy_margin(ph.Config(two_way=True, tuning=ph.Tuning(proxy_margin=1.0e-3)).validate()) == 1.0e-3
    for bad in (-1.0e-3, float("nan"), True, 2.5, "2.5 mm"):
        with pytest.raises(ValueError, match="proxy_margin"):
            ph.Config(tuning=ph.Tuning(proxy_margin=bad)).validate()
    model, _ = _scene()
    bones = ph.body_ids(model, [str(b) for b in ph.load_asset().body_names])
    before = model.geom_margin.copy()
    assert len(set_proxy_margin(model, bones, None)) == 0 and np.array_equal(model.geom_margin, before)
    ids = set_proxy_margin(model, bones, 1.5e-3)
    names = sorted(model.geom(int(g)).name for g in ids)
    assert len(names) == 16 and all(n.endswith("_proxy") for n in names), names
    changed = np.flatnonzero(model.geom_margin != before)
    assert sorted(changed.tolist()) == sorted(ids.tolist()) and np.all(model.geom_margin[ids] == 1.5e-3)
