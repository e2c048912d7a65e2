"""The hand MJCF compiles, its keyframes are within joint ranges, its skin equals the asset's."""

import mujoco
import numpy as np
import pytest

import trimesh

import physhand_mj as ph
from physhand_mj.build.skin import signed_distance


@pytest.fixture(scope="module")
def scene():
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("hand_only")))
    return model, mujoco.MjData(model)


def test_hand_compiles_with_joints_and_actuators():
    model = mujoco.MjModel.from_xml_path(str(ph.HAND_XML))
    assert model.njnt == 23
    assert model.nu == model.njnt, "one position actuator per joint"
    for a in range(model.nu):
        j = model.actuator_trnid[a, 0]
        np.testing.assert_allclose(model.actuator_ctrlrange[a], model.jnt_range[j])


def test_keyframes_within_joint_ranges(scene):
    model, _ = scene
    names = {model.key(k).name for k in range(model.nkey)}
    assert {"open", "power", "pinch"} <= names
    lo, hi = model.jnt_range[:, 0], model.jnt_range[:, 1]
    for k in range(model.nkey):
        q = model.key_qpos[k][model.jnt_qposadr]
        assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9), model.key(k).name
        np.testing.assert_allclose(model.key_ctrl[k], q[model.actuator_trnid[:, 0]])


def test_open_keyframe_is_asset_rest_pose(scene, asset):
    model, data = scene
    mujoco.mj_resetDataKeyframe(model, data, model.key("open").id)
    mujoco.mj_kinematics(model, data)
    mount = model.body("hand_mount").id
    R0, p0 = data.xmat[mount].reshape(3, 3), data.xpos[mount]
    for i, name in enumerate(asset.body_names):
        b = model.body(str(name)).id
        np.testing.assert_allclose(data.xpos[b], R0 @ asset.body_rest_pos[i] + p0, atol=1e-6, err_msg=str(name))


def test_skin_mesh_matches_asset_and_does_not_collide(scene, asset):
    model, data = scene
    mujoco.mj_forward(model, data)
    gid = model.geom("physhand_skin").id
    assert model.geom_contype[gid] == 0 and model.geom_conaffinity[gid] == 0
    mid = model.geom_dataid[gid]
    adr, n = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
    assert n == asset.n_skin
    world = model.mesh_vert[adr:adr + n] @ data.geom_xmat[gid].reshape(3, 3).T + data.geom_xpos[gid]
    np.testing.assert_allclose(world, asset.skin_vertices, atol=1e-5)
    # write-back round trip
    ph.set_skin_vertices(model, data, asset.skin_vertices + 0.01)
    world = model.mesh_vert[adr:adr + n] @ data.geom_xmat[gid].reshape(3, 3).T + data.geom_xpos[gid]
    np.testing.assert_allclose(world, asset.skin_vertices + 0.01, atol=1e-5)
    with pytest.raises(ValueError, match="non-finite"):
        ph.set_skin_vertices(model, data, np.full_like(asset.skin_vertices, np.nan))


def test_collision_proxies_inside_rest_skin(asset):
    _, model, data = ph.open_hand_scene("hand_only", "open", asset=asset)
    skin = trimesh.Trimesh(ph.rest_skin_world(model, data, asset), asset.skin_faces, process=False)
    proxies = [g for g in range(model.ngeom) if model.geom_contype[g] and model.geom_bodyid[g] > 0]
    assert len(proxies) >= 15
    for g in proxies:
        # sample the proxy surface through MuJoCo's own geometry: points along +-axes at size
        c, R, s = data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3), model.geom_size[g]
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE:
            local = [[r * np.cos(t), r * np.sin(t), z] for r in [s[0]] for t in np.linspace(0, 2 * np.pi, 12)
                     for z in (-s[1], 0.0, s[1])] + [[0, 0, s[1] + s[0]], [0, 0, -s[1] - s[0]]]
        else:
            local = [[x, y, z] for x in (-s[0], s[0]) for y in (-s[1], s[1]) for z in (-s[2], s[2])]
        pts = np.asarray(local) @ R.T + c
        depth = -signed_distance(skin, pts)
        assert depth.min() > 0.5e-3, f"{model.geom(g).name} reaches {depth.min() * 1e3:.2f} mm from the skin"
