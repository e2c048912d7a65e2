"""physhand_mj.add_skin: the soft skin on scenes built with MjSpec from parts (both MyoHand namings,
a prefix, a name map), each error case, and SoftHand's compiled-model path (no skin in the model)."""

import mujoco
import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.attach import _OLD, TOL_MM, draw_skin
from physhand_mj.contact.bones import HOLD_DEPTH, KEPT_OUT_DEPTH
from physhand_mj.hand_mjcf import PROXY_SUFFIX


def hand_part(naming="asset"):
    """mjcf/hand/myohand.xml without its skin, bones renamed to ``naming`` ("asset" / "myosuite_old")."""
    hand = mujoco.MjSpec.from_file(str(ph.HAND_XML))
    hand.delete(hand.geom("physhand_skin"))
    hand.delete(hand.mesh("physhand_skin"))
    if naming == "myosuite_old":
        for new_name, old_name in _OLD.items():
            hand.body(new_name).name = old_name
    return hand


def scene(*hands):
    """A floor, a ball under the palm, and each (hand spec, prefix) attached in a frame of its own."""
    s = mujoco.MjSpec()
    s.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.5, 0.5, 0.01])
    ball = s.worldbody.add_body(name="ball", pos=[0.0, 0.0, 0.15])
    ball.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.02, 0, 0], contype=0, conaffinity=0)
    for k, (hand, prefix) in enumerate(hands):
        s.attach(hand, prefix=prefix, frame=s.worldbody.add_frame(pos=[0.3 * k, 0, 0]))
    return s


@pytest.mark.parametrize("scheme,naming", [("asset", "auto"), ("myosuite_old", "myosuite_old"),
                                           ("myosuite_old", "auto"), ("asset", "h_")])
def test_skin_on_a_scene_from_parts_follows_its_bones(asset, scheme, naming):
    spec = scene((hand_part(scheme), "h_"))
    kw = {} if naming in ("auto", "h_") else {"prefix": "h_"}
    att = ph.add_skin(spec, naming, asset, **kw)
    assert att.naming.scheme == scheme and att.naming.prefix == "h_" and att.geom == "h_physhand_skin"
    assert att.offset_mm < 0.01 and att.offset_deg < 0.01, att  # the same MyoHand bones: exact after the fit
    model = spec.compile()
    g = model.geom(att.geom)
    assert g.contype == 0 and g.conaffinity == 0 and model.geom_bodyid[g.id] == 0  # non-colliding, world frame
    data = mujoco.MjData(model)
    for name, q in zip(asset.rest_qpos_names, asset.rest_qpos):  # the asset's rest pose (fingers spread)
        j = model.joint("h_" + str(name))
        data.qpos[j.qposadr[0]] = q
        data.ctrl[_actuator_of(model, j.id)] = q
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device="cpu"), naming=att.naming, object_geoms=["ball"],
                       settle_frames=2)
    assert [model.body(b).name for b in hand.bones[:3]] == list(att.naming.bones[:3])
    for _ in range(2):
        mujoco.mj_step(model, data)
        hand.step()
    # the skin written into the mesh is the solver's skin, and it sits on the bones (rest pose, 2 frames)
    mid = model.geom_dataid[g.id]
    adr, n = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
    world = model.mesh_vert[adr: adr + n] @ data.geom_xmat[g.id].reshape(3, 3).T + data.geom_xpos[g.id]
    assert np.abs(world - hand.skin_vertices).max() < 1e-5
    b0 = model.body(att.naming.bones[0]).id
    rest = (asset.skin_vertices - asset.body_rest_pos[0]) @ _rot(data, b0, asset).T + data.xpos[b0]
    dev = np.linalg.norm(hand.skin_vertices - rest, axis=1)
    assert np.median(dev) < 5e-4 and dev.max() < 3e-3, (np.median(dev), dev.max())


def test_the_hold_starts_at_2_mm_where_no_proxy_keeps_the_bones_out(asset):
    """The bones' hold (contact/bones.py hold_depth): from 0.5 mm where the hand's object proxies get
    the one-way margin (MuJoCo keeps the bones out), from 2 mm on a model without them (as MyoSuite's),
    where MuJoCo lets a closing bone a little way in."""
    for keep in (True, False):
        spec = scene((hand_part(), "h_"))
        att = ph.add_skin(spec, "auto", asset)
        if not keep:
            for g in [g for g in spec.geoms if g.name.endswith(PROXY_SUFFIX)]:
                spec.delete(g)
        model = spec.compile()
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        hand = ph.SoftHand(model, data, ph.Config(device="cpu"), naming=att.naming, object_geoms=["ball"],
                           settle_frames=0)
        want = KEPT_OUT_DEPTH if keep else float(HOLD_DEPTH)
        assert len(hand.proxies) == (16 if keep else 0)
        assert hand.solver.contact.hold_depth == want
        assert hand.solver.contact.bone_hold.depth.numpy()[0] == pytest.approx(want)


