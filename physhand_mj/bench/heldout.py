"""Held-out contact cases: random objects at random skin sites, random depths (issue 51, item 3).

    cases = generate(seed=0, count=12, asset=asset)
    for h in cases:
        r = run_case(h.case, ph.Config(device="cpu"), frames=20, asset=asset)
        print(h.label, verdict(h, r))

Every case is drawn from ``numpy.random.default_rng([seed, i])``: case i is the same whatever the
count. Kinds, in turn (case i is ``KINDS[i % 7]``), sizes in mm:

- ``convex``: the hull of 8-30 points on an ellipsoid of semi-axes 3-12 (radii 0.6-1 of it);
- ``nonconvex``: a sphere (r 5-12) with 2-4 smooth dents 20-45 % of its radius deep, a star
  prism (4-7 points, r 6-15, notches 30-60 % of that, 3-12 high) or a torus (R 5-12, r 1.5-4);
- ``plate``: a 1 or 0.5 thick plate of 5-25 x 5-25, an analytic box or a 12-triangle mesh, pressed
  face first or edge first;
- ``rod``: an analytic capsule or cylinder of 1.5-3 diameter and 10-40 length, lying or end first;
- ``shell``: a spherical cap shell 1 thick, outer radius 5-15, cap half-angle 60-90 degrees (90: a
  hemisphere), rim first or dome first;
- ``cone``: apex angle 15-60 degrees, 5-20 high, analytic or a 12-32-section mesh, tip first;
- ``wedge``: a knife edge of 20-60 degrees, 5-25 long, 5-15 high, edge first.

Meshes are closed, consistently wound and enclose positive volume (checked here: ``Objects.add``
would repair or reject anything else). A placement is a skin vertex of the rest-pose hand (drawn in
proportion to its area, the forearm stub's last ``WRIST_MM`` excluded) and its outward normal; the
object's axis is turned about the normal by a random spin and tilted off it by up to ``TILT_DEG``,
and its deepest point ends 0.5-4 mm into the rest skin: pressed in from 2 mm outside over
``press_frames`` frames, or starting there (``embedded``). The frames from ``press_frames`` on are
held frames.

Feasibility: the bones' clearance from the object at its final pose, the smallest signed distance
of the contact's own object SDF (``sdf.geom_sdf`` on ``Objects.geoms_exact``, a small Warp kernel)
over points on the bones' surface (the rest-pose skeleton vertices, bones being still here, and an
order-``BONE_ORDER`` barycentric lattice on every bone triangle: the bones' edges are ~2.7 mm, so
their vertices alone miss a 0.5 mm plate). A case whose clearance is below ``CLEARANCE_MM`` has no
(or barely a) penetration-free skin: it is ``infeasible`` and reported apart from the pass rate.

Pass (:func:`verdict`): finite, and all four measures (skin samples inside on the order-5 and
order-9 lattices, object points and the denser check points inside the skin) zero at the last frame
and in every held frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from physhand_mj.bench.cases import Case, case_frame, case_position, cone_mesh, wedge
from physhand_mj.contact.metrics import phi_below
from physhand_mj.contact.sdf import GeomSet
from physhand_mj.types import GeomType

wp.set_module_options({"enable_backward": False})

KINDS = ("convex", "nonconvex", "plate", "rod", "shell", "cone", "wedge")
TILT_DEG = 30.0  # the object's axis leans off the skin normal by up to this
DEPTH_MM = (0.5, 4.0)  # the deepest object point's final depth into the rest skin
PRESS_START_MM = 2.0  # a pressed case starts this far outside the skin
WRIST_MM = 15.0  # skin within this of the skin's wrist end (the forearm stub's cut) is no site
CLEARANCE_MM = 0.5  # bones closer to the object than this (or inside it): infeasible
BONE_ORDER = 4  # barycentric lattice order on bone triangles (15 points, ~0.7 mm apart)
MESH_RANGE = 0.05  # m: run_case's mesh query range (objects here are at most ~40 mm)


@dataclass
class Heldout:
    """One generated case: ``case`` (run it with :func:`~physhand_mj.bench.cases.run_case`), its
    ``kind`` (one of KINDS) and ``shape`` (what was drawn, e.g. ``torus`` or ``box 1.0 mm face``),
    the skin ``vertex`` it sits at and the bone ``body`` nearest it, ``embedded`` (starts at its final
    depth) and the bones' ``clearance_mm`` from it at its final pose (negative: a bone inside)."""

    case: Case
    kind: str
    shape: str
    vertex: int
    body: str
    embedded: bool
    clearance_mm: float = float("nan")

    @property
    def feasible(self) -> bool:
        return bool(self.clearance_mm >= CLEARANCE_MM)

    @property
    def label(self) -> str:
        return (f"{self.case.name} ({self.shape}) at {self.body} v{self.vertex}, {self.case.depth * 1e3:.1f} mm "
                f"{'embedded' if self.embedded else 'pressed'}")


