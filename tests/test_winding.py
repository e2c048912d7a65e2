"""The object side's inside test (physhand_mj/contact/winding.py): solid angles against analytic
winding numbers, and the local winding number against the full one where Warp's pseudo normals
are wrong (the demo's squeezed skin), on the CPU and CUDA, with CUDA's patches against the BVH's."""

import warnings

import numpy as np
import pytest
import trimesh
import warp as wp

import physhand_mj as ph
from physhand_mj.contact.closest import FOUR_PI, solid_angle
from physhand_mj.contact.features import FEATURE_LANES
from physhand_mj.contact.inside import INSIDE_RANGE, inside_depth, object_point
from physhand_mj.contact.winding import Patches, closest_tiled, frame_winding, patches_of, winding_sign


@wp.kernel
def _solid_angles(p: wp.array(dtype=wp.vec3), x: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=int),
                  out: wp.array(dtype=float)):
    i = wp.tid()
    s = float(0.0)
    for t in range(faces.shape[0]):
        s += solid_angle(x[faces[t, 0]] - p[i], x[faces[t, 1]] - p[i], x[faces[t, 2]] - p[i])
    out[i] = s


def test_solid_angles_sum_to_the_winding_number():
    """features.solid_angle summed over a closed, outward-wound mesh is 4 pi inside and 0 outside (a
    sphere; a point 0.5 mm outside it too), and -4 pi inside the same mesh wound inward."""
    m = trimesh.creation.icosphere(2, radius=0.01)
    pts = np.array([[0, 0, 0], [0.004, -0.003, 0.002], [0.02, 0, 0], [0, 0.0105, 0]], np.float32)
    out = {}
    for name, faces in (("out", m.faces), ("in", m.faces[:, ::-1])):
        o = wp.zeros(len(pts), dtype=float, device="cpu")
        wp.launch(_solid_angles, len(pts), [wp.array(pts, dtype=wp.vec3, device="cpu"),
                                            wp.array(m.vertices.astype(np.float32), dtype=wp.vec3, device="cpu"),
                                            wp.array(np.ascontiguousarray(faces, np.int32), dtype=int, device="cpu")],
                  [o], device="cpu")
        out[name] = o.numpy() / FOUR_PI
    np.testing.assert_allclose(out["out"], [1, 1, 0, 0], atol=1e-5)
    np.testing.assert_allclose(out["in"], [-1, -1, 0, 0], atol=1e-5)


@wp.kernel
def _feature_sides(skin: wp.uint64, feat: wp.array(dtype=int), pts: wp.array(dtype=wp.vec3),
                   pts_geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform), far: float,
                   faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), patches: Patches,
                   out: wp.array2d(dtype=float)):
    k = wp.tid()
    i = feat[k]
    p = object_point(i, pts, pts_geom, pose)
    q = wp.mesh_query_point_sign_normal(skin, p, far)
    out[k, 0] = 0.0
    if q.result:
        out[k, 0] = q.sign
        out[k, 2] = wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v))
    out[k, 1] = winding_sign(p, i, faces, x, patches, 0.0)


