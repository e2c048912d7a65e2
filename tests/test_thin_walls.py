"""Thin walls pressed face-first into the hand (docs/contact.md "Thin walls"): a box plate thinner
than the skin, of several extents, thicknesses and depths, at the palm, across three fingers and
slanted, pressed in from outside over frames or starting embedded; the skin must end under the
wall (the side the wall came from is left open) at zero by all four measures over the last frames.
A placement whose bones come within BONE_CLEAR of the wall has no penetration-free skin and is
skipped (the issue's feasibility rule)."""

import numpy as np
import pytest

import physhand_mj as ph
from physhand_mj.bench.cases import run_case, wall_case
from physhand_mj.types import GeomType, Layer

BONE_CLEAR = 3.0e-4  # m: the bones' least clearance from the wall for a placement to count as feasible


def quat_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def bone_clearance(asset, x, pos, quat, size) -> float:
    """The skeleton vertices' least signed distance (m) from the box ``size`` at (pos, quat)."""
    sk = np.asarray(x, float)[np.flatnonzero(np.asarray(asset.layer) == int(Layer.SKELETON))]
    loc = (sk - pos) @ quat_matrix(quat)
    q = np.abs(loc) - np.asarray(size)
    return float((np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)).min())


def run_wall(case, frames, **tuning):
    asset = ph.load_asset()
    r = run_case(case, ph.Config(device="cpu", tuning=ph.Tuning(**tuning)), frames=frames, asset=asset)
    x = r["state"].x.numpy()
    r["bone_clear"] = bone_clearance(asset, x, r["object_pos"], r["object_quat"], case.size)
    return r


def assert_clean(r, last):
    assert r["finite"]
    if r["bone_clear"] < BONE_CLEAR:
        pytest.skip(f"bones {r['bone_clear'] * 1e3:.2f} mm from the wall: no penetration-free skin")
    for key in ("skin_count", "dense_count", "obj_count", "check_count"):
        assert np.all(r[key][-last:] == 0), (key, r[key].tolist())


@pytest.mark.parametrize("half,thick,depth", [(0.004, 0.001, 0.004), (0.008, 0.002, 0.002), (0.008, 0.0005, 0.001)])
def test_wall_embedded_at_the_palm(half, thick, depth):
    assert_clean(run_wall(wall_case(half, thick, depth), 12), 3)


def test_wall_pressed_into_the_palm():
    assert_clean(run_wall(wall_case(0.008, 0.001, 0.003, start=0.002), 14), 3)


@pytest.mark.slow
@pytest.mark.parametrize("kw", [
    dict(half=0.008, thick=0.001, depth=0.004),  # 16 mm, 4 mm deep at the palm (main: 57 samples in frames 0-5)
    dict(half=0.012, thick=0.001, depth=0.002, start=0.002),  # 24 mm pressed in
    dict(half=0.008, thick=0.001, depth=0.0015, site="fingers"),  # across three proximal phalanges
    dict(half=0.012, thick=0.001, depth=0.0015, site="fingers"),
    dict(half=0.012, thick=0.001, depth=0.0015, site="fingers", start=0.002),
    dict(half=0.008, thick=0.001, depth=0.003, tilt=25.0, start=0.002),  # slanted, pressed in
    # (slanted 25 degrees and embedded: in the wall family below, where it keeps samples)
], ids=lambda kw: "-".join(f"{k}{v}" for k, v in kw.items()))
def test_walls(kw):
    assert_clean(run_wall(wall_case(**kw), 16), 3)


@pytest.mark.slow
@pytest.mark.parametrize("kw,frames,last", [
    (dict(half=0.015, thick=0.001, depth=0.004), 14, 10),  # the 30 mm plate 4 mm deep (issue 51's case)
    (dict(half=0.015, thick=0.001, depth=0.004, start=0.005), 20, 10),  # 30 mm pressed 4 mm from 5 mm out, held
    (dict(half=0.012, thick=0.001, depth=0.004, start=0.002), 20, 10),  # 24 mm pressed 4 mm from 2 mm out, held
    (dict(half=0.012, thick=0.001, depth=0.004), 16, 15),  # 24 mm 4 mm deep from the start
], ids=["30mm-embedded", "30mm-pressed-held", "24mm-pressed-held", "24mm-embedded"])
def test_wide_walls(kw, frames, last):
    """The wide plates that folded round their rims before the flesh followed the pushed skin near a
    wall (Tuning.wall_carry, on by default; solver/carry.py) end clean by all four measures (measured:
    from frame 0-4 on; with the share at 0 the 30 mm plates keep 29-225 order-5 samples or object points,
    the 24 mm ones 31 samples held)."""
    assert_clean(run_wall(wall_case(**kw), frames), last)