# ---------------------------------------------------------------------------------------- objects

def closed_mesh(vertices, faces):
    """A trimesh of (vertices, faces), merged, checked closed and wound outward (positive volume)."""
    import trimesh

    m = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=True)
    if not (m.is_watertight and m.is_winding_consistent):
        raise ValueError("generated mesh is not closed")  # a generator bug, never the user's
    if m.volume < 0:
        m.invert()
    return m


def _quat_axis(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.array([np.cos(angle / 2), *(np.sin(angle / 2) * a)])


FACE_UP = np.array([1.0, 0.0, 0.0, 0.0])
ACROSS = _quat_axis([1, 0, 0], np.pi / 2)  # the object's z axis across the press (its y axis along it)
FLIP = _quat_axis([1, 0, 0], np.pi)  # the object's -z leads


def _convex(rng):
    import trimesh

    n = int(rng.integers(8, 31))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = d * rng.uniform(3e-3, 12e-3, 3) * rng.uniform(0.6, 1.0, (n, 1))
    m = trimesh.convex.convex_hull(pts)
    return "hull", m.vertices, m.faces, FACE_UP


def _dented(rng):
    import trimesh

    r = rng.uniform(5e-3, 12e-3)
    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    u = m.vertices.copy()
    scale = np.ones(len(u))
    for _ in range(int(rng.integers(2, 5))):
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        ang = np.arccos(np.clip(u @ c, -1, 1))
        scale -= rng.uniform(0.2, 0.45) * np.exp(-(ang / rng.uniform(0.3, 0.7)) ** 2)
    # radial: the surface stays star-shaped about the centre, so it cannot pass through itself
    return "dented sphere", u * (r * np.maximum(scale, 0.3))[:, None], m.faces, FACE_UP


def _star(rng):
    import trimesh

    k = int(rng.integers(4, 8))
    r_out = rng.uniform(6e-3, 15e-3)
    r_in = r_out * rng.uniform(0.3, 0.6)
    h = rng.uniform(3e-3, 12e-3)
    ang = np.arange(2 * k) * np.pi / k
    poly = np.c_[np.cos(ang), np.sin(ang)] * np.where(np.arange(2 * k) % 2, r_in, r_out)[:, None]
    fan = [[0, 1 + i, 1 + (i + 1) % (2 * k)] for i in range(2 * k)]
    m = trimesh.creation.extrude_triangulation(np.vstack([[0, 0], poly]), fan, h)
    m.apply_translation([0, 0, -h / 2])
    return f"star prism {k}", m.vertices, m.faces, [FACE_UP, ACROSS][int(rng.integers(2))]


def _torus(rng):
    import trimesh

    big = rng.uniform(5e-3, 12e-3)
    small = min(rng.uniform(1.5e-3, 4e-3), 0.6 * big)
    m = trimesh.creation.torus(major_radius=big, minor_radius=small, major_sections=48, minor_sections=16)
    return "torus", m.vertices, m.faces, [FACE_UP, ACROSS][int(rng.integers(2))]


def cap_shell(r: float, thickness: float, top: float, rings: int = 16, sections: int = 48):
    """(vertices, faces): a spherical cap shell about the origin, outer radius ``r`` (m), ``thickness``
    (m), from its pole (+z) to the half-angle ``top`` (rad), closed by a flat rim."""
    t = np.linspace(0.0, top, rings + 1)[1:]
    a = np.arange(sections) * 2 * np.pi / sections
    ring = np.stack([np.outer(np.sin(t), np.cos(a)), np.outer(np.sin(t), np.sin(a)),
                     np.repeat(np.cos(t)[:, None], sections, 1)], -1).reshape(-1, 3)
    v = np.vstack([[0, 0, r], ring * r, [0, 0, r - thickness], ring * (r - thickness)])
    n = 1 + rings * sections  # vertices per side; side s's ring k, angle j: s n + 1 + k sections + j
    faces = []
    for s in (0, 1):
        o, flip = s * n, s == 1  # the inner side faces the centre
        for j in range(sections):
            j1 = (j + 1) % sections
            faces.append([o, o + 1 + j, o + 1 + j1])
            for k in range(rings - 1):
                a0, a1 = o + 1 + k * sections + j, o + 1 + k * sections + j1
                b0, b1 = a0 + sections, a1 + sections
                faces += [[a0, b0, b1], [a0, b1, a1]]
        if flip:
            faces[-sections * (2 * rings - 1):] = [f[::-1] for f in faces[-sections * (2 * rings - 1):]]
    last = 1 + (rings - 1) * sections
    for j in range(sections):  # the rim: outer last ring to inner last ring
        j1 = (j + 1) % sections
        a0, a1, b0, b1 = last + j, last + j1, n + last + j, n + last + j1
        faces += [[a0, b0, b1], [a0, b1, a1]]
    return v, np.asarray(faces)


def _shell(rng):
    top = np.radians(rng.uniform(60.0, 90.0))  # the cap's half-angle from the pole (+z)
    v, f = cap_shell(rng.uniform(5e-3, 15e-3), 1e-3, top)
    rim_first = bool(rng.integers(2))
    return (f"shell {np.degrees(top):.0f} deg {'rim' if rim_first else 'dome'} first", v, f,
            FLIP if rim_first else FACE_UP)


def draw_object(kind: str, rng) -> tuple:
    """(shape label, GeomType, size, vertices, faces, base quaternion): an object of ``kind`` in
    its own frame (m); the base quaternion turns it to how it meets the skin (its +z into the hand)."""
    import trimesh

    if kind == "convex":
        label, v, f, base = _convex(rng)
    elif kind == "nonconvex":
        label, v, f, base = (_dented, _star, _torus)[int(rng.integers(3))](rng)
    elif kind == "shell":
        label, v, f, base = _shell(rng)
    elif kind == "plate":
        t = (1e-3, 0.5e-3)[int(rng.integers(2))]
        half = np.array([*rng.uniform(2.5e-3, 12.5e-3, 2), t / 2])
        edge = bool(rng.integers(2))
        base = ACROSS if edge else FACE_UP
        label = f"{t * 1e3:.1f} mm {'edge' if edge else 'face'} first"
        if rng.integers(2):
            return f"box {label}", GeomType.BOX, tuple(half), None, None, base
        m = trimesh.creation.box(extents=2 * half)
        label, v, f = f"mesh plate {label}", m.vertices, m.faces
    elif kind == "rod":
        r, half = rng.uniform(0.75e-3, 1.5e-3), rng.uniform(5e-3, 20e-3)
        lying = rng.uniform() < 0.6
        gtype = (GeomType.CAPSULE, GeomType.CYLINDER)[int(rng.integers(2))]
        return (f"{gtype.name.lower()} d {2e3 * r:.1f} mm {'lying' if lying else 'end first'}", gtype,
                (r, half, 0.0), None, None, ACROSS if lying else FACE_UP)
    elif kind == "cone":
        angle, h = rng.uniform(15.0, 60.0), rng.uniform(5e-3, 20e-3)
        if rng.integers(2):
            return f"cone {angle:.0f} deg", GeomType.CONE, (h * np.tan(np.radians(angle) / 2), h, 0.0), None, None, \
                FACE_UP
        v, f = cone_mesh(angle, h, sections=int(rng.integers(12, 33)))
        label, base = f"mesh cone {angle:.0f} deg", FACE_UP
    elif kind == "wedge":
        angle = rng.uniform(20.0, 60.0)
        v, f = wedge(angle, length=rng.uniform(5e-3, 25e-3), height=rng.uniform(5e-3, 15e-3))
        label, base = f"wedge {angle:.0f} deg", FACE_UP
    else:
        raise ValueError(f"unknown kind '{kind}'; one of {', '.join(KINDS)}")
    m = closed_mesh(v, f)
    return label, GeomType.MESH, (0.0, 0.0, 0.0), m.vertices, m.faces, base


def support(gtype: GeomType, size, vertices, d: np.ndarray) -> float:
    """max over the object of p . d (m), d a unit direction in the object's frame."""
    s = np.asarray(size, float)
    lateral = float(np.hypot(d[0], d[1]))
    if gtype == GeomType.MESH:
        return float((np.asarray(vertices) @ d).max())
    if gtype == GeomType.SPHERE:
        return float(s[0])
    if gtype == GeomType.BOX:
        return float(np.abs(d) @ s)
    if gtype == GeomType.CAPSULE:
        return float(s[0] + s[1] * abs(d[2]))
    if gtype == GeomType.CYLINDER:
        return float(s[0] * lateral + s[1] * abs(d[2]))
    if gtype == GeomType.CONE:  # tip at the origin, base disc (radius s[0]) at z = -s[1]
        return float(max(0.0, -s[1] * d[2] + s[0] * lateral))
    raise ValueError(f"no support rule for {gtype!r}")


# ---------------------------------------------------------------------------------------- sites

def skin_sites(asset):
    """(skin vertex indices, their outward unit normals (V, 3), draw weights summing to 1): the
    rest skin's vertices, weighted by area, the last WRIST_MM at the wrist end left out."""
    import trimesh

    skin = asset.skin_vertices
    tm = trimesh.Trimesh(skin, asset.skin_faces, process=False)
    along = skin @ np.asarray(asset.meta["finger_axis"], float)
    keep = np.flatnonzero(along > along.min() + WRIST_MM * 1e-3)
    area = np.zeros(len(skin))
    np.add.at(area, tm.faces.ravel(), np.repeat(tm.area_faces / 3.0, 3))
    w = area[keep]
    return keep, np.asarray(tm.vertex_normals)[keep], w / w.sum()


def bone_points(asset, order: int = BONE_ORDER) -> np.ndarray:
    """(P, 3) m: points on the rest-pose bones' surface: the skeleton vertices and an order-``order``
    barycentric lattice on every bone triangle."""
    from physhand_mj.enums import Layer

    x = np.asarray(asset.positions, float)
    tri = x[np.asarray(asset.bone_faces)]
    ij = [(i, j) for i in range(order + 1) for j in range(order + 1 - i)]
    bary = np.array([(i / order, j / order, 1 - (i + j) / order) for i, j in ij])
    lattice = np.einsum("pk,tkd->tpd", bary, tri).reshape(-1, 3)
    return np.concatenate([x[np.asarray(asset.layer) == Layer.SKELETON], lattice])


@wp.kernel
def _phi_points(points: wp.array(dtype=wp.vec3), geoms: GeomSet, n: int, phi: wp.array(dtype=float)):
    # the objects' own SDF at each point (cap 1 km: every geom's exact SDF is evaluated)
    i = wp.tid()
    phi[i] = phi_below(points[i], geoms, 0, n, -1, 1.0e3)


def object_phi(case: Case, points: np.ndarray, asset, depth: float | None = None) -> np.ndarray:
    """(P,) m: the signed distance of ``case``'s object, at ``depth`` m (default its final depth),
    at ``points`` (P, 3), from the contact's own SDF (``Objects.geoms_exact`` on the CPU)."""
    from physhand_mj.contact import Objects

    p0, n, quat = case_frame(case, asset)
    pos = case_position(case, p0, n, case.depth if depth is None else depth)
    objs = Objects("cpu", 1)
    if case.gtype == GeomType.MESH:
        objs.add(GeomType.MESH, None, pos, quat, name=case.name, vertices=case.vertices, faces=case.faces,
                 mesh_range=MESH_RANGE, mesh_grid_spacing=0.0)
    else:
        objs.add(case.gtype, case.size, pos, quat, name=case.name)
    pts = wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device="cpu")
    phi = wp.empty(len(points), dtype=float, device="cpu")
    wp.launch(_phi_points, len(points), inputs=[pts, objs.geoms_exact, len(objs)], outputs=[phi], device="cpu")
    return phi.numpy().astype(float)