def _actuator_of(model, joint: int) -> int:
    return int(np.flatnonzero((model.actuator_trnid[:, 0] == joint)
                              & (model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT))[0])


def _rot(data, b0, asset):
    from physhand_mj.rotations import quat_to_mat

    return data.xmat[b0].reshape(3, 3) @ quat_to_mat(np.asarray(asset.body_rest_quat[0], float)).T


def test_name_map(asset):
    hand = hand_part()
    hand.body("distph2_r").name = "index_tip"
    hand.body("midph2_r").name = "index_middle"
    spec = scene((hand, "h_"))
    with pytest.raises(ValueError, match=r"lacks the hand's bone bodies \['h_midph2_r', 'h_distph2_r'\]"):
        ph.add_skin(spec, "asset", asset, prefix="h_")
    att = ph.add_skin(spec, {"distph2_r": "h_index_tip", "midph2_r": "h_index_middle",
                             **{str(b): "h_" + str(b) for b in asset.body_names
                                if str(b) not in ("distph2_r", "midph2_r")}}, asset)
    assert att.naming.scheme == "map" and "h_index_tip" in att.naming.bones and att.geom == "physhand_skin"
    with pytest.raises(ValueError, match="ambiguous name map: bodies \\['h_index_tip'\\]"):
        ph.add_skin(scene((hand_part(), "h_")), {"distph2_r": "h_index_tip", "midph2_r": "h_index_tip"}, asset)


def test_missing_bones_are_listed(asset):
    hand = hand_part("myosuite_old")
    hand.body("distph3").name = "tip3"
    with pytest.raises(ValueError, match=r"lacks the hand's bone bodies \['h_distph3'\].*closest naming: 'myosuite_old'"):
        ph.add_skin(scene((hand, "h_")), "auto", asset)
    empty = mujoco.MjSpec()
    empty.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.1, 0, 0])
    with pytest.raises(ValueError, match="lacks the hand's bone bodies"):
        ph.add_skin(empty, "asset", asset)


def test_two_hands_are_ambiguous_until_named(asset):
    spec = scene((hand_part(), "left_"), (hand_part("myosuite_old"), "right_"))
    with pytest.raises(ValueError, match="ambiguous bones.*asset with prefix 'left_'.*myosuite_old with prefix 'right_'"):
        ph.add_skin(spec, "auto", asset)
    left = ph.add_skin(spec, "left_", asset)
    right = ph.add_skin(spec, "myosuite_old", asset, prefix="right_")
    model = spec.compile()
    assert model.geom(left.geom).id != model.geom(right.geom).id
    with pytest.raises(ValueError, match="already has the skin \\('left_physhand_skin'\\)"):
        ph.add_skin(spec, "left_", asset)


def test_skin_added_twice_is_refused(asset):
    spec = mujoco.MjSpec.from_file(str(ph.scene_path("hand_only")))  # includes myohand.xml: skin present
    with pytest.raises(ValueError, match="already has the skin \\('physhand_skin'\\): add_skin once per hand"):
        ph.add_skin(spec, "asset", asset)


def test_bone_frames_off_the_asset_are_measured(asset):
    hand = hand_part()
    mid = hand.body("midph3_r")
    mid.pos = np.asarray(mid.pos) + [0.0, -0.003, 0.0]  # a middle phalanx 3 mm longer than the asset's
    with pytest.raises(ValueError, match=r"bone 'h_(midph3|distph3)_r' is 2\.[5-9]\d mm off.*tolerance 0.5 mm / 0.5 deg"):
        ph.add_skin(scene((hand, "h_")), "auto", asset)
    hand = hand_part()
    tip = hand.body("distph4_r")
    tip.quat = [np.cos(0.02), 0.0, 0.0, np.sin(0.02)]  # 2.3 degrees about z: the DIP hinge takes a part, 1.7 deg stay
    with pytest.raises(ValueError, match=r"'h_distph4_r' [12]\.\d\d deg off"):
        ph.add_skin(scene((hand, "h_")), "auto", asset)
    hand = hand_part()
    mid = hand.body("midph3_r")
    mid.pos = np.asarray(mid.pos) + [0.0, -0.0002, 0.0]  # 0.2 mm: inside the tolerance, measured
    att = ph.add_skin(scene((hand, "h_")), "auto", asset)
    assert 0.15 < att.offset_mm < TOL_MM and att.fitted, att