@wp.kernel
def _feature_sides_tiled(tris: wp.array(dtype=int), tri_count: wp.array(dtype=int), feat: wp.array(dtype=int),
                         pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int),
                         pose: wp.array(dtype=wp.transform), far: float, eps: float, faces: wp.array2d(dtype=int),
                         x: wp.array(dtype=wp.vec3), patches: Patches, out: wp.array(dtype=float)):
    k, lane = wp.tid()
    i = feat[k]
    p = object_point(i, pts, pts_geom, pose)
    found, f, u, v, sign = closest_tiled(p, i, lane, faces, x, tris, tri_count, far, eps, 1, patches)
    if lane == 0:
        out[k] = 0.0
        if found:
            out[k] = sign


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not wp.is_cuda_available(), reason="no CUDA device"))])
def test_local_winding_number_is_right_where_the_pseudo_normals_are_wrong(device):
    """The feature push's inside test (Config.tuning.feature_winding, features.py: the solid angles of the
    skin triangles within contact_frame_margin of a feature point, summed on the skin as it is now,
    plus the rest's from the frame's start) against the full generalised winding number (every skin
    triangle's solid angle, numpy): the same side for every listed feature point at the end of each
    frame of the demo's approach with its old closing targets (the farthest the skin has moved since the far part was taken),
    where Warp's pseudo normals take outside points in front of turned-over skin triangles as inside
    (they do here: the case is the one docs/contact.md measures). Both the CPU's sum (winding_sign)
    and the block-per-feature kernels' (closest_tiled: CUDA's, FEATURE_LANES lanes there)."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    # the demo's closing targets before 2026-11-25, past the glass (0.75 of the way to the power
    # grasp from the open hand): the fingers squeeze the skin against the glass and turn skin
    # triangles over (the demo's targets now stop at the glass: build.scenes.GRASP_CLOSE)
    hand_only = mujoco.MjModel.from_xml_path(str(ph.scene_path("hand_only")))
    data.ctrl[:] = 0.75 * hand_only.key("power").ctrl + 0.25 * hand_only.key("open").ctrl
    mujoco.mj_forward(model, data)
    # the lists and patches at the frame margin (feature_slack = contact_frame_margin): the old targets
    # move skin 12 mm in a frame, past the slack's lists (reported as feature_slack_exceeded; an H200
    # then gave one listed point of ~100 a patch short of a triangle); the sign is this test's subject
    # (those targets drive fingertip bones more than 2 mm into the glass; the contact must still press
    # that skin onto them to turn triangles over, so the bones' hold, contact/bones.py, is off here)
    hand = ph.SoftHand(model, data, ph.Config(device=device, tuning=ph.Tuning(feature_slack=0.01, bone_hold=False)))
    c, state = hand.solver.contact, hand.state
    lanes = FEATURE_LANES if device == "cuda" else 1
    faces = c.model.skin_faces.numpy()
    pts = c.points
    checked = pseudo_wrong = tiled_checked = 0
    for frame in range(12):
        mujoco.mj_step(model, data)
        hand.step()
        if frame < 6:
            continue
        n = int(c.features.count.numpy()[0])
        assert n > 20
        skin = c.volume(state, winding=False).mesh
        skin.refit()
        out = wp.zeros((n, 3), dtype=float, device=device)
        wp.launch(_feature_sides, n, [skin.id, c.features.listed, pts.pts, pts.geom, c.objects.pose, c.config.contact_frame_margin,
                                      c.model.skin_faces, state.x, c.features.patches], [out], device=device)
        o = out.numpy().astype(float)
        tiled = wp.zeros(n, dtype=float, device=device)
        wp.launch(_feature_sides_tiled, (n, lanes), [c.lists.cand, c.cand_count, c.features.listed, pts.pts, pts.geom, c.objects.pose,
                                                     c.config.contact_frame_margin, c.feature_eps, c.model.skin_faces,
                                                     state.x, c.features.patches], [tiled], device=device, block_dim=lanes)
        assert np.all(c.features.patch_len.numpy()[:n] > 0)  # every patch fit the pool
        # the full winding number, every skin triangle, in float64
        world, _ = _object_points_world(c, c.features.listed.numpy()[:n])
        x = state.x.numpy().astype(float)[faces]
        full = np.array([_solid_angle_sum(x - p) for p in world]) / FOUR_PI
        assert np.all(np.abs(full - np.round(full)) < 1e-3)  # off the surface: an integer
        truth = np.where(full > 0.5, -1.0, 1.0)
        near = (o[:, 0] != 0) & (o[:, 2] < 2e-3)  # within 2 mm of the skin
        assert np.array_equal(o[:, 1], truth), np.flatnonzero(o[:, 1] != truth)
        # (the block scan finds no patch triangle within contact_frame_margin of a point the skin moved
        # away from in the frame: far from any push either way)
        ts = tiled.numpy()
        assert np.array_equal(ts[ts != 0], truth[ts != 0]), np.flatnonzero((ts != 0) & (ts != truth))
        lost = ts == 0
        assert np.all((o[lost, 0] == 0) | (o[lost, 2] > 0.5 * c.config.contact_frame_margin)), o[lost]
        tiled_checked += int((ts != 0).sum())
        checked += int(near.sum())
        pseudo_wrong += int((near & (o[:, 0] != truth)).sum())
    assert checked > 100 and pseudo_wrong > 0 and tiled_checked > 100, (checked, pseudo_wrong, tiled_checked)
    if device == "cpu":  # CUDA's patches (feature_patches_tiled, a block over every skin triangle) against the BVH's
        from physhand_mj.contact.patches_tiled import feature_patches_tiled

        n = int(c.features.count.numpy()[0])
        x_start = state.x.numpy().copy()
        c.run_stage(state)  # the frame's lists and patches for this skin (BVH + winding number)
        state.x.assign(x_start)
        n = int(c.features.count.numpy()[0])
        used, pool = wp.zeros(1, dtype=int, device="cpu"), wp.zeros_like(c.features.patch_pool)
        slot, start, length = (wp.zeros_like(a) for a in (c.features.slot, c.features.patch_start, c.features.patch_len))
        fill, far = wp.zeros_like(c.features.patch_len), wp.zeros_like(c.features.far_angle)
        wp.launch(feature_patches_tiled, (n, 1), [c.model.skin_faces, state.x, c.features.listed, c.features.count, n, pts.pts, pts.geom,
                                                  c.objects.pose, c.config.contact_frame_margin, c.slack_check.data.feat_dist, c.slack_check.data.slack,
                                                  c.tris_per_world, c.geoms_per_world],
                  [used, patches_of(slot, pool, start, length, far), fill], device="cpu", block_dim=1)
        assert np.array_equal(length.numpy()[:n], c.features.patch_len.numpy()[:n])
        p0, p1, s0, s1 = c.features.patch_pool.numpy(), pool.numpy(), c.features.patch_start.numpy(), start.numpy()
        for k in range(n):
            ln = c.features.patch_len.numpy()[k]
            assert np.array_equal(np.sort(p0[s0[k]: s0[k] + ln]), np.sort(p1[s1[k]: s1[k] + ln]))
        # the far part's own solid angle against 4 pi w_0 minus the patch's (w_0 an integer)
        np.testing.assert_allclose(far.numpy()[:n], c.features.far_angle.numpy()[:n], atol=2e-3)


def _solid_angle_sum(tri):
    """Sum of the solid angles of triangles ``tri`` (k, 3, 3), vertices relative to the point."""
    a, b, d = tri[:, 0], tri[:, 1], tri[:, 2]
    la, lb, ld = (np.linalg.norm(v, axis=1) for v in (a, b, d))
    num = np.einsum("ij,ij->i", a, np.cross(b, d))
    den = la * lb * ld + np.einsum("ij,ij->i", a, b) * ld + np.einsum("ij,ij->i", b, d) * la + \
        np.einsum("ij,ij->i", d, a) * lb
    return float((2.0 * np.arctan2(num, den)).sum())


def _object_points_world(c, idx):
    """World positions (k, 3) of the contact's object points ``idx`` and their geoms."""
    from physhand_mj.rotations import quat_to_mat

    pts = c.points
    pose = c.objects._host["pose"][pts.geom_host[idx]].astype(float)
    rot = quat_to_mat(np.concatenate([pose[:, 6:], pose[:, 3:6]], axis=1)).reshape(-1, 3, 3)
    return np.einsum("kij,kj->ki", rot, pts.pts_host[idx].astype(float)) + pose[:, :3], pts.geom_host[idx]


