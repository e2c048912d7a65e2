"""Hard contact cases: sharp, thin and embedded objects pressed into the soft hand.

    case = press_case("cone_tip", site="fingertip", depth=0.003)
    result = run_case(case, ph.Config(device="cpu"), frames=30)

A case is an object (a geom of :class:`~physhand_mj.contact.Objects`: analytic or a trimesh-built
mesh) placed against a skin point of the embedded hand in its rest pose (``fingertip``: the index
finger's pad; ``palm``: the middle of the palm; ``fingers``: the middle finger's proximal phalanx, where a
plate lies across three fingers; or any skin point and normal: ``Case.point``, ``Case.normal``, as
physhand_mj/bench/heldout.py draws them), its axis along the skin's inward normal. The
object starts ``start`` m outside the skin (or inside, negative) and moves ``depth`` m into the
rest skin over ``press_frames`` frames, then holds; the bones do not move. :func:`run_case` runs
the solver and measures both penetration measures after every frame, plus a dense check (skin
samples on an order-``check_order`` lattice, which no strategy queries).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physhand_mj.rotations import compose_quat
from physhand_mj.types import GeomType

# the paper's cone experiment (section 4.2): physhand bench cone and the accuracy sweep's cone:paper
CONE = dict(radius=0.06, height=0.10)  # m: the analytic cone, tip at the origin
SHEET = dict(nx=50, ny=48, spacing=0.005, height=0.005)  # 2,400 vertices, 5 mm apart, 5 mm above the tip


SITES = ("fingertip", "palm", "fingers")


def rot_z_to(n: np.ndarray) -> np.ndarray:
    """Quaternion (w x y z) rotating +z onto unit vector n."""
    z = np.array([0.0, 0.0, 1.0])
    n = n / np.linalg.norm(n)
    c = float(z @ n)
    if c < -0.999999:
        return np.array([0.0, 1.0, 0.0, 0.0])
    a = np.cross(z, n)
    q = np.array([1.0 + c, *a])
    return q / np.linalg.norm(q)


def site_point(asset, site: str):
    """(skin point (3,), outward unit normal (3,)) of the rest-pose hand at ``site`` (m, asset frame)."""
    import trimesh

    if site not in SITES:
        raise ValueError(f"unknown site '{site}'; one of {', '.join(SITES)}")
    names = list(asset.body_names)
    skin = asset.skin_vertices
    tm = trimesh.Trimesh(skin, asset.skin_faces, process=False)
    vn = tm.vertex_normals
    palmar = np.asarray(asset.meta["palm_normal"], float)  # out of the palm
    axis = np.asarray(asset.meta["finger_axis"], float)
    if site == "fingertip":
        c = asset.body_rest_pos[names.index("distph2_r")] + 0.008 * axis
        near = np.flatnonzero(np.linalg.norm(skin - c, axis=1) < 0.012)
        k = near[np.argmax(vn[near] @ palmar)]  # the pad: the normal most along the palm's
    elif site == "fingers":  # the middle finger's palmar skin halfway along its proximal phalanx
        # (a plate there lies across the index, middle and ring proximal phalanges)
        c = asset.body_rest_pos[names.index("3proxph_r")] + 0.02 * axis
        lateral = np.linalg.norm((skin - c) - np.outer((skin - c) @ palmar, palmar), axis=1)
        near = np.flatnonzero(lateral < 0.005)
        k = near[np.argmax((skin[near] - c) @ palmar)]
    else:  # the palm's surface on the line through the middle metacarpal, 2 cm before its head
        c = asset.body_rest_pos[names.index("3proxph_r")] - 0.02 * axis
        lateral = np.linalg.norm((skin - c) - np.outer((skin - c) @ palmar, palmar), axis=1)
        near = np.flatnonzero(lateral < 0.01)
        k = near[np.argmax((skin[near] - c) @ palmar)]
    return skin[k].astype(float), vn[k].astype(float)


def case_frame(case: Case, asset):
    """(skin point (3,) m, outward unit normal (3,), geom quaternion (4,) w x y z) of ``case``: its
    site (named, or ``point``/``normal``) and the geom's orientation, its +z along the inward normal."""
    p0, n = (np.asarray(case.point, float), np.asarray(case.normal, float)) if case.point is not None \
        else site_point(asset, case.site)
    quat = compose_quat(rot_z_to(-n), np.array([np.cos(case.spin / 2), 0, 0, np.sin(case.spin / 2)]))
    if case.lay:  # a quarter turn about the geom x axis: its z axis lies across the normal
        quat = compose_quat(quat, np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]))
    if case.tilt:  # slanted: a turn about the geom x axis
        quat = compose_quat(quat, np.array([np.cos(case.tilt / 2), np.sin(case.tilt / 2), 0.0, 0.0]))
    if case.turn is not None:
        quat = compose_quat(quat, np.asarray(case.turn, float))
    return p0, n, quat


def case_position(case: Case, p0: np.ndarray, n: np.ndarray, depth_now: float) -> np.ndarray:
    """The geom's position (m) with its lead point (geom z = ``case.lead``) ``depth_now`` m into the
    rest skin along -n from the site ``p0``."""
    return p0 - n * depth_now - (-n) * case.lead