def clearance_mm(case: Case, asset, bones: np.ndarray | None = None) -> float:
    """The bones' clearance (mm) from ``case``'s object at its final pose (negative: a bone inside)."""
    bones = bone_points(asset) if bones is None else bones
    return float(object_phi(case, bones, asset).min() * 1e3)


# ---------------------------------------------------------------------------------------- cases

def draw_case(seed: int, i: int, asset, sites=None, press_frames: int = 10) -> Heldout:
    """Case ``i`` of ``seed`` (its clearance not yet measured: :func:`generate` does that)."""
    rng = np.random.default_rng([seed, i])
    kind = KINDS[i % len(KINDS)]
    label, gtype, size, v, f, base = draw_object(kind, rng)
    keep, normals, w = skin_sites(asset) if sites is None else sites
    k = int(rng.choice(len(keep), p=w))
    vertex, normal = int(keep[k]), normals[k].astype(float)
    spin = _quat_axis([0, 0, 1], rng.uniform(0, 2 * np.pi))
    lean = rng.uniform(0, 2 * np.pi)
    tilt = _quat_axis([np.cos(lean), np.sin(lean), 0.0], np.radians(rng.uniform(0.0, TILT_DEG)))
    from physhand_mj.rotations import compose_quat, quat_to_mat

    turn = compose_quat(compose_quat(tilt, spin), base)
    lead = support(gtype, size, v, quat_to_mat(turn).T @ np.array([0.0, 0.0, 1.0]))
    depth = rng.uniform(*DEPTH_MM) * 1e-3
    embedded = bool(rng.integers(2))
    case = Case(f"{kind}{i}", gtype, tuple(size), vertices=v, faces=f, lead=lead, site=f"v{vertex}", depth=depth,
                start=-depth if embedded else PRESS_START_MM * 1e-3, press_frames=press_frames,
                point=asset.skin_vertices[vertex].astype(float), normal=normal, turn=turn)
    return Heldout(case, kind, label, vertex, _nearest_body(asset, vertex), embedded)