@wp.kernel
def _inside_two_ways(skin: wp.uint64, p: wp.array(dtype=wp.vec3), lo: wp.vec3, hi: wp.vec3, margin: float,
                     out: wp.array2d(dtype=float)):
    """inside_depth and frame_winding (given the point's distance to the skin; a coarse winding number,
    asked again where it lies far from an integer) beside Warp's sign queries that each ran both (the
    code they replaced)."""
    i = wp.tid()
    out[i, 0] = inside_depth(skin, p[i], lo, hi)
    q = wp.mesh_query_point_sign_winding_number(skin, p[i], INSIDE_RANGE)
    if q.result and q.sign < 0.0:
        out[i, 1] = wp.length(p[i] - wp.mesh_eval_position(skin, q.face, q.u, q.v))
    d = float(1.0e6)
    c = wp.mesh_query_point_no_sign(skin, p[i], 1.0)
    if c.result:
        d = wp.length(p[i] - wp.mesh_eval_position(skin, c.face, c.u, c.v))
    out[i, 2] = frame_winding(skin, p[i], d, margin)
    w0 = float(-1.0)
    r = wp.mesh_query_point_sign_winding_number(skin, p[i], margin, 2.0, -0.5)
    if not r.result:
        w0 = 0.0
    elif r.sign < 0.0:
        w0 = 0.0
        r = wp.mesh_query_point_sign_winding_number(skin, p[i], margin, 2.0, 0.5)
        if r.sign < 0.0:
            w0 = 1.0
    out[i, 3] = w0


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not wp.is_cuda_available(), reason="no CUDA device"))])
def test_inside_depth_and_frame_winding_equal_warps_sign_queries(asset, device):
    """The object-side measure's inside test and the feature patches' w_0 search for the closest
    skin point only where it matters; their answers equal Warp's sign queries bit for bit at 6,000
    points within 3 cm of the rest hand's skin and 2,000 on it, wound outward (w 0 or 1) and inward (w -1 inside)."""
    x = np.asarray(asset.positions[: asset.n_skin], np.float32)
    rng = np.random.default_rng(3)
    pts = (x[rng.integers(0, len(x), 6000)] + rng.normal(0.0, 0.01, (6000, 3))).astype(np.float32)
    # and 2,000 on the skin (triangle centroids: w ~ 1/2, where frame_winding's coarse sum asks again)
    f = np.asarray(asset.skin_faces)[rng.integers(0, len(asset.skin_faces), 2000)]
    pts = np.concatenate([pts, x[f].mean(axis=1).astype(np.float32)])
    lo, hi = wp.vec3(*(x.min(0) - 1e-3)), wp.vec3(*(x.max(0) + 1e-3))
    seen = {}
    for wound, faces in (("out", asset.skin_faces), ("in", np.asarray(asset.skin_faces)[:, ::-1])):
        mesh = wp.Mesh(points=wp.array(x, dtype=wp.vec3, device=device),
                       indices=wp.array(np.ascontiguousarray(faces, np.int32).ravel(), dtype=int, device=device),
                       support_winding_number=True)
        out = wp.zeros((len(pts), 4), dtype=float, device=device)
        wp.launch(_inside_two_ways, len(pts), [mesh.id, wp.array(pts, dtype=wp.vec3, device=device), lo, hi, 0.01],
                  [out], device=device)
        o = out.numpy()
        assert np.array_equal(o[:, 0], o[:, 1]) and np.array_equal(o[:, 2], o[:, 3])
        seen[wound] = (int((o[:, 0] > 0).sum()), set(np.unique(o[:, 2]).tolist()))
    # both cases were met: points inside the skin (with depths), and w_0 of 1 / 0 outward, -1 / 0 inward
    assert seen["out"][0] > 500 and seen["out"][1] == {0.0, 1.0}
    assert seen["in"][0] == 0 and seen["in"][1] == {-1.0, 0.0}