# The plates of the tests above and the two slanted ones (frames, last frames that must be clean),
# each also run 10 % shallower and deeper and tilted 5 degrees either way: the wall family
WALL_FAMILY = [
    (dict(half=0.004, thick=0.001, depth=0.004), 12, 3), (dict(half=0.008, thick=0.002, depth=0.002), 12, 3),
    (dict(half=0.008, thick=0.0005, depth=0.001), 12, 3), (dict(half=0.008, thick=0.001, depth=0.003, start=0.002), 14, 3),
    (dict(half=0.008, thick=0.001, depth=0.004), 16, 3), (dict(half=0.012, thick=0.001, depth=0.002, start=0.002), 16, 3),
    (dict(half=0.008, thick=0.001, depth=0.0015, site="fingers"), 16, 3),
    (dict(half=0.012, thick=0.001, depth=0.0015, site="fingers"), 16, 3),
    (dict(half=0.012, thick=0.001, depth=0.0015, site="fingers", start=0.002), 16, 3),
    (dict(half=0.008, thick=0.001, depth=0.003, tilt=25.0), 16, 3),
    (dict(half=0.008, thick=0.001, depth=0.003, tilt=25.0, start=0.002), 16, 3),
    (dict(half=0.015, thick=0.001, depth=0.004), 14, 10), (dict(half=0.015, thick=0.001, depth=0.004, start=0.005), 20, 10),
    (dict(half=0.015, thick=0.001, depth=0.004, start=0.002, tilt=20.0), 20, 4),
    (dict(half=0.012, thick=0.001, depth=0.004, start=0.002), 20, 10), (dict(half=0.012, thick=0.001, depth=0.004), 16, 15),
]


def wall_family():
    for kw, frames, last in WALL_FAMILY:
        yield kw, frames, last
        for f in (0.9, 1.1):
            yield dict(kw, depth=kw["depth"] * f), frames, last
        for t in (-5.0, 5.0):
            yield dict(kw, tilt=kw.get("tilt", 0.0) + t), frames, last


@pytest.mark.slow
def test_wall_family():
    """The 80 plates of WALL_FAMILY at the default (CPU; ~3-5 min): every run finite, no placement
    infeasible, and every one clean by all four measures over its last frames. Touch damping (the
    default since 2026-12-01) brings the held skin to rest; without it 74 of 80 were clean at Eq. 9's
    20 um offset and 75 at 4 um, not the same ones: the 16 mm plate slanted 25 degrees and embedded
    kept 7-36 order-5 samples up to 0.49 mm in frames 2-13 with its skin swinging 8-18 mm a frame,
    the 30 mm plate slanted 20 degrees 2 object points (26 um) in its last frame, 24 and 30 mm
    plates slanted or pressed deeper residues in held frames (docs/contact.md "Thin walls",
    "Held contact at rest")."""
    runs = [(kw, run_wall(wall_case(**kw), frames), last) for kw, frames, last in wall_family()]
    assert len(runs) == 80 and all(r["finite"] for _, r, _ in runs)
    assert all(r["bone_clear"] >= BONE_CLEAR for _, r, _ in runs), [(kw, r["bone_clear"]) for kw, r, _ in runs]
    keys = ("skin_count", "dense_count", "obj_count", "check_count")
    failed = [(kw, [int(r[k][-last:].max()) for k in keys]) for kw, r, last in runs
              if any(r[k][-last:].max() > 0 for k in keys)]
    assert not failed, failed


@pytest.mark.slow
def test_wide_wall_folds_without_the_wall_carry():
    """The same 30 mm plate 4 mm deep with Tuning.wall_carry 0 folds round its rims (the reference the
    test above improves on: a mechanism, not luck)."""
    r = run_wall(wall_case(0.015, 0.001, 0.004), 14, wall_carry=0.0)
    assert r["finite"] and r["skin_count"][-6:].max() > 0


@pytest.mark.slow
def test_wall_into_an_eminence():
    """A 24 mm plate 4 mm deep at the palm, one rim cutting into an eminence: clean over the last 3 of 16 frames."""
    assert_clean(run_wall(wall_case(0.012, 0.001, 0.004), 16), 3)


@pytest.mark.slow
def test_thick_wall_slanted():
    assert_clean(run_wall(wall_case(0.008, 0.002, 0.002, tilt=20.0), 16), 4)