@dataclass
class Case:
    """An object against the hand: ``gtype``/``size`` (MuJoCo sizes) or a mesh (``vertices``,
    ``faces``) in the geom frame. It is mounted with its +z axis along the skin's inward normal;
    its leading point (what touches first) is at geom z = ``lead``, and the object extends toward
    -z (out of the hand)."""

    name: str
    gtype: GeomType
    size: tuple = (0.0, 0.0, 0.0)
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    lead: float = 0.0  # m: the geom-frame z of the object's leading point (what touches first)
    site: str = "fingertip"
    depth: float = 0.003  # m into the rest skin
    start: float = 0.002  # m outside the skin at frame 0 (negative: starts embedded)
    press_frames: int = 15
    spin: float = 0.0  # rad about the normal (orients edges)
    lay: bool = False  # turn the geom's z axis across the normal (a capsule lying on the skin)
    tilt: float = 0.0  # rad about the geom's x axis, after spin and lay (a plate pressed in slanted)
    # any skin site instead of a named one: ``point`` (3,) m and its outward unit ``normal`` (3,) in the
    # asset frame (``site`` is then only a label)
    point: np.ndarray | None = None
    normal: np.ndarray | None = None
    turn: np.ndarray | None = None  # a last rotation (w x y z) in the geom frame, after spin, lay and tilt


def wedge(angle_deg=30.0, length=0.02, height=0.012):
    """A knife edge: a triangular prism, its edge along x at z = 0 (the lead), opening toward -z."""
    half = height * np.tan(np.radians(angle_deg) / 2)
    prof = np.array([[0.0, 0.0], [-half, -height], [half, -height]])  # (y, z)
    import trimesh

    m = trimesh.convex.convex_hull(np.array([[sx * length / 2, y, z] for sx in (-1, 1) for y, z in prof]))
    return m.vertices.copy(), m.faces.copy()  # outward-wound


def cone_mesh(angle_deg=30.0, height=0.015, sections=24):
    import trimesh

    r = height * np.tan(np.radians(angle_deg) / 2)
    m = trimesh.creation.cone(radius=r, height=height, sections=sections)  # base at z=0, tip at z=h
    v = m.vertices.copy()
    v[:, 2] -= height  # tip at the origin
    return v, m.faces.copy()


def wall_case(half: float, thick: float, depth: float, site: str = "palm", start=None, tilt: float = 0.0) -> Case:
    """A square plate (a thin box) of half extent ``half`` and thickness ``thick`` (m), face-first
    ``depth`` m into the rest skin at ``site``: embedded from the start (``start`` None) or pressed in
    from ``start`` m outside over 10 frames; ``tilt`` (degrees) slants it (tests/test_thin_walls.py,
    benchmarks/wall_sections.py)."""
    emb = start is None
    return Case("wall", GeomType.BOX, (half, half, thick / 2), lead=thick / 2, site=site, depth=depth,
                start=-depth if emb else start, press_frames=1 if emb else 10, tilt=np.radians(tilt))


def press_case(kind: str, site: str = "fingertip", depth: float = 0.003, start: float = 0.002) -> Case:
    """Named cases: ``cone_tip`` (analytic cone, 2 x 17 degree half-angle), ``mesh_cone`` (a
    30-degree cone mesh, 24 sections), ``knife`` (30-degree wedge mesh), ``plate`` (a 1 mm box
    pressed edge-first), ``capsule`` (r 3 mm, pressed past its axis), ``coarse`` (an icosphere of
    20 faces, radius 8 mm: a coarse scan's corners), ``bone`` (a sphere of radius 5 mm whose lead
    goes ``depth`` into the skin: at the fingertip 6 mm puts the distal phalanx, 4.1 mm under the
    pad, inside it, so no penetration-free skin exists)."""
    import trimesh

    if kind == "cone_tip":
        return Case(kind, GeomType.CONE, (0.004, 0.012, 0.0), site=site, depth=depth, start=start)
    if kind == "mesh_cone":
        v, f = cone_mesh()
        return Case(kind, GeomType.MESH, vertices=v, faces=f, site=site, depth=depth, start=start)
    if kind == "knife":
        v, f = wedge()
        return Case(kind, GeomType.MESH, vertices=v, faces=f, site=site, depth=depth, start=start)
    if kind == "plate":
        return Case(kind, GeomType.BOX, (0.012, 0.0005, 0.008), lead=0.008, site=site, depth=depth, start=start,
                    spin=np.pi / 2)
    if kind == "capsule":  # lying across the skin; depth > 3 mm puts its axis inside the rest skin
        return Case(kind, GeomType.CAPSULE, (0.003, 0.01, 0.0), lead=0.003, site=site, depth=depth, start=start,
                    lay=True)
    if kind == "bone":
        return Case(kind, GeomType.SPHERE, (0.005, 0.0, 0.0), lead=0.005, site=site, depth=depth, start=start)
    if kind == "coarse":
        m = trimesh.creation.icosahedron()
        v = m.vertices * 0.008
        v = v - [0, 0, v[:, 2].max()]
        return Case(kind, GeomType.MESH, vertices=v, faces=m.faces, site=site, depth=depth, start=start)
    raise ValueError(f"unknown case '{kind}'")


