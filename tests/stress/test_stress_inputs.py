"""Bad user inputs end in one line that says what to fix, never a crash (issue 14). Complements
tests/test_asset_errors.py (files, arrays), tests/test_contact.py (object errors), tests/test_solver.py
and tests/test_coupling.py (NaN bone poses and qpos, unsupported MuJoCo geoms)."""

import dataclasses

import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.asset import validate_asset
from physhand_mj.contact import Objects
from physhand_mj.types import GeomType

TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * 0.01
TET_SKIN = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]


def _one_line(excinfo, *words):
    msg = str(excinfo.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, (w, msg)


@pytest.mark.parametrize("label, kwargs, words", [
    ("degenerate tet", dict(positions=TET * [1, 1, 0], tets=[[0, 1, 2, 3]]), ("non-positive rest volume", "drop")),
    ("zero-area skin triangle", dict(positions=np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 1]]) * 0.01,
                                     skin_faces=[[0, 1, 2], [0, 1, 3]], vertex_mass=1e-3), ("zero area", "remove")),
    ("non-manifold skin", dict(positions=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]]) * 0.01,
                               skin_faces=[[0, 1, 2], [1, 0, 3], [0, 1, 4]], vertex_mass=1e-3),
     ("non-manifold", "split")),
    ("open skin around tets", dict(positions=TET, tets=[[0, 1, 2, 3]], skin_faces=TET_SKIN[:2]), ("closed", "holes")),
])
def test_bad_user_body_is_refused_in_one_line(label, kwargs, words):
    x = kwargs.pop("positions")
    with pytest.raises(ph.AssetError) as e:
        ph.soft_body(x, **kwargs)
    _one_line(e, *words)


def test_inverted_tet_in_a_saved_asset_is_refused(asset):
    bad = dataclasses.replace(asset, tets=asset.tets.copy(), tet_rest_volume=asset.tet_rest_volume.copy())
    bad.tets[7] = bad.tets[7][[1, 0, 2, 3]]
    bad.tet_rest_volume[7] *= -1
    with pytest.raises(ph.AssetError) as e:
        validate_asset(bad)
    _one_line(e, "non-positive rest volume", "first [7]")


def test_a_closed_tet_body_passes():
    body = ph.soft_body(TET, tets=[[0, 1, 2, 3]], skin_faces=TET_SKIN)
    assert len(body.tets) == 1


@pytest.mark.parametrize("gtype, size", [(GeomType.SPHERE, [0.0]), (GeomType.BOX, [0.01, 0.0, 0.01]),
                                         (GeomType.CAPSULE, [0.0, 0.01]), (GeomType.CYLINDER, [0.01, 0.0]),
                                         (GeomType.ELLIPSOID, [0.01, 0.01, 0.0]), (GeomType.CONE, [0.01, 0.0]),
                                         (GeomType.SPHERE, [np.nan])])
def test_zero_size_geom_is_refused(gtype, size):
    with pytest.raises(ValueError) as e:
        Objects("cpu", 1).add(gtype, size, name="g")
    _one_line(e, "geom 'g'", "positive", gtype.name)


def test_unsupported_geom_type_is_refused():
    with pytest.raises(ValueError) as e:
        Objects("cpu", 1).add(42, [0.01], name="g")
    _one_line(e, "unsupported geom type 42", "SPHERE")


def test_nan_pose_and_qpos_are_refused(scene):
    cfg = ph.Config(device="cpu")
    solver = ph.Solver(ph.make_model(scene.asset, cfg), cfg)
    state = solver.make_state(*scene.mount)
    q = scene.open.copy()
    q[5] = np.nan
    with pytest.raises(ValueError) as e:
        scene.bones(q)
    _one_line(e, "finite")
    pos, quat = scene.bones(scene.open)
    pos[4, 2] = np.inf
    with pytest.raises(ph.SolverError) as e:
        solver.set_body_poses(state, pos, quat)
    _one_line(e, "non-finite", str(scene.asset.body_names[4]), "qpos")
    objs = Objects("cpu", 1)
    objs.add(GeomType.SPHERE, [0.01], name="ball")
    with pytest.raises(ValueError) as e:
        objs.set_poses(np.array([[np.nan, 0, 0]]), np.array([[1.0, 0, 0, 0]]))
    _one_line(e, "ball", "non-finite")