def test_compiled_model_path_leaves_the_model_alone(asset):
    model = scene((hand_part(), "h_")).compile()  # compiled without the skin: no spec at hand
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with pytest.raises(ValueError, match="has no geom 'h_physhand_skin'"):
        ph.SoftHand(model, data, naming="auto", settle_frames=0)
    before = model.mesh_vert.copy()
    hand = ph.SoftHand(model, data, ph.Config(device="cpu"), naming="auto", writeback=False, object_geoms=["ball"],
                       settle_frames=2)
    mujoco.mj_step(model, data)
    hand.step()
    assert np.array_equal(model.mesh_vert, before) and hand.skin_mesh_id == -1
    assert hand.skin_vertices.shape == (asset.n_skin, 3) and hand.metrics()["finite"]
    scn = mujoco.MjvScene(model, maxgeom=model.ngeom + len(asset.skin_faces) + 100)
    mujoco.mjv_updateScene(model, data, mujoco.MjvOption(), None, mujoco.MjvCamera(), mujoco.mjtCatBit.mjCAT_ALL, scn)
    n0 = scn.ngeom
    assert hand.draw(scn) == len(asset.skin_faces) and scn.ngeom == n0 + len(asset.skin_faces)
    f = asset.skin_faces[7]
    g = scn.geoms[n0 + 7]
    corner = g.pos + g.mat @ np.array([1.0, 0.0, 0.0])  # the triangle's (size[0], 0, 0) corner = vertex 1
    assert g.type == mujoco.mjtGeom.mjGEOM_TRIANGLE and np.allclose(g.pos, hand.skin_vertices[f[0]], atol=1e-6)
    assert np.allclose(corner, hand.skin_vertices[f[1]], atol=1e-6)
    with pytest.raises(ValueError, match="max_geom >="):
        draw_skin(mujoco.MjvScene(model, maxgeom=10), hand.skin_vertices, asset.skin_faces)


def test_self_proxies_are_copied_onto_a_model_without_them(asset):
    """A hand built elsewhere (here the hand MJCF without its self proxies, with MyoSuite's older bone
    names): add_skin copies the self proxies onto its bones, where the hand MJCF has its own (the same
    world poses and shapes at the same joint angles), inert; SoftHand with self-collision turns them
    on. A model that has them gets no second set."""
    from physhand_mj.hand_mjcf import SELF_PROXY_BIT, SELF_PROXY_SUFFIX

    bare = hand_part("myosuite_old")
    for g in [g for g in bare.geoms if g.name.endswith(SELF_PROXY_SUFFIX)]:
        bare.delete(g)
    spec = scene((bare, "h_"))
    att = ph.add_skin(spec, "myosuite_old", asset, prefix="h_")
    assert len(att.self_proxies) == 16 and all(n.startswith("h_") for n in att.self_proxies)
    ref_spec = scene((hand_part("myosuite_old"), "h_"))
    assert ph.add_skin(ref_spec, "myosuite_old", asset, prefix="h_").self_proxies == ()
    model, ref = spec.compile(), ref_spec.compile()
    data, ref_data = mujoco.MjData(model), mujoco.MjData(ref)
    key = np.random.default_rng(0).uniform(0.0, 0.5, model.nq)  # the same joint angles in both
    data.qpos[:], ref_data.qpos[:] = key, key
    mujoco.mj_forward(model, data)
    mujoco.mj_forward(ref, ref_data)
    for name in att.self_proxies:
        g, r = model.geom(name), ref.geom(name)
        np.testing.assert_allclose(data.geom_xpos[g.id], ref_data.geom_xpos[r.id], atol=1e-9)
        np.testing.assert_allclose(data.geom_xmat[g.id], ref_data.geom_xmat[r.id], atol=1e-9)
        np.testing.assert_array_equal(g.size, r.size)
        assert g.type == r.type and g.margin == r.margin
        assert g.contype == SELF_PROXY_BIT and g.conaffinity == 0
    hand = ph.SoftHand(model, data, ph.Config(device="cpu", self_collision=True), naming=att.naming, settle_frames=0)
    assert sorted(model.geom(int(g)).name for g in hand.self_proxies) == sorted(att.self_proxies)
