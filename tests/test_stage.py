"""A contact stage's launches merged: the stage's feature list with its first pass's feature push
(features.stage_features_tiled / _scan), against the recorded launches it replaces."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph


@pytest.mark.parametrize("kind", ["tiled", "scan"])
def test_the_stage_feature_list_pushes_as_the_first_pass_would(kind):
    """CUDA's stage-feature kernels (stage_features_tiled: a block per feature, one hand;
    stage_features_scan: a thread per feature, batches) list a stage's features and, on the same
    skin, give its first pass's feature push in the same launch (one closest-point query per feature
    instead of two): run on the CPU (a block is one thread) for the knife 1.5 mm deeper in the palm
    than the contact left it, the push equals the pass kernel's (feature_contact_tiled / _scan) over
    the list it made (the per-vertex mean and weights, the touched vertices), and the list holds
    every point that pass pushes."""
    from physhand_mj.bench.cases import press_case, run_case, site_point
    from physhand_mj.contact import features as F
    from physhand_mj.contact.query import push_sums

    asset = ph.load_asset()
    r = run_case(press_case("knife", site="palm", depth=0.004, start=-0.004), ph.Config(device="cpu"), frames=2,
                 asset=asset)
    c, state, o = r["solver"].contact, r["state"], r["objects"]
    m, cfg, d = c.model, c.config, "cpu"
    _, n = site_point(asset, "palm")
    o.set_poses((r["object_pos"] - 0.0015 * n)[None], r["object_quat"][None])
    x0 = state.x.numpy().copy()
    c.run_stage(state)  # the frame's triangle and feature lists (and the features' patches) for this pose
    state.x.assign(x0)
    k = int(c.features.count.numpy()[0])
    assert k > 100
    nv = m.n_vertices

    def outputs():
        return (wp.zeros(nv, dtype=wp.vec3, device=d), wp.zeros(nv, dtype=float, device=d),
                wp.zeros(nv, dtype=int, device=d), wp.zeros(1, dtype=int, device=d),
                wp.full(nv, -1, dtype=int, device=d))

    wind = c._winding_args()
    fused, alone = outputs(), outputs()
    stage, stage_count = wp.zeros(k, dtype=int, device=d), wp.zeros(1, dtype=int, device=d)

    def inputs(cand, cand_count, push, out=None, out_count=None):
        return F.feature_inputs(m.skin_faces, state.x, cand, cand_count, c.points.pts, c.points.geom, c.points.normal, o.pose,
                                cfg.contact_frame_margin, tris=c.lists.cand, tri_count=c.cand_count,
                                stride=c.points.n_features, geom_obj=o.obj, keep=cfg.contact_margin,
                                eps=c.feature_eps, offset=cfg.feature_offset, max_step=cfg.contact_margin, pose0=o.pose,
                                x0=state.x, winding=wind, out=out, out_count=out_count,
                                push=(push_sums(*push[:3], push[4]), push[3]))

    dim, kw = ((c.points.n_features, 1), dict(block_dim=1)) if kind == "tiled" else (c.points.n_features, {})
    wp.launch(F.feature_kernel(kind, True), dim, inputs(c.features.listed, c.features.count, fused, stage, stage_count), device=d,
              **kw)
    wp.launch(F.feature_kernel(kind, False), dim, inputs(stage, stage_count, alone), device=d, **kw)
    assert np.array_equal(state.x.numpy(), x0)  # neither moves the skin
    (d0, h0, t0, n0, v0), (d1, h1, t1, n1, v1) = ([a.numpy() for a in out] for out in (fused, alone))
    assert int(stage_count.numpy()[0]) > 20 and int(n0[0]) > 10  # points kept, vertices pushed
    assert int(n0[0]) == int(n1[0]) and set(t0[: n0[0]]) == set(t1[: n1[0]])
    assert np.array_equal(h0, h1) and np.array_equal(d0, d1) and np.array_equal(v0, v1)
