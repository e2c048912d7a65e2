"""The skin measure's two layouts (physhand_mj/metrics.py): the triangles near an object culled into a
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
from physhand_mj.metrics import penetration_samples
from physhand_mj.solver import Solver, make_model
from physhand_mj.types import Config, GeomType

DEVICES = ["cpu"] + (["cuda"] if wp.is_cuda_available() else [])


def _pressed(device):
    """The open hand at rest with a 2 cm sphere sunk 6 mm into the back of the hand and a 3 cm mesh
    box sunk 4 mm into the palm (no step: the measure sees the deep start as it is)."""
    wp.init()
    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    cfg = Config(device=device)
    objects = Objects(device, 2)
    solver = Solver(make_model(asset, cfg), cfg, objects=objects)
    state = solver.make_state(*mount_pose(model, data))
    skin = state.x.numpy()[: asset.n_skin].astype(float)
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
    m, v = contact.model, contact.world_views()
    out = wp.zeros((1, 6), dtype=float, device=device)
    none = wp.zeros(0, dtype=int, device=device)
    wp.launch(penetration_samples, contact.n_tris,
              [m.skin_faces, state.x, v["gtype"], v["size"], v["inv_pose"], v["radius"], v["mesh"],
               contact.objects.count, v["obj"], -1, 0, order, contact.tris_per_world, 1, none, none], [out],
              device=device)
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