def test_walls_are_thin_geoms_only():
    """Only thin geoms get face points pushed (no extra work for other objects)."""
    from physhand_mj.contact import Objects
    from physhand_mj.contact.inside import ObjectPoints, wall_half_thickness

    o = Objects("cpu", 8)
    o.add(GeomType.BOX, (0.02, 0.02, 0.0005), (0, 0, 0.1))  # a plate: a wall
    o.add(GeomType.BOX, (0.02, 0.02, 0.004), (0, 0, 0.2))  # 8 mm thick: not
    o.add(GeomType.BOX, (0.001, 0.001, 0.02), (0, 0, 0.3))  # a rod: a wall (the skin can close over it)
    o.add(GeomType.CYLINDER, (0.02, 0.001), (0, 0, 0.4))  # a disc: a wall
    o.add(GeomType.SPHERE, (0.01,), (0, 0, 0.5))
    o.add(GeomType.CAPSULE, (0.00085, 0.014), (0, 0, 0.6))  # a 1.7 mm rod: a wall
    o.add(GeomType.CYLINDER, (0.003, 0.02), (0, 0, 0.7))  # a 6 mm rod: not
    o.add(GeomType.BOX, (0.001, 0.001, 0.001), (0, 0, 0.8))  # a 2 mm cube, thin but not long: not
    assert [wall_half_thickness(o, g) > 0 for g in range(8)] == [True, False, True, True, False, True, False, False]
    pts = ObjectPoints(o)
    normal = pts.normal.numpy()
    on = np.linalg.norm(normal, axis=1) > 0
    assert on.sum() == pts.n_wall > 0
    assert set(pts.geom_host[on]) == {0, 2, 3, 5}
    # Tuning.wall_carry's broad walls: the plate and the disc, not the rods
    assert pts.wall_geom.tolist() == [1, 0, 0, 1, 0, 0, 0, 0]
    # the plate's face points' normals are their faces' (+-z on the broad faces), unit length
    plate = on & (pts.geom_host == 0)
    broad = plate & np.isclose(np.abs(pts.pts_host[:, 2]), 0.0005)
    assert broad.sum() > 0.9 * plate.sum()
    assert np.allclose(normal[broad][:, 2], np.sign(pts.pts_host[broad, 2]), atol=1e-5)
    assert np.allclose(np.linalg.norm(normal[plate], axis=1), 1.0, atol=1e-5)
    o2 = Objects("cpu", 1)
    o2.add(GeomType.SPHERE, (0.01,), (0, 0, 0.5))
    assert ObjectPoints(o2).n_wall == 0


def heldout_case(i):
    """Case ``i`` of the held-out generator's seed 0 (physhand_mj/bench/heldout.py), run for 20 frames
    (the last 10 held), its bones' clearance measured."""
    from physhand_mj.bench import heldout as H

    asset = ph.load_asset()
    h = H.draw_case(0, i, asset)
    h.clearance_mm = H.clearance_mm(h.case, asset)
    assert h.feasible, h.clearance_mm
    return h, H.verdict(h, run_case(h.case, ph.Config(device="cpu"), frames=20, asset=asset))


@pytest.mark.slow
def test_buried_rod():
    """Held-out rod122: a 1.7 mm capsule 28 mm long lying 2.9 mm deep in the palm, 94 % under the rest
    skin at the start (bones 7.1 mm clear). The skin must go down around it (before rods were walls:
    264 object points up to 7.3 mm inside the skin in every frame, the skin closed over it)."""
    h, v = heldout_case(122)
    assert h.kind == "rod" and h.embedded
    assert v["passed"], v


@pytest.mark.slow
def test_shell_dome_first():
    """Held-out shell46: an 88-degree 1 mm spherical cap shell, dome first, 3.1 mm into the proximal
    phalanx of the little finger (bones 0.65 mm clear; before the wall push: 334-722 skin samples)."""
    h, v = heldout_case(46)
    assert h.kind == "shell"
    assert v["passed"], v


@pytest.mark.parametrize("half,depth", [(0.03, 0.002), (0.03, 0.004), (0.03, 0.0), (0.02, 0.004)])
def test_wide_plates_cut_the_thumb(half, depth):
    """Issue 51's 60 mm plate (and a 40 mm one) face-first at the palm has no penetration-free skin:
    it passes through the thumb's metacarpal at the rest pose whatever its depth (docs/contact.md
    "Thin walls"), so a run of it is skipped by the feasibility rule (no solver run here)."""
    from physhand_mj.bench.cases import case_frame, case_position

    asset = ph.load_asset()
    case = wall_case(half, 0.001, depth)
    p0, n, quat = case_frame(case, asset)
    assert bone_clearance(asset, asset.positions, case_position(case, p0, n, depth), quat, case.size) < 0.0