def _nearest_body(asset, vertex: int) -> str:
    from physhand_mj.enums import Layer

    skel = np.flatnonzero(np.asarray(asset.layer) == Layer.SKELETON)
    j = skel[np.argmin(np.linalg.norm(asset.positions[skel] - asset.skin_vertices[vertex], axis=1))]
    return str(asset.body_names[int(asset.vertex_body[j])])


def generate(seed: int, count: int, asset, press_frames: int = 10) -> list[Heldout]:
    """``count`` held-out cases of ``seed``, their bone clearance measured."""
    sites, bones = skin_sites(asset), bone_points(asset)
    out = []
    for i in range(count):
        h = draw_case(seed, i, asset, sites, press_frames)
        h.clearance_mm = clearance_mm(h.case, asset, bones)
        out.append(h)
    return out


MEASURES = (("skin5", "skin_count", "skin_max_um"), ("skin9", "dense_count", "dense_max_um"),
            ("object", "obj_count", "obj_max_um"), ("check", "check_count", "check_max_um"))


def verdict(h: Heldout, r: dict) -> dict:
    """What run_case's rows ``r`` say of ``h``: ``passed`` (finite, the four measures zero at the last
    frame and in every held frame), ``failed`` (the measures that were not: skin5, skin9, object,
    check, or nonfinite), and per measure the worst count and depth (um) over the held frames and
    the last frame's."""
    held = slice(min(h.case.press_frames, len(r["ms"]) - 1), None)  # (the last frame at least)
    out, failed = {}, []
    for name, count, depth in MEASURES:
        c, d = np.asarray(r[count])[held], np.asarray(r[depth])[held]
        out[name] = dict(held_count=int(c.max()), held_max_um=round(float(d.max()), 2),
                         last_count=int(c[-1]), last_max_um=round(float(d[-1]), 2))
        if c.max() > 0:
            failed.append(name)
    if not r["finite"]:
        failed.append("nonfinite")
    return dict(passed=not failed, failed=failed, measures=out, finite=bool(r["finite"]),
                max_disp_mm=round(float(np.nanmax(r["max_disp_mm"])), 2), held_frames=len(r["ms"][held]))
