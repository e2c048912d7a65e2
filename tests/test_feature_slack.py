"""Config.tuning.feature_slack (contact/slack.py): the object's feature points are listed, and their
patches sized, for the skin's motion in a frame, not for the whole frame margin. Checked against
brute force on the skin at the frame's start (which points are listed, which triangles their patches
hold) and at its end (the patch still holds the closest skin triangle; no unlisted point came near
the skin), and the slack's bookkeeping on its own."""

import warnings

import numpy as np
import pytest
import warp as wp

import physhand_mj as ph
from physhand_mj.bench.cases import press_case, run_case
from physhand_mj.config import FEATURE_LIST_SHARE
from physhand_mj.contact.closest import closest_on_triangle
from physhand_mj.contact.slack import UNLISTED, SkinMoves, certify_features, next_slack, skin_motion, skin_reach
from physhand_mj.contact.inside import object_point


@wp.func
def _tri_dist(p: wp.vec3, t: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3)):
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    bc = closest_on_triangle(a, b, c, p)
    return wp.length(bc[0] * a + bc[1] * b + (1.0 - bc[0] - bc[1]) * c - p)


@wp.kernel
def _brute(pts: wp.array(dtype=wp.vec3), geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform),
           faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), radius: wp.array(dtype=float),
           dist: wp.array(dtype=float), count: wp.array(dtype=int)):
    """Per object point: its distance to the skin ``x`` over every triangle, and how many triangles
    come within ``radius[i]`` of it."""
    i = wp.tid()
    p = object_point(i, pts, geom, pose)
    best = float(1.0e30)
    n = int(0)
    for t in range(faces.shape[0]):
        d = _tri_dist(p, t, faces, x)
        best = wp.min(best, d)
        if d <= radius[i]:
            n += 1
    dist[i] = best
    count[i] = n


@wp.kernel
def _patch_closest(feat: wp.array(dtype=int), pts: wp.array(dtype=wp.vec3), geom: wp.array(dtype=int),
                   pose: wp.array(dtype=wp.transform), faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                   pool: wp.array(dtype=int), start: wp.array(dtype=int), length: wp.array(dtype=int),
                   out: wp.array(dtype=float)):
    """Per listed feature: its distance to the skin ``x`` over its patch's triangles only."""
    k = wp.tid()
    p = object_point(feat[k], pts, geom, pose)
    best = float(1.0e30)
    for j in range(start[k], start[k] + length[k]):
        best = wp.min(best, _tri_dist(p, pool[j], faces, x))
    out[k] = best


def _cpu(a):
    """A device array's copy on the CPU (the brute force runs there)."""
    return wp.array(a.numpy(), dtype=a.dtype, device="cpu")


def _brute_force(c, x, radius):
    pts = c.points
    n = pts.pts.shape[0]
    dist = wp.zeros(n, dtype=float, device="cpu")
    count = wp.zeros(n, dtype=int, device="cpu")
    wp.launch(_brute, n, [_cpu(pts.pts), _cpu(pts.geom), _cpu(c.space.pose), _cpu(c.model.skin_faces), _cpu(x),
                          wp.array(np.asarray(radius, np.float32), dtype=float, device="cpu")], [dist, count],
              device="cpu")
    return dist.numpy().astype(float), count.numpy()


@wp.kernel
def _signs(mesh: wp.uint64, pts: wp.array(dtype=wp.vec3), geom: wp.array(dtype=int),
           pose: wp.array(dtype=wp.transform), far: float, out: wp.array(dtype=float)):
    i = wp.tid()
    q = wp.mesh_query_point_sign_normal(mesh, object_point(i, pts, geom, pose), far)
    out[i] = 0.0
    if q.result:
        out[i] = q.sign


def _pseudo_inside(c, x, far):
    """Per object point: whether the skin ``x``'s pseudo normals put it inside (within ``far``)."""
    mesh = wp.Mesh(points=_cpu(x), indices=wp.array(c.model.skin_faces.numpy().reshape(-1), dtype=int, device="cpu"))
    out = wp.zeros(c.points.pts.shape[0], dtype=float, device="cpu")
    wp.launch(_signs, out.shape[0], [mesh.id, _cpu(c.points.pts), _cpu(c.points.geom), _cpu(c.space.pose), far], [out],
              device="cpu")
    return out.numpy() < 0


DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device"))]


@pytest.fixture(scope="module")
def asset():
    return ph.load_asset()


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("slack", [4.0e-3, 1.0e-2])
def test_lists_and_patches_match_brute_force_at_both_ends_of_the_frame(asset, slack, device):
    """A knife edge pressed 4 mm into the fingertip (frames 1-12 of the hard case; its edge's points
    are the features). At the last frame's start the listed points are exactly the feature points
    within min(margin, contact_margin + share x slack) of the skin (config.FEATURE_LIST_SHARE: 0.5,
    the default, and 1.0, the lists before it; and those within the margin the pseudo
    normals put inside), each patch holds exactly the triangles
    within min(margin, d + slack) of its point; at the frame's end (the skin moved less than half
    the slack: not reported) each listed point's closest skin point lies in its patch, and no
    unlisted feature point is within contact_margin of the skin. With the slack at the frame margin
    every feature point within the margin is listed with a patch of that radius (the lists before
    the slack). On CUDA the patches are a block's over every skin triangle (feature_patches_tiled)."""
    _check_lists(asset, slack, device)


def test_patches_past_their_slot_go_to_the_pools_top(asset, monkeypatch):
    """winding.feature_patches with each listed feature's own slot cut to 30 entries: the larger
    patches are written again at the pool's top, below its end and above the list's slots, and the
    lists and patches still match brute force at both ends of the frame (the test above)."""
    from physhand_mj.contact import patch_pool as pool_mod

    monkeypatch.setattr(pool_mod, "PATCH_SLOT", 30)  # (the knife's patches: 19 to ~70)
    c = _check_lists(asset, 4.0e-3, "cpu")
    n = int(c.features.count.numpy()[0])
    cap = min(30, c.features.patch_pool.shape[0] // (2 * n))  # (the list's slots fill at most half the pool)
    assert cap == 30
    length, start = c.features.patch_len.numpy()[:n], c.features.patch_start.numpy()[:n]
    top = length > cap
    assert top.any() and (~top).any()
    np.testing.assert_array_equal(start[~top], cap * np.arange(n)[~top])  # (their own slots)
    assert np.all(start[top] >= cap * n) and np.all(start[top] + length[top] <= c.features.patch_pool.shape[0])
    span = sorted(zip(start[top], start[top] + length[top]))
    assert all(a[1] <= b[0] for a, b in zip(span, span[1:]))  # (the top's patches do not overlap)
    used = c.features.patch_used.numpy()
    assert used[0] == length.sum() and used[1] == length[top].sum() and used[2] == 0


def _check_lists(asset, slack, device):
    cfg = ph.Config(device=device, tuning=ph.Tuning(feature_slack=slack)).validate()
    r = run_case(press_case("knife", site="fingertip", depth=0.004, start=0.002), cfg, frames=12, check_order=5,
                 asset=asset)
    solver, state = r["solver"], r["state"]
    c = solver.contact
    act = solver.last_activity
    assert act["feature_slack_exceeded"] == 0
    used = float(c.slack_check.data.report.numpy()[0, 0])  # (m, as the lists were made: not the report's rounded mm)
    assert used >= slack - 1e-9 and used <= cfg.contact_frame_margin + 1e-9
    if slack >= cfg.contact_frame_margin:
        assert used == pytest.approx(cfg.contact_frame_margin)
    else:
        assert used < cfg.contact_frame_margin  # (the press moved the skin < 4 mm a frame: the slack came down)
    n = int(c.features.count.numpy()[0])
    assert n > 10
    feat = c.features.listed.numpy()[:n]
    is_feature = np.zeros(c.points.pts.shape[0], bool)
    is_feature[c.points.feature.numpy()] = True
    # the frame's start: the skin the lists were made on
    x0 = c.slack_check.data.moves.x_start
    reach = min(cfg.contact_frame_margin, cfg.contact_margin + FEATURE_LIST_SHARE * used)
    if used >= cfg.contact_frame_margin - 1e-9:  # (a slack at the margin lists every point within it)
        reach = cfg.contact_frame_margin
    d0, _ = _brute_force(c, x0, np.zeros(c.points.pts.shape[0]))
    inside = _pseudo_inside(c, x0, cfg.contact_frame_margin)
    want = set(np.flatnonzero(is_feature & ((d0 <= reach) | (inside & (d0 <= cfg.contact_frame_margin)))).tolist())
    near_edge = np.abs(d0 - reach) < 1e-7  # (float rounding at the cut)
    got = set(feat.tolist())
    assert {i for i in got ^ want if not near_edge[i]} == set()
    # the band past the list's reach, within keep + slack: measured for the frame's check, not listed
    band = is_feature & ~np.isin(np.arange(len(d0)), feat) & (d0 <= min(cfg.contact_frame_margin,
                                                                         cfg.contact_margin + used) - 1e-7)
    assert band.any() == (FEATURE_LIST_SHARE < 1.0 and slack < cfg.contact_frame_margin)
    np.testing.assert_allclose(c.slack_check.data.pt_dist.numpy()[band], d0[band], atol=1e-6)
    assert np.all(c.slack_check.data.pt_face.numpy()[band] == -1)
    assert len(got) < int(np.count_nonzero(is_feature)) or slack >= cfg.contact_frame_margin
    np.testing.assert_allclose(c.slack_check.data.feat_dist.numpy()[:n], d0[feat], atol=1e-6)
    radius = np.full(c.points.pts.shape[0], -1.0)
    radius[feat] = np.minimum(cfg.contact_frame_margin, c.slack_check.data.feat_dist.numpy()[:n] + used)
    _, count = _brute_force(c, x0, radius)
    length = c.features.patch_len.numpy()[:n]
    assert np.all(length >= 0)
    np.testing.assert_array_equal(length, count[feat])
    if device != "cpu":  # (CUDA's patch fills in no fixed order; the same triangles)
        pool, start = c.features.patch_pool.numpy(), c.features.patch_start.numpy()[:n]
        assert all(len(set(pool[a: a + ln])) == ln for a, ln in zip(start, length))
    # the frame's end
    x1 = state.x
    d1, _ = _brute_force(c, x1, np.zeros(c.points.pts.shape[0]))
    pc = wp.zeros(n, dtype=float, device="cpu")
    wp.launch(_patch_closest, n, [_cpu(a) for a in (c.features.listed, c.points.pts, c.points.geom, c.space.pose, c.model.skin_faces, x1,
                                                    c.features.patch_pool, c.features.patch_start, c.features.patch_len)], [pc], device="cpu")
    np.testing.assert_allclose(pc.numpy(), d1[feat], atol=1e-7)
    unlisted = is_feature.copy()
    unlisted[feat] = False
    assert np.all(d1[unlisted] > cfg.contact_margin)
    # and the contact's result: nothing inside by either measure
    assert r["skin_count"][-1] == 0 and r["check_count"][-1] == 0 and r["obj_count"][-1] == 0
    return c


def _arr(a, dtype):
    return wp.array(np.asarray(a), dtype=dtype, device="cpu")


def test_the_frames_check_flags_only_a_move_that_could_spoil_a_list():
    """skin_motion / skin_reach / certify_features / next_slack on a hand-made skin (one world, margin
    10 mm): feature point 0 is listed 1 mm from triangle A (vertices 0-2), triangle B (vertices
    3-5) starts 8 mm away; point 1 is unlisted, 20 mm below. With a 4 mm slack: a move of B too
    small to come within contact_margin of the point passes; one large enough and near enough
    fails; A itself moving 2.5 mm passes for a point outside and fails for one inside (a triangle
    outside the patch could then be nearer than A); a fast vertex sliding 5 cm sideways fails too
    (the check knows end positions only, and the world's longest edge: conservative); B's vertex
    moving 4.6 mm away from the point passes (it ends too far from it) but counts towards the next
    slack; B moving 5 mm 38 mm away passes. The next slack is 2.5 x the
    largest move near the points, at least 0.8 x the last and the least, at most the margin; after
    a failed frame at least 2.5 x the world's largest move; a world that listed nothing keeps it. A
    non-finite vertex counts 0. With the
    margin's slack (a world's first frame) a triangle 10.2 mm from the unlisted point that comes to
    0.4 mm of it fails. A capped patch of a point 8 mm inside with an 8 mm slack needs less move than
    the fast list's threshold: a move anywhere as long as that fails it with no fast vertex at all (8
    mm outside, or no such move: it passes). More fast vertices than the list holds fail the world
    where those not asked moved as far as a point needs, not where they moved less. An unlisted point 3.2 mm from B, measured
    (past the lists' keep + s / 2, config.FEATURE_LIST_SHARE), needs a 2.7 mm move of B's vertex
    towards it; not measured (taken as keep + s away) or listed, more. B swept through that point,
    ending far from it, fails (its vertices' ways passed through the point); so does a listed
    point's closest triangle passing through it (the point may now be inside)."""
    faces = wp.array(np.array([[0, 1, 2], [3, 4, 5]], np.int32), dtype=int, device="cpu")
    base = np.array([[-1, -1, 1], [1, -1, 1], [0, 1, 1], [-1, -1, 8], [1, -1, 8], [0, 1, 8]], np.float32) * 1e-3
    pose = wp.array(np.array([[0, 0, 0, 0, 0, 0, 1]], np.float32), dtype=wp.transform, device="cpu")

    def check(moves, x0=base, slack0=4e-3, pts=((0, 0, 0), (0, 0, -20e-3)), dist=(1e-3, UNLISTED), cap=4,
              face=None):
        x1 = x0.copy()
        for v, dv in moves.items():
            x1[v] += np.asarray(dv, np.float32)
        slack = _arr(np.float32([slack0]), float)
        nv = x0.shape[0]
        mv = SkinMoves()  # (a fast row of ``cap``, not slack.skin_moves' room for every vertex)
        mv.x_start, mv.vmotion = _arr(x0, wp.vec3), wp.zeros(nv, dtype=float, device="cpu")
        mv.motion, mv.reach = wp.zeros(1, dtype=float, device="cpu"), wp.zeros(1, dtype=float, device="cpu")
        mv.fast, mv.fast_count = wp.zeros((1, cap), dtype=int, device="cpu"), wp.zeros(1, dtype=int, device="cpu")
        fast_count, x1w, world = mv.fast_count, _arr(x1, wp.vec3), _arr(np.zeros(nv, np.int32), int)
        wp.launch(skin_motion, nv, [x1w, world, slack], [mv], device="cpu")
        wp.launch(skin_reach, 2, [faces, x1w, world], [mv], device="cpu")
        edges = [np.linalg.norm(t - np.roll(t, 1, axis=1), axis=2) for t in (x0[faces.numpy()], x1[faces.numpy()])]
        longest = max(np.nanmax(e) for e in edges)  # (at the start or the end; asked only where a vertex moved fast)
        assert mv.reach.numpy()[0] == (pytest.approx(longest, rel=1e-6) if fast_count.numpy()[0] else 0.0)
        near, failed = wp.zeros(1, dtype=float, device="cpu"), wp.zeros(1, dtype=int, device="cpu")
        n = len(pts)
        wp.launch(certify_features, n, [_arr(np.arange(n, dtype=np.int32), int),
                                        _arr(np.asarray(pts, np.float32), wp.vec3), _arr(np.zeros(n, np.int32), int),
                                        pose, _arr(np.int32([1]), int), 1, _arr(np.float32(dist), float),
                                        _arr(np.int32(face or [0] * n), int), faces, x1w, mv, slack, 1e-2, 5e-4],
                  [near, failed], device="cpu")
        report = wp.zeros((1, 3), dtype=float, device="cpu")
        listed = _arr(np.int32([int(any(abs(x) < UNLISTED for x in dist))]), int)
        wp.launch(next_slack, 1, [mv, near, failed, listed, 4e-3, 1e-2], [slack, report], device="cpu")
        return report.numpy()[0], float(slack.numpy()[0]), int(fast_count.numpy()[0])

    r, nxt, n = check({3: (0, 0, -3e-3)})  # B 3 mm towards the point: fast, but it needs 4 mm
    assert (r[2], n) == (0, 1) and r[1] == pytest.approx(3e-3) and nxt == pytest.approx(4e-3)
    r, nxt, _ = check({3: (0, 0, -4.6e-3)})  # 4.6 mm, starting 8 mm away: could come within keep of the point
    assert r[2] == 1 and nxt == pytest.approx(1e-2)  # (2.5 x 4.6 mm, capped at the margin)
    r, nxt, _ = check({0: (0, 0, 2.5e-3)})  # A itself 2.5 mm: no triangle outside the patch came near
    assert r[2] == 0 and nxt == pytest.approx(6.25e-3)  # (but the next lists allow for it)
    r, nxt, _ = check({0: (0, 0, 2.5e-3)}, dist=(-1e-3, UNLISTED))  # the same with the point inside: C moved
    assert r[2] == 1  # past half the slack, so a triangle outside the patch could now be nearer than C
    r, nxt, _ = check({5: (50e-3, 0, 0)})  # 5 cm sideways: B's edges are then 5 cm long, and a triangle
    assert r[2] == 1  # that long could reach the point from where it ended (conservative)
    r, nxt, _ = check({3: (0, 0, 4.6e-3)})  # 4.6 mm away from the point (what towards it fails, above): it
    assert r[2] == 0 and nxt == pytest.approx(1e-2)  # started near enough to count for the next slack, but
    # ended 12.7 mm from the point, farther than keep + B's longest edge (5.1 mm): no triangle of it came near
    far = base.copy()
    far[3:] += np.float32([0, 0, 30e-3])  # B starting 38 mm away: too far for its 5 mm move
    r, nxt, _ = check({3: (5e-3, 0, 0)}, x0=far)
    assert r[2] == 0 and r[1] == pytest.approx(5e-3) and nxt == pytest.approx(4e-3)
    r, nxt, _ = check({1: (np.nan, 0, 0), 2: (0, 0, 1e-3)})
    assert r[2] == 0 and r[1] == pytest.approx(1e-3) and nxt == pytest.approx(4e-3)
    r, nxt, _ = check({1: (0, 0, 4.8e-3)})  # A's vertex 4.8 mm: the next slack capped at the margin (its way
    assert r[2] == 1 and nxt == pytest.approx(1e-2)  # starts 1.7 mm from the point, A's edges grow to 5.3 mm)
    r, nxt, _ = check({}, slack0=1e-2)  # nothing moved: the slack comes down by SLACK_DECAY a frame
    assert r[2] == 0 and nxt == pytest.approx(8e-3)
    r, nxt, _ = check({}, slack0=1e-2, pts=((0, 0, -20e-3),), dist=(UNLISTED,))  # nothing listed: it stays
    assert r[2] == 0 and nxt == pytest.approx(1e-2)
    # the margin's slack: point 1 unlisted (farther than the margin), B's vertex 10.2 mm from it moves to 0.4 mm
    low = base.copy()
    low[3:] = np.float32([[0, 0, -9.8e-3], [1e-3, 0, -9.8e-3], [0, 1e-3, -9.8e-3]])
    r, nxt, _ = check({3: (0, 0, -9.8e-3)}, x0=low, slack0=1e-2, pts=((0, 0, -20e-3),), dist=(UNLISTED,))
    assert r[2] == 1
    # a capped patch: 8 mm inside, slack 8 mm (r = 10 mm, 2 mm to spare): a 3 mm move anywhere (under
    # the list's 4 mm threshold, not asked) fails it unasked; 8 mm outside (a move of 9.5 mm would be
    # needed to come within keep) passes; with nothing moved, or moves under its 2 mm, it passes too
    r, nxt, n = check({3: (3e-3, 0, 0)}, x0=far, slack0=8e-3, pts=((0, 0, -7e-3),), dist=(-8e-3,))
    assert (r[2], n) == (1, 0)
    r, nxt, n = check({3: (3e-3, 0, 0)}, x0=far, slack0=8e-3, pts=((0, 0, -7e-3),), dist=(8e-3,))
    assert (r[2], n) == (0, 0)
    r, nxt, n = check({}, slack0=8e-3, pts=((0, 0, -7e-3),), dist=(-8e-3,))
    assert (r[2], n) == (0, 0)
    r, nxt, n = check({3: (1.5e-3, 0, 0)}, x0=far, slack0=8e-3, pts=((0, 0, -7e-3),), dist=(-8e-3,))
    assert (r[2], n) == (0, 0)
    # more fast vertices than the list holds (cap 1): those not asked moved up to 30 mm, more than any
    # point needs: the world fails, the next slack from its largest move
    r, nxt, n = check({3: (0, 0, 30e-3), 4: (0, 0, 30e-3)}, x0=far, cap=1)
    assert r[2] == 1 and n == 2 and nxt == pytest.approx(1e-2)
    # ... but fast vertices past the list's end that moved less than every point needs spoil nothing (the
    # shipped demo's third frame: 325 vertices moved 4.6-7.2 mm, half its 9.2 mm slack or more, none as
    # far as a point needed): with an 8 mm slack, two of B's vertices 4.5 mm sideways, point 0 (listed 1
    # mm away) needs 8.5 mm, point 1 (unlisted) 8 mm
    r, nxt, n = check({3: (4.5e-3, 0, 0), 4: (4.5e-3, 0, 0)}, x0=far, slack0=8e-3, cap=1)
    assert r[2] == 0 and n == 2 and r[1] == pytest.approx(4.5e-3)
    # config.FEATURE_LIST_SHARE: a point 3.2 mm above B and one of B's vertices rising towards it. Not
    # measured (beyond the lists' reach, taken as keep + s away), a 2.9 mm move passes; measured in
    # the band past the lists' keep + s / 2 (pt_face -1: 3.2 mm), it needs 2.7 mm: 2.5 mm passes, 2.9
    # mm fails; the point listed 3.2 mm from B (face 1) needs 3.2 + 4 - 0.5 mm: 2.9 mm passes
    above = dict(pts=((0, 0, 0), (0, 0, 11.2e-3)))
    r, nxt, n = check({3: (0, 0, 2.9e-3)}, dist=(1e-3, UNLISTED), **above)
    assert (r[2], n) == (0, 1)
    r, nxt, n = check({3: (0, 0, 2.5e-3)}, dist=(1e-3, 3.2e-3), face=(0, -1), **above)
    assert (r[2], n) == (0, 1)
    r, nxt, n = check({3: (0, 0, 2.9e-3)}, dist=(1e-3, 3.2e-3), face=(0, -1), **above)
    assert (r[2], n) == (1, 1)
    r, nxt, n = check({3: (0, 0, 2.9e-3)}, dist=(1e-3, 3.2e-3), face=(0, 1), **above)
    assert (r[2], n) == (0, 1)
    # B swept 6 (9) mm up through that point, leaving it 2.8 (5.8) mm inside behind B, every vertex of B
    # ending farther than keep + B's edges from it: B's way passed through it, so it fails (measured or not)
    lift = {v: (0, 0, 6e-3) for v in (3, 4, 5)}
    r, nxt, n = check(lift, dist=(1e-3, 3.2e-3), face=(0, -1), **above)
    assert (r[2], n) == (1, 3)
    r, nxt, n = check(lift, dist=(1e-3, UNLISTED), **above)
    assert (r[2], n) == (1, 3)
    r, nxt, n = check({v: (0, 0, 9e-3) for v in (3, 4, 5)}, dist=(1e-3, 3.2e-3), face=(0, -1), **above)
    assert (r[2], n) == (1, 3)
    # A, point 0's closest triangle 1 mm above it, moved 2.5 mm down through it: the point may now be inside,
    # where a triangle outside its patch must not come nearer than A (d + 2.5 mm): a move of 1.5 mm could do
    # that, under half the slack: it fails unasked; A's vertex 0 moving 2.5 mm up leaves it on A's side: passes
    r, nxt, n = check({v: (0, 0, -2.5e-3) for v in (0, 1, 2)})
    assert r[2] == 1
    r, nxt, n = check({0: (0, 0, 2.5e-3)})
    assert r[2] == 0


def test_the_shipped_demo_outruns_no_list(asset):
    """The shipped demo (``physhand demo``: the grasp_glass scene from its approach keyframe, its
    lists sized for the frame margin as the CLI sizes them): in its third frame skin vertices move
    up to 7.2 mm, more than half the lists' 10 mm slack, none of them as far as a feature point
    needs: no frame is flagged. (With the default ``feature_slack`` the slack that frame is 2.5 x an
    earlier frame's move near the points, 6.4-9.2 mm by the path: where it is 6.4 mm the frame is
    flagged and warns, as the demo's comment says, so the demo sizes its lists.)"""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    config = ph.Config(device="cpu")
    config.tuning.feature_slack = config.contact_frame_margin  # as physhand_mj/cli.py's demo
    hand = ph.SoftHand(model, data, config, asset=asset)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for frame in range(4):
            mujoco.mj_step(model, data)
            hand.step()
            act = hand.solver.last_activity
            assert act["feature_slack_exceeded"] == 0, (frame, act)
            if frame == 2:  # moves past half the slack, the fast vertices' own check passes them
                assert act["skin_motion_mm"] > 0.5 * act["feature_slack_mm"], act


def test_a_deep_start_lists_with_the_margin_first_then_with_the_skins_move(asset):
    """A plate starting 4 mm inside the palm: the first frame lists with the frame margin, the next
    with 2.5 x the largest move near the points in the first (at least
    Config.tuning.feature_slack); a flagged frame warns once where the lists were cut short, not at the
    margin."""
    cfg = ph.Config(device="cpu").validate()
    r = run_case(press_case("plate", site="palm", depth=0.004, start=-0.004), cfg, frames=1, check_order=5,
                 asset=asset)
    solver = r["solver"]
    act = solver.last_activity
    assert act["feature_slack_mm"] == pytest.approx(cfg.contact_frame_margin * 1e3)
    move = act["skin_motion_mm"] * 1e-3
    assert move > 0
    nxt = float(solver.contact.slack_check.data.slack.numpy()[0])
    near = float(solver.contact.slack_check.data.near_motion.numpy()[0])
    assert 0 < near <= move + 1e-7  # (the report's skin_motion_mm is rounded to 0.1 um)
    assert nxt == pytest.approx(min(max(cfg.feature_slack, 2.5 * near), cfg.contact_frame_margin), rel=1e-5)
    # a report of a frame that outran a cut-short slack warns (once), one at the margin does not
    c = solver.contact
    c.slack_check.warned = False
    c.slack_check.data.report_host.numpy()[0] = (cfg.contact_frame_margin, 0.6 * cfg.contact_frame_margin, 1.0)
    assert c.feature_motion()["feature_slack_exceeded"] == 1 and not c.slack_check.warned
    c.slack_check.data.report_host.numpy()[0] = (4e-3, 2.5e-3, 1.0)
    with pytest.warns(RuntimeWarning, match="feature_slack"):
        assert c.feature_motion()["feature_slack_exceeded"] == 1
    assert c.slack_check.warned


def test_feature_slack_must_be_a_distance():
    with pytest.raises(ValueError, match="feature_slack"):
        ph.Config(tuning=ph.Tuning(feature_slack=-1e-3)).validate()
    with pytest.raises(ValueError, match="feature_slack"):
        ph.Config(tuning=ph.Tuning(feature_slack=float("nan"))).validate()
    with pytest.raises(ValueError, match="feature_slack"):  # (0: every vertex fast, every frame flagged)
        ph.Config(tuning=ph.Tuning(feature_slack=0.0)).validate()


def test_the_slack_changes_no_push_on_the_cpu(asset):
    """On the CPU a feature point's closest skin point comes from the skin's BVH either way; the slack
    changes which points are listed and the patches their winding numbers sum over. A cone tip
    started 4 mm deep in the fingertip (its skin jitters up to ~3 mm a frame around the tip, some
    frames flagged): the skin after 16 frames with the 4 mm slack equals the run listing at the frame
    margin (the lists before the slack) to 1 um, and neither leaves anything inside."""
    runs = {}
    for slack in (4.0e-3, 1.0e-2):
        r = run_case(press_case("cone_tip", site="fingertip", depth=0.004, start=-0.004),
                     ph.Config(device="cpu", tuning=ph.Tuning(feature_slack=slack)), frames=16,
                     check_order=5, asset=asset)
        assert r["skin_count"][-1] == 0 and r["obj_count"][-1] == 0 and r["check_count"][-1] == 0
        runs[slack] = r["skin"]
    np.testing.assert_allclose(runs[4.0e-3], runs[1.0e-2], atol=1e-6)


@pytest.mark.slow  # the hoi_box grasp in 2 worlds, 5 frames, then brute force over every point
def test_band_points_in_batched_worlds(asset):
    """Batched worlds, each queried at its own offset (Contact.set_query_offsets): the hoi_box grasp in
    two worlds on the CPU, five frames. At the last frame's start, per world w with slack s_w: the
    listed points are those within contact_margin + s_w / 2 of their own world's skin (or inside by
    its pseudo normals), the points past that and within contact_margin + s_w are measured (their
    distance in pt_dist, pt_face -1), all by brute force over the shifted skin (worlds 1 m apart)."""
    from physhand_mj.batch_rollout import replicated_batch

    hands, (pos, quat, op, oq) = replicated_batch(asset, ph.scene_path("hoi_box"), "grasp", 2)
    cfg = hands.solver.config
    for _ in range(5):  # (the first three list at the frame margin: the grasp starts inside the box)
        hands.step(pos, quat, op, oq)
    c = hands.solver.contact
    assert c.query_shift is not None
    used = c.slack_check.data.report.numpy()[:, 0]  # (m, each world's slack its last lists were made with)
    assert np.all(used < cfg.contact_frame_margin)
    x0 = c.slack_check.data.moves.x_start.numpy() + c.query_shift.numpy()  # the frame's start, where the worlds were queried
    d0, _ = _brute_force(c, _cpu_arr(x0), np.zeros(c.points.pts.shape[0]))
    world = c.points.geom.numpy() // c.geoms_per_world
    is_feature = np.zeros(len(d0), bool)
    is_feature[c.points.feature.numpy()] = True
    listed = np.zeros(len(d0), bool)
    listed[c.features.listed.numpy()[: int(c.features.count.numpy()[0])]] = True
    lim = cfg.contact_margin + FEATURE_LIST_SHARE * used[world]
    ask = cfg.contact_margin + used[world]
    edge = (np.abs(d0 - lim) < 1e-7) | (np.abs(d0 - ask) < 1e-7)  # (float rounding at the cuts)
    inside = _pseudo_inside(c, _cpu_arr(x0), cfg.contact_frame_margin)
    want = is_feature & ((d0 <= lim) | (inside & (d0 <= cfg.contact_frame_margin)))
    assert not np.any((listed != want) & ~edge)
    band = is_feature & ~listed & (d0 <= ask) & ~edge
    assert band.sum() > 50 and set(np.unique(world[band])) == {0, 1}
    np.testing.assert_allclose(c.slack_check.data.pt_dist.numpy()[band], d0[band], atol=1e-6)
    assert np.all(c.slack_check.data.pt_face.numpy()[band] == -1)
    beyond = is_feature & ~listed & (d0 > ask) & ~edge
    assert beyond.any() and np.all(c.slack_check.data.pt_dist.numpy()[beyond] >= UNLISTED)


def _cpu_arr(x):
    return wp.array(np.asarray(x, np.float32), dtype=wp.vec3, device="cpu")