def bone_case(site: str, depth: float, radius: float, asset) -> tuple:
    """An infeasible start (contact/bones.py): a sphere of ``radius`` m on the site's normal, embedded
    so that the skeleton vertex deepest inside it lies ``depth`` m inside (bisection over how far its
    lead point goes into the rest skin; the bones do not move). Returns (Case, the sphere's centre
    (3,) m, the skeleton's least clearance from it (m; about -depth, or less where the sphere
    cannot reach a bone less deep without holding another deeper))."""
    from physhand_mj.types import Layer

    skel = np.asarray(asset.positions)[np.asarray(asset.layer) == int(Layer.SKELETON)]
    p0, n = site_point(asset, site)

    def clearance(t):
        return float((np.linalg.norm(skel - (p0 + n * (radius - t)), axis=1) - radius).min())

    lo, hi = 0.0, 2.0 * radius
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if clearance(mid) > -depth else (lo, mid)
    case = Case("sphere", GeomType.SPHERE, (radius, 0.0, 0.0), lead=radius, site=site, depth=lo, start=-lo,
                press_frames=1)
    return case, p0 + n * (radius - lo), clearance(lo)


def run_case(case: Case, config, frames: int = 30, check_order: int = 9, asset=None, progress=None) -> dict:
    """Run ``case`` for ``frames`` frames; returns per-frame arrays of both measures
    (``skin_count``/``skin_max_um``: the order-5 metric; ``dense_count``/``dense_max_um``: order
    ``check_order``; ``obj_count``/``obj_max_um``: object points inside the skin; ``check_count``/
    ``check_max_um``: the denser object points of ``Contact.check_points``, which the contact never
    uses), the largest
    skin displacement from the rest shape (``max_disp_mm``), finiteness, ms per frame, the final
    skin (``skin``), the object's last pose (``object_pos`` m, ``object_quat`` w x y z) and the
    solver pieces (``solver``, ``state``, ``objects``)."""
    import time

    import physhand_mj as ph
    from physhand_mj.contact import Objects
    from physhand_mj.contact.metrics import summarize
    from physhand_mj.solver import Solver, make_model

    asset = asset if asset is not None else ph.load_asset()
    cfg = config.validate()
    p0, n, quat = case_frame(case, asset)
    objs = Objects(str(cfg.device or "cpu"), 1)

    def place(depth_now):
        return case_position(case, p0, n, depth_now)

    if case.gtype == GeomType.MESH:
        objs.add(GeomType.MESH, None, place(-case.start), quat, name=case.name, vertices=case.vertices,
                 faces=case.faces, mesh_range=0.05, mesh_grid_spacing=cfg.mesh_grid)
    else:
        objs.add(case.gtype, case.size, place(-case.start), quat, name=case.name)
    model = make_model(asset, cfg)
    solver = Solver(model, cfg, objects=objs)
    solver.warn_fast_motion = False
    state = solver.make_state()
    rest = state.x.numpy()[: asset.n_skin].astype(float).copy()
    rows = {k: [] for k in ("skin_count", "skin_max_um", "dense_count", "dense_max_um", "obj_count", "obj_max_um",
                            "check_count", "check_max_um", "max_disp_mm", "ms")}
    finite = True
    pos = place(-case.start)
    for f in range(frames):
        a = min((f + 1) / max(case.press_frames, 1), 1.0)
        pos = place(-case.start + a * (case.depth + case.start))
        objs.set_poses(pos[None], quat[None])
        t = time.perf_counter()
        solver.step(state)
        rows["ms"].append((time.perf_counter() - t) * 1e3)
        c = solver.contact
        m5 = summarize(c.measure(state, order=5))
        md = summarize(c.measure(state, order=check_order, check=True))
        x = state.x.numpy()[: asset.n_skin].astype(float)
        finite = finite and bool(np.all(np.isfinite(state.x.numpy())))
        rows["skin_count"].append(m5["penetration_count"])
        rows["skin_max_um"].append(m5["penetration_max_um"])
        rows["obj_count"].append(m5["object_in_skin_count"])
        rows["obj_max_um"].append(m5["object_in_skin_max_um"])
        rows["dense_count"].append(md["penetration_count"])
        rows["dense_max_um"].append(md["penetration_max_um"])
        rows["check_count"].append(md["object_in_skin_count"])
        rows["check_max_um"].append(md["object_in_skin_max_um"])
        rows["max_disp_mm"].append(float(np.nanmax(np.linalg.norm(x - rest, axis=1))) * 1e3)
        if progress is not None:
            progress(f)
    out = {k: np.asarray(v) for k, v in rows.items()}
    out.update(finite=finite, skin=state.x.numpy()[: asset.n_skin].astype(float), solver=solver, state=state,
               objects=objs, object_pos=pos, object_quat=quat)
    return out
