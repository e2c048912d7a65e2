"""A contact stage's launches merged: the stage's feature list with its first pass's feature push
(features.stage_features_tiled / _scan), and the whole stage in one launch (Config.fused_stage,
contact/stage.py), each against the recorded launches it replaces."""

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.contact import Contact


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
    k = int(c.feat_count.numpy()[0])
    assert k > 100
    nv = m.n_vertices

    def outputs():
        return (wp.zeros(nv, dtype=wp.vec3, device=d), wp.zeros(nv, dtype=float, device=d),
                wp.zeros(nv, dtype=int, device=d), wp.zeros(1, dtype=int, device=d),
                wp.full(nv, -1, dtype=int, device=d))

    wind = c._winding_args()
    fused, alone = outputs(), outputs()
    stage, stage_count = wp.zeros(k, dtype=int, device=d), wp.zeros(1, dtype=int, device=d)
    push = [o.obj, cfg.feature_offset, cfg.contact_margin, o.pose, state.x]
    if kind == "tiled":
        wp.launch(F.stage_features_tiled, (c.points.n_features, 1),
                  [m.skin_faces, state.x, c.cand, c.cand_count, c.feat, c.feat_count, c.points.n_features, c.points.pts, c.points.geom,
                   o.pose, cfg.contact_frame_margin, cfg.contact_margin, c.feature_eps, *wind, *push],
                  [stage, stage_count, *fused], device=d, block_dim=1)
        wp.launch(F.feature_contact_tiled, (c.points.n_features, 1),
                  [m.skin_faces, c.cand, c.cand_count, stage, stage_count, c.points.n_features, c.points.pts, c.points.geom,
                   o.pose, o.obj,
                   cfg.contact_frame_margin, cfg.feature_offset, cfg.contact_margin, c.feature_eps, state.x, o.pose,
                   state.x, *wind], list(alone), device=d, block_dim=1)
    else:
        wp.launch(F.stage_features_scan, c.points.n_features,
                  [m.skin_faces, state.x, c.feat, c.feat_count, c.points.pts, c.points.geom, o.pose,
                   cfg.contact_frame_margin, cfg.contact_margin, c.feature_eps, *wind[1:], *push],
                  [stage, stage_count, *fused], device=d)
        wp.launch(F.feature_contact_scan, c.points.n_features,
                  [m.skin_faces, stage, stage_count, c.points.pts, c.points.geom, o.pose, o.obj,
                   cfg.contact_frame_margin, cfg.feature_offset, cfg.contact_margin, c.feature_eps, state.x, o.pose,
                   state.x, *wind[1:]], list(alone), device=d)
    assert np.array_equal(state.x.numpy(), x0)  # neither moves the skin
    (d0, h0, t0, n0, v0), (d1, h1, t1, n1, v1) = ([a.numpy() for a in out] for out in (fused, alone))
    assert int(stage_count.numpy()[0]) > 20 and int(n0[0]) > 10  # points kept, vertices pushed
    assert int(n0[0]) == int(n1[0]) and set(t0[: n0[0]]) == set(t1[: n1[0]])
    assert np.array_equal(h0, h1) and np.array_equal(d0, d1) and np.array_equal(v0, v1)


@pytest.mark.parametrize("kind, site, extra", [("knife", "fingertip", {}), ("cone_tip", "palm", {}),
                                               ("knife", "fingertip", {"feature_contact": False})])
def test_a_fused_stage_is_the_recorded_stage_bit_for_bit(monkeypatch, kind, site, extra):
    """Config.fused_stage (contact/stage.py: a stage's lists, feature pushes, decision points and
    applies in one launch with barriers between them, the passes a loop) makes the recorded stage's
    decisions: on the CPU (a block is one thread) the skin after 3 frames of a hard case starting
    4 mm deep and every counter of the last frame (lists, touched vertices per pass, passes that ran)
    equal the recorded stage's with the same feature kernels (CUDA's, forced), bit for bit; also
    without the object's features (no feature list: the stage's Eq. 9 alone)."""
    from physhand_mj.bench.cases import press_case, run_case

    init = Contact.__init__

    def tiled_init(self, *args, **kw):
        init(self, *args, **kw)
        self.tiled_features = True

    monkeypatch.setattr(Contact, "__init__", tiled_init)
    asset = ph.load_asset()
    out = {}
    for fused in (False, True):
        r = run_case(press_case(kind, site=site, depth=0.004, start=-0.004),
                     ph.Config(device="cpu", fused_stage=fused, **extra), frames=3, asset=asset)
        c = r["solver"].contact
        assert c.fused == fused
        out[fused] = r["skin"].copy(), c._counters_host.numpy().copy(), r["solver"].last_activity
    (x0, c0, a0), (x1, c1, a1) = out[False], out[True]
    assert c0[0] > 0 and c0[1] > 0 and a0["triangles_tested"] > 0  # the stage had work
    assert np.array_equal(x0, x1) and np.array_equal(c0, c1)
    assert a1["ops_run"] < a0["ops_run"]  # one launch a stage


def test_fused_stage_is_validated():
    with pytest.raises(ValueError, match="fused_stage"):
        ph.Config(fused_stage=1).validate()


def test_a_stuck_grid_barrier_is_raised_not_hidden():
    """A fused stage on CUDA runs a block per SM with grid barriers (stage.grid_sync); a block that
    never arrives makes the others give up and flag it. The frame then raises SolverError naming the
    fix instead of returning a half-done contact (the flag set by hand here: the CPU runs one thread)."""
    from physhand_mj.bench.cases import press_case, run_case

    r = run_case(press_case("knife", site="fingertip", depth=0.004, start=0.002), ph.Config(device="cpu", fused_stage=True),
                 frames=2, asset=ph.load_asset())
    solver, state = r["solver"], r["state"]
    assert solver.step(state)["nonfinite"] == 0  # no flag: frames run
    solver.contact.stage_barrier.assign(np.array([0, 0, 1, 0], np.int32))
    with pytest.raises(ph.SolverError, match="fused_stage=False"):
        solver.step(state)
    assert solver.step(state)["nonfinite"] == 0  # reported once, then cleared
