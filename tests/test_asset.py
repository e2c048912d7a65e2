"""Invariants of the embedded layered hand (paper section 3.1, NIMBLE Table 2 targets)."""

import numpy as np
import pytest
import trimesh

import physhand_mj as ph
from physhand_mj import Layer
from physhand_mj.build import derive
from physhand_mj.build.skin import signed_distance


def test_counts_in_range(asset):
    s = asset.summary()
    assert 4000 <= s["skin_vertices"] <= 6000, s
    assert 3000 <= s["skeleton_vertices"] <= 4000, s
    assert s["flesh_vertices"] > 0 and s["tets"] > 10_000, s
    assert s["bodies"] >= 20, s


def test_skin_is_closed_manifold_outward(asset):
    skin = trimesh.Trimesh(asset.skin_vertices, asset.skin_faces, process=False)
    assert skin.is_watertight and skin.is_winding_consistent
    assert skin.body_count == 1
    assert skin.volume > 0, "skin normals must point outward"
    edge = skin.edges_unique_length * 1e3
    assert 2.0 < edge.mean() < 4.0, f"mean skin edge {edge.mean():.2f} mm, want about 3 mm"


def test_every_tet_positive_and_matches_rest_volume(asset):
    v = derive.tet_signed_volumes(asset.positions, asset.tets)
    assert v.min() > 0, f"min tet volume {v.min():.3e} m^3"
    np.testing.assert_allclose(v, asset.tet_rest_volume, rtol=1e-9)
    # The tets fill exactly the skin minus the bones.
    skin = trimesh.Trimesh(asset.skin_vertices, asset.skin_faces, process=False)
    bones = trimesh.Trimesh(asset.positions, asset.bone_faces, process=False)
    bones.remove_unreferenced_vertices()
    assert v.sum() == pytest.approx(skin.volume - bones.volume, rel=1e-6)


def test_skeleton_vertices_map_to_existing_bodies(asset):
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(ph.HAND_XML))
    names = {model.body(i).name for i in range(model.nbody)}
    skel = asset.layer == Layer.SKELETON
    assert np.all(asset.vertex_body[skel] >= 0)
    used = {str(asset.body_names[i]) for i in np.unique(asset.vertex_body[skel])}
    assert used <= names, used - names
    assert np.all(asset.vertex_body[~skel] == -1)


def test_no_flesh_or_bone_vertex_outside_skin(asset):
    skin = trimesh.Trimesh(asset.skin_vertices, asset.skin_faces, process=False)
    inner = asset.positions[asset.n_skin:]
    depth = -signed_distance(skin, inner)
    assert depth.min() > 0, f"a vertex lies {-depth.min() * 1e3:.3f} mm outside the skin"
    bones = asset.positions[asset.layer == Layer.SKELETON]
    assert (-signed_distance(skin, bones)).min() > 1e-3, "bones must sit at least 1 mm inside the skin"


def test_hand_length_is_adult(asset):
    axis = np.asarray(asset.meta["finger_axis"])
    # wrist crease ~ the wrist joint centre (the hand frame's origin) to the middle fingertip
    length_mm = (asset.skin_vertices @ axis).max() * 1e3
    assert 170 <= length_mm <= 190, length_mm


def test_derived_data_consistent(asset):
    x = asset.positions
    np.testing.assert_allclose(np.linalg.norm(x[asset.edges[:, 0]] - x[asset.edges[:, 1]], axis=1),
                               asset.edge_rest_length, rtol=1e-9)
    # Every skin triangle edge is a tet edge (skin vertices are tet vertices).
    tet_edges = {tuple(e) for e in asset.edges.tolist()}
    f = asset.skin_faces
    skin_edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    assert all(tuple(e) in tet_edges for e in skin_edges.tolist())
    # Attachments: nearest skeleton vertex (Eq. 5), one per movable vertex.
    movable = np.nonzero(asset.layer != Layer.SKELETON)[0]
    assert np.array_equal(np.sort(asset.attach[:, 0]), movable)
    skel = np.nonzero(asset.layer == Layer.SKELETON)[0]
    probe = asset.attach[:: max(1, len(asset.attach) // 50)]
    for v, s in probe:
        d = np.linalg.norm(x[skel] - x[v], axis=1)
        assert np.linalg.norm(x[s] - x[v]) == pytest.approx(d.min())
    # Dihedral pairs: one per interior skin edge of a closed surface (= every edge), rest angles.
    assert len(asset.dihedral) == len(np.unique(skin_edges, axis=0))
    np.testing.assert_allclose(derive.dihedral_angles(x, asset.dihedral), asset.dihedral_rest_angle, atol=1e-9)
    # Masses: total = density x flesh volume.
    assert asset.mass.sum() == pytest.approx(asset.density * asset.tet_rest_volume.sum(), rel=1e-9)


def test_quality_figures_reported(asset):
    assert asset.meta["q_tet_min_dihedral_deg"] > 0.5
    assert asset.meta["q_tet_frac_below_5deg"] < 0.01
    assert asset.meta["q_tet_min_volume_mm3"] > 0