def test_a_full_patch_pool_warns_and_its_overflowing_features_get_no_patch(monkeypatch):
    """The pool's bound (PATCH_POOL_MAX): the features whose patches do not fit get patch_len -1 (they
    keep the pseudo-normal sign, one hand), the others keep theirs, the frame stays finite, and the
    overflow is reported once as a warning that says what to change through the API (no source
    constant to edit)."""
    import mujoco

    from physhand_mj.contact import patch_pool as pool_mod

    monkeypatch.setattr(pool_mod, "PATCH_POOL_MAX", 512)
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    with pytest.warns(RuntimeWarning, match="contact_frame_margin") as rec:  # (from the hand's first frames on)
        hand = ph.SoftHand(model, data, ph.Config(device="cpu"))
        c = hand.solver.contact
        for _ in range(8):
            mujoco.mj_step(model, data)
            hand.step()
            c.features_listed()
    msg = [str(w.message) for w in rec if "patches" in str(w.message)]
    assert len(msg) == 1 and "BatchedHands" in msg[0] and ".py" not in msg[0] and "PATCH" not in msg[0], msg
    assert c.features.patch_pool.shape[0] == 512
    n = int(c.features.count.numpy()[0])
    lens = c.features.patch_len.numpy()[:n]
    assert n > 0 and np.any(lens == -1) and np.any(lens > 0)
    assert lens[lens > 0].sum() <= 512
    assert c.features.patch_used.numpy()[2] == np.count_nonzero(lens < 0)  # (the failures are counted, and warned of)
    assert np.all(np.isfinite(hand.state.x.numpy()))


