"""Sharp tips, knife edges and thin walls pressed into the palm and the fingertips (issue 14).

Each run: the embedded hand at rest in hand_only, one object (physhand_mj.bench.cases) pressed from 2 mm
outside to ``depth`` into the rest skin over 8 frames (or starting there), held 10 frames, pulled
20 mm out over 4 frames and left away 6 frames; default Config (multires, the object's features,
side-aware exits, the 25 mm tether). Asserted every frame: positions finite, no skin vertex over 25
mm from its rigidly carried position, tet volume within 2 %; while held: penetration by both
measures (order-9 skin samples in the object, object points in the skin) not growing (the second
half of the hold within the first half's worst + 2 samples / 20 um) and, for the cases that close,
zero; after the object left: no tet inverted, zero by both measures. Measured margins:
docs/stability.md.
"""

import numpy as np
import pytest
import trimesh

import physhand_mj as ph
from physhand_mj.bench.cases import Case, press_case
from physhand_mj.types import GeomType
from stress_harness import Stress, press_schedule

PRESS, HOLD, LEAVE, FREE = 8, 10, 4, 6
VOLUME_TOL = 0.02


def _run(scene, case, depth, first):
    run = Stress(scene, ph.Config(device="cpu"), case)
    for d in press_schedule(depth, first, PRESS if first != depth else 0, HOLD if first != depth else PRESS + HOLD,
                            LEAVE, FREE):
        run.frame(depth=d)
    return run


# (kind, site, depth m, first depth m: -0.002 = pressed in from 2 mm outside, = depth: starts there,
#  worst um allowed while held by either measure: 0 = clean from the end of the press)
SHARP = [
    ("cone_tip", "fingertip", 0.004, -0.002, 0.0),
    ("cone_tip", "palm", 0.006, 0.006, 400.0),  # the tip flickers in and out: 0-4 points, <= 279 um
    ("mesh_cone", "palm", 0.006, -0.002, 1000.0),  # its tip flickers: 0-3 points, <= 735 um
    ("knife", "fingertip", 0.004, 0.004, 50.0),  # one frame with 2 edge points, 3.5 um
    ("knife", "palm", 0.006, -0.002, 300.0),  # its edge flickers: 0-21 samples, <= 46 um (253 um before
    # the 4 um contact offset, 0.25 mm feature spacing and last feature push; 2026-11-25)
]
# um: how much the second half of the hold may exceed the first (not growing). A tip or edge held 6 mm
# deep whose deepest points flicker in and out by hundreds of micrometres frame to frame gets a
# flicker's slack (mesh cone, features 60 um out: skin 56 -> 112 um, object 452 -> 622 um between the
# halves; 1 um out: object 734 -> 488 um; the knife 6 mm in the palm: object points inside the skin
# per held frame 0, 0, 2, 0, 11 | 0, 28, 0, 0, 2 and order-9 samples 0, 0, 21, 0, 2 | 0, 0, 0, 0, 13
# (46 -> 34 um), with the settings before 2026-11-25 25 -> 10 samples, 253 -> 110 um: noise, no
# trend); every other case the harness's 20 um and 2 samples (x4 check points)
FLICKER_UM = 200.0  # the two tips held 6 mm deep
KNIFE_SLACK = {"grow_count": 5.0, "grow_um": 50.0}  # the knife held 6 mm deep: 20 check points, 50 um


@pytest.mark.parametrize("kind, site, depth, first, worst_um", SHARP)
def test_sharp_tip_or_knife_edge(scene, margins, kind, site, depth, first, worst_um):
    run = _run(scene, press_case(kind, site=site, depth=depth), depth, first)
    held = (PRESS, PRESS + HOLD)
    out = run.check(volume_tol=VOLUME_TOL, hold=held, free_from=PRESS + HOLD + LEAVE,
                    clean_after=PRESS if worst_um == 0 else None,
                    **({"grow_um": FLICKER_UM} if worst_um >= 400.0 else KNIFE_SLACK if worst_um >= 300.0 else {}))
    r = run.arrays()
    worst = max(np.nanmax(r["skin_max_um"][slice(*held)]), np.nanmax(r["obj_max_um"][slice(*held)]))
    assert worst <= max(worst_um, 0.0), f"held penetration {worst:.1f} um > {worst_um} um: {run.report()}"
    margins.update(out, case=f"{kind} {site}", depth_mm=depth * 1e3, start="deep" if first == depth else "press",
                   held_worst_um=round(float(worst), 1), held_bound_um=worst_um)


# thin walls: a 1 mm plate edge first (cases.py) and a 1 mm wall lying flat, its hand-facing face 0.3 mm into the skin
WALL = Case("wall", GeomType.BOX, (0.012, 0.012, 0.0005), lead=0.001)
# the same wall as a mesh (12 triangles): its floor comes from objects.mesh_half_thickness (0.5 mm)
_box = trimesh.creation.box(extents=(0.024, 0.024, 0.001))
WALL_MESH = Case("wall_mesh", GeomType.MESH, vertices=_box.vertices, faces=_box.faces, lead=0.001)
THIN = [
    ("plate", "palm", 0.004, -0.002, 50.0),
    ("plate", "fingertip", 0.004, 0.004, 50.0),
    # the wall's hand-facing face starts 0.3 mm into the palm, and its far edge lies in the skin rising
    # to the finger bases (the rest skin crosses the wall 3-4 mm inside that edge): the skin there is
    # pushed past the wall's mid-plane. Side-aware exits with the thickness floor (query.side_floor:
    # 0.05 mm for a 1 mm wall) keep it on the hand's side; measured held worst 7.6 um, object side 0
    # (with the fixed 0.5 mm floor it tunnelled: 300-1,050 samples, 200-505 points up to 4.6 mm)
    ("wall", "palm", 0.0008, 0.0008, 50.0),
    ("wall", "fingertip", 0.0008, 0.0008, 50.0),
    # the same wall as a 12-triangle mesh, its floor from objects.mesh_half_thickness (0.05 mm): with
    # the fixed floor it tunnels (432-1,043 samples 0.5 mm deep, object points to 3.8 mm, frames 0-15);
    # with it and features ending 1 um out the skin crossed for 4 frames of the hold (45-73 samples up
    # to 492 um, points to 586 um); with features 60 um out (Config.tuning.feature_offset) it holds
    ("wall_mesh", "palm", 0.0008, 0.0008, 50.0),
]


@pytest.mark.parametrize("kind, site, depth, first, worst_um", THIN)
def test_thin_wall(scene, margins, kind, site, depth, first, worst_um):
    import dataclasses

    walls = {"wall": WALL, "wall_mesh": WALL_MESH}
    case = dataclasses.replace(walls[kind], site=site) if kind in walls else press_case(kind, site=site, depth=depth)
    run = _run(scene, case, depth, first)
    held = (PRESS, PRESS + HOLD)
    out = run.check(volume_tol=VOLUME_TOL, hold=held, free_from=PRESS + HOLD + LEAVE)
    r = run.arrays()
    worst = max(np.nanmax(r["skin_max_um"][slice(*held)]), np.nanmax(r["obj_max_um"][slice(*held)]))
    assert worst <= worst_um, f"held penetration {worst:.1f} um > {worst_um} um: {run.report()}"
    margins.update(out, case=f"{kind} {site}", depth_mm=depth * 1e3, start="deep" if first == depth else "press",
                   held_worst_um=round(float(worst), 1), held_bound_um=worst_um)
