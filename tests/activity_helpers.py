"""Shared by the activity and sleeping tests: the open hand with a sphere parked far away, on the CPU."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.contact import Objects
from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config, GeomType

R = 0.02  # m, the sphere's radius
FAR = (1.0, 1.0, 1.0)  # m, far from the hand


@pytest.fixture(scope="module")
def scene():
    wp.init()
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    poses = bone_poses_at(model, data, model.key("open").qpos, body_ids(model, asset.body_names))
    return asset, mount_pose(model, data), poses


def _solver(scene, gtype=GeomType.SPHERE, size=(R, 0.0, 0.0), **config):
    asset, mount, poses = scene
    cfg = Config.from_dict({"device": "cpu", **config}).validate()
    objects = Objects(cfg.device, 1)
    objects.add(gtype, size, pos=FAR, name="ball")
    solver = Solver(make_model(asset, cfg), cfg, objects=objects)
    state = solver.make_state(*mount)
    top = state.x.numpy()[: asset.n_skin]
    top = top[np.argmax(top[:, 2])].astype(float)  # the back of the hand (palm down): its highest skin point
    return solver, state, objects, top


def _step(solver, state, poses):
    solver.set_body_poses(state, *poses)
    return solver.step(state)
