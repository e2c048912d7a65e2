"""The generic builder on a small analytic input: a sphere of flesh around two bones."""

import numpy as np
import pytest
import trimesh

pytest.importorskip("tetgen")

from physhand_mj import Layer  # noqa: E402
from physhand_mj.asset import validate_asset  # noqa: E402
from physhand_mj.build import BuildError, build_from_meshes  # noqa: E402


def _bones():
    a = trimesh.creation.capsule(height=0.03, radius=0.004, count=[16, 16])
    b = a.copy()
    a.apply_translation([-0.012, 0, 0])
    b.apply_translation([0.012, 0, 0])
    return {"bone_a": a, "bone_b": b}


def _pose():
    return {"bone_a": (np.zeros(3), np.array([1.0, 0, 0, 0])), "bone_b": (np.zeros(3), np.array([1.0, 0, 0, 0]))}


def test_build_from_meshes_soft_pad():
    skin = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    asset = build_from_meshes(skin, _bones(), _pose(), skeleton_vertices=400)
    validate_asset(asset)
    assert asset.n_skin == len(skin.vertices)
    np.testing.assert_allclose(asset.skin_vertices, skin.vertices)
    bones = trimesh.util.concatenate(list(_bones().values()))
    # flesh volume = sphere - bones, within the bones' remeshing error
    assert asset.tet_rest_volume.sum() == pytest.approx(skin.volume - bones.volume, rel=0.02)
    assert set(np.unique(asset.vertex_body[asset.layer == Layer.SKELETON])) == {0, 1}


def test_bone_outside_skin_is_a_clear_error():
    skin = trimesh.creation.icosphere(subdivisions=3, radius=0.012)
    with pytest.raises(BuildError, match="skin"):
        build_from_meshes(skin, _bones(), _pose(), skeleton_vertices=400)


def test_missing_pose_is_a_clear_error():
    skin = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    with pytest.raises(BuildError, match="rest pose"):
        build_from_meshes(skin, _bones(), {}, skeleton_vertices=400)


def test_cli_builds_from_user_meshes(tmp_path):
    from physhand_mj import cli, load_asset

    bones_dir = tmp_path / "bones"
    bones_dir.mkdir()
    for name, mesh in _bones().items():
        mesh.export(bones_dir / f"{name}.stl")
    trimesh.creation.icosphere(subdivisions=3, radius=0.03).export(tmp_path / "pad.obj")
    (tmp_path / "pad.xml").write_text(
        '<mujoco><worldbody><body name="bone_a"><geom size="0.01"/></body>'
        '<body name="bone_b"><geom size="0.01"/></body></worldbody></mujoco>')
    out = tmp_path / "pad.npz"
    rc = cli.main(["build-hand", "--skin", str(tmp_path / "pad.obj"), "--bones", str(bones_dir),
                   "--model", str(tmp_path / "pad.xml"), "--out", str(out), "--skeleton-vertices", "400"])
    assert rc == 0
    asset = load_asset(out)
    assert set(asset.body_names.tolist()) == {"bone_a", "bone_b"}
    # a bone file naming no body is a one-line error
    (bones_dir / "nobody.stl").write_bytes((bones_dir / "bone_a.stl").read_bytes())
    assert cli.main(["build-hand", "--skin", str(tmp_path / "pad.obj"), "--bones", str(bones_dir),
                     "--model", str(tmp_path / "pad.xml"), "--out", str(out)]) == 1