def test_a_patch_pool_too_small_for_the_scene_grows(monkeypatch):
    """A pool made for 8 entries per feature point (the demo's grasp lists ~170 points with up to
    ~270 triangles each): the first frame's patches overflow it (66-81 points without a patch), and
    it grows to twice their need, without a warning; the solver records its frames again (they read
    the new pool), and from then on every listed point's patch fits. A later frame whose need
    passes half the pool grows it again before it overflows (with touch damping the glass's first
    frame needs less, 12,781 entries, and frame 2 17,677 of the 32,768 it grew to)."""
    import mujoco

    from physhand_mj.contact import patch_pool as pool_mod

    monkeypatch.setattr(pool_mod, "PATCH_POOL_PER_FEATURE", 8)
    monkeypatch.setattr(pool_mod, "PATCH_POOL_MIN", 64)
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        hand = ph.SoftHand(model, data, ph.Config(device="cpu"), settle_frames=1)
        c = hand.solver.contact
        first = c.features.patch_pool.shape[0]
        assert first == 8 * c.points.n_features and c.reallocations == 0
        grew = []
        for frame in range(6):
            mujoco.mj_step(model, data)
            hand.step()
            used = c.features.patch_used_host.numpy()
            n = int(c.features.count.numpy()[0])
            assert n > 100 and 2 * used[0] <= c.features.patch_pool.shape[0], (frame, n, used)
            if grew:  # (a frame after the pool first grew: recorded again, every patch in it)
                assert hand.solver._recorded_geoms[1] == len(grew)
                assert used[2] == 0 and np.all(c.features.patch_len.numpy()[:n] >= 0), (frame, used)
            if c.reallocations > len(grew):
                grew.append(frame)
    assert grew[0] == 0 and c.features.patch_pool.shape[0] >= 4 * first, (grew, c.features.patch_pool.shape[0], first)


def test_the_patch_pool_holds_4096_worlds_of_the_box_grasp():
    """The pool's bound against the case that overflowed it on an H100 (the HOI box grasp at W = 4,096:
    442,139,565 entries, ~107,944 a world, against 2^28): one world's need on the CPU (the same scene
    and keyframe; a world's patches do not depend on the others), times 4,096, fits both the bound and
    the pool a batch of 4,096 such worlds allocates (256 entries per feature point up to the bound),
    laid out as winding.feature_patches lays it out: each listed feature's own slot of c entries (c
    at most half that pool over the frame's list) and the larger patches again at the pool's top."""
    import mujoco

    from physhand_mj.contact import patch_pool as pool_mod

    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("hoi_box")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    # (the lists at the frame margin, as every world's first frame with contact makes them: the pool's
    # worst case; Config.tuning.feature_slack cuts later frames' lists to ~1/4 of this)
    hand = ph.SoftHand(model, data, ph.Config(device="cpu", tuning=ph.Tuning(feature_slack=1e-2)))
    c = hand.solver.contact
    worlds = 4096
    pool = pool_mod.patch_pool_size(c.points.n_features * worlds, hand.config.contact_frame_margin)
    need = layout = 0
    for _ in range(3):
        hand.step()
        c.features_listed()
        n = int(c.features.count.numpy()[0])
        length = c.features.patch_len.numpy()[:n]
        assert np.all(length >= 0)
        need = max(need, int(c.features.patch_used_host.numpy()[0]))
        cap = min(pool_mod.PATCH_SLOT, pool // (2 * n * worlds))
        layout = max(layout, n * cap + int(length[length > cap].sum()))
        assert cap >= 32, cap
    assert 50_000 < need <= c.features.patch_pool.shape[0]  # the grasp lists features; one hand's pool holds them
    assert need * worlds <= pool, (need * worlds, pool)
    assert layout * worlds <= pool, (layout * worlds, pool)
    assert need * worlds < 2**31  # the int32 counters do not wrap


def test_a_deep_start_lists_nearly_every_point_and_every_patch_fits():
    """The coarse mesh 4 mm deep in the fingertip (a hard case) lists most of its feature points at
    once, with patches past the slot a listed point gets: the list's slots fill at most half the
    pool (two slots' worth per feature point), so every patch fits (slots sized by the whole pool of
    128 entries per point left those patches no room: 157 of them went without one, in a pool that
    held them all packed)."""
    import warnings

    from physhand_mj.bench.cases import press_case, run_case

    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*patches.*")
        r = run_case(press_case("coarse", site="fingertip", depth=0.004, start=-0.004), ph.Config(device="cpu"),
                     frames=2, asset=ph.load_asset())
    c = r["solver"].contact
    n = int(c.features.count.numpy()[0])
    used = c.features.patch_used.numpy()
    assert n > c.points.n_features // 2 and used[1] > 0 and used[2] == 0, (n, c.points.n_features, used)
    assert np.all(c.features.patch_len.numpy()[:n] >= 0)
