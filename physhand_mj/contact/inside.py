"""The closed skin as a volume: which object surface points lie inside the hand (second measure).

:class:`SkinVolume` keeps a ``wp.Mesh`` over the skin vertices of a solver ``State`` (the mesh's
points *are* the state's first ``n_skin`` positions; ``refit`` after they move) with Warp's fast
winding-number support: a point is inside the skin where the generalised winding number exceeds
1/2 (Jacobson et al. 2013), robust where the skin folds or touches itself at creases. Its depth is
the distance to the closest skin point.

:class:`ObjectPoints` holds the object surface points of :mod:`physhand_mj.contact.surface` for
every geom of an :class:`~physhand_mj.contact.Objects`, in the geoms' local frames (poses are read
per evaluation, so moving objects need no rebuild).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.sdf import geom_sdf_grad
from physhand_mj.contact.surface import PointKind, mesh_points, primitive_points
from physhand_mj.types import GeomType

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

INSIDE_RANGE = 0.05  # m: farthest a point inside the hand can be from the skin (the palm is ~3 cm thick)


# The BVH builder of the skin meshes: Warp picks LBVH on CUDA (built on the GPU, looser boxes) and
# SAH on the CPU; a refit keeps the tree's topology, and the feature queries (one GPU thread walks
# the tree per feature: latency-bound) visit fewer nodes in an SAH tree. Built once per state.
BVH_CONSTRUCTOR = "sah"
# triangles a leaf of a CUDA batch's winding-number skin mesh (Warp's bvh_leaf_size; one hand and the
# CPU keep Warp's default, 4). Its refit computes every node's dipole data once a frame, over every
# world's skin: a larger leaf means fewer nodes, while a query that opens a leaf sums more triangles
# exactly. H100, 1,024 skins (benchmarks/winding_leaf.py): the refit 7.49 / 4.61 / 2.96 / 2.13 ms at
# leaf 4 / 8 / 16 / 32, 20k queries 0.77 / 1.01 / 1.54 / 2.58 ms
WINDING_LEAF_SIZE = 16


class SkinVolume:
    """A ``wp.Mesh`` over ``x[:n_skin]`` with faces ``faces`` (F, 3); with ``winding`` (the measure's)
    it carries Warp's fast-winding-number data (a refit then costs ~15 x more: 1.3 vs 0.09 ms for
    10k triangles on a CPU), without it (the contact stage's) only the BVH."""

    def __init__(self, x, n_skin: int, faces, winding: bool = True, shift=None, worlds: int = 1):
        f = faces.numpy() if hasattr(faces, "numpy") else np.asarray(faces)
        # ``shift`` (n_skin,) vec3: the mesh holds x + shift (batched worlds at one origin queried
        # apart, Contact.set_query_offsets); :meth:`sync` copies it in before every refit
        self.x, self.shift = x[:n_skin], shift
        self.points = x[:n_skin] if shift is None else wp.zeros(n_skin, dtype=wp.vec3, device=x.device)
        if shift is not None:  # the BVH is built on the shifted points
            wp.launch(add_shift, n_skin, inputs=[self.x, shift], outputs=[self.points], device=x.device)
        self.mesh = wp.Mesh(points=self.points, indices=wp.array(np.asarray(f, np.int32).ravel(), dtype=wp.int32,
                                                                  device=x.device),
                            support_winding_number=winding, bvh_constructor=BVH_CONSTRUCTOR,
                            bvh_leaf_size=WINDING_LEAF_SIZE if winding and worlds > 1 and x.device.is_cuda else None)
        # the skin's bounding box (lower, upper), m; batched worlds (skins world by world): one per
        # world, world w's at [2 w, 2 w + 1] (a box over every world's skin, 1 m apart, culls nothing)
        self.worlds = max(int(worlds), 1)
        self.box = wp.zeros(2 * self.worlds, dtype=wp.vec3, device=x.device)

    def ops(self) -> list:
        """Refit the BVH (and winding-number data) to the current positions, and their bounding
        box, as operations for a solver frame (run them in order; :meth:`refit` runs them now)."""
        d = self.box.device
        per = max(self.points.shape[0] // self.worlds, 1)  # skin vertices per world
        return [*self.sync_ops(), self.mesh.refit,
                lambda: wp.launch(reset_box, self.worlds, inputs=[self.box], device=d),
                lambda: wp.launch(skin_box, self.points.shape[0], inputs=[self.points, per], outputs=[self.box],
                                  device=d)]

    def sync_ops(self) -> list:
        """Ops copying the positions (plus their shift) into the mesh's points (none unshifted)."""
        if self.shift is None:
            return []
        d = self.box.device
        return [lambda: wp.launch(add_shift, self.points.shape[0], inputs=[self.x, self.shift], outputs=[self.points],
                                  device=d)]

    def refit_ops(self) -> list:
        """:meth:`sync_ops` then the BVH refit (no bounding box)."""
        return [*self.sync_ops(), self.mesh.refit]

    def refit(self) -> None:
        for op in self.ops():
            op()


@wp.kernel
def add_shift(x: wp.array(dtype=wp.vec3), shift: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = x[i] + shift[i]


@wp.kernel
def shift_poses(pose: wp.array(dtype=wp.transform), offset: wp.array(dtype=wp.vec3), geoms_per_world: int,
                out: wp.array(dtype=wp.transform)):
    """out[g] = pose[g] moved by its world's query offset (world g // geoms_per_world)."""
    g = wp.tid()
    t = pose[g]
    out[g] = wp.transform(wp.transform_get_translation(t) + offset[g // geoms_per_world], wp.transform_get_rotation(t))


@wp.kernel
def reset_box(box: wp.array(dtype=wp.vec3)):
    w = wp.tid()
    box[2 * w] = wp.vec3(1.0e6)
    box[2 * w + 1] = wp.vec3(-1.0e6)


@wp.kernel
def skin_box(x: wp.array(dtype=wp.vec3), per_world: int, box: wp.array(dtype=wp.vec3)):
    """Bounding box of the points x per world (``per_world`` points each, world by world):
    box[2 w] = lower, box[2 w + 1] = upper (reset_box first)."""
    i = wp.tid()
    p = x[i]
    w = i // per_world
    wp.atomic_min(box, 2 * w, p)
    wp.atomic_max(box, 2 * w + 1, p)


@wp.func
def object_point(i: int, pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int),
                 pose: wp.array(dtype=wp.transform)):
    """World position of object point i (stored in its geom's frame)."""
    return wp.transform_point(pose[pts_geom[i]], pts[i])


@wp.func_native("""
return wp::mesh_query_winding_number(mesh, p, accuracy);
""")
def winding_number(mesh: wp.uint64, p: wp.vec3, accuracy: float) -> float:
    """Warp's fast winding number of ``mesh`` at ``p`` (Barill et al. 2018; the mesh needs
    ``support_winding_number``): what ``wp.mesh_query_point_sign_winding_number`` compares with its
    threshold, without that query's closest-point search (Warp 1.19 does not expose it in Python)."""
    ...


@wp.func
def inside_depth(skin: wp.uint64, p: wp.vec3, lower: wp.vec3, upper: wp.vec3):
    """Depth (m) of world point p inside the closed skin, 0 outside: inside where the winding number
    exceeds 1/2 and a skin point lies within INSIDE_RANGE; the depth is the distance to the closest
    one. ``wp.mesh_query_point_sign_winding_number(skin, p, INSIDE_RANGE)``'s answer, with its
    closest-point search run only for the points inside (the same search: the same face, u, v); most
    object points are outside, and their search was about half the measure's time."""
    if p[0] < lower[0] or p[1] < lower[1] or p[2] < lower[2] or p[0] > upper[0] or p[1] > upper[1] or p[2] > upper[2]:
        return 0.0
    if not (winding_number(skin, p, 2.0) > 0.5):  # (the query's default accuracy and threshold, its test)
        return 0.0
    q = wp.mesh_query_point_no_sign(skin, p, INSIDE_RANGE)
    if q.result:
        return wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v))
    return 0.0


@wp.func
def add_inside(out: wp.array2d(dtype=float), o: int, d: float):
    """One object point inside the skin at depth ``d`` (m) into row ``o``'s columns 3-5: count, sum
    of depths, deepest."""
    wp.atomic_add(out, o, 3, 1.0)
    wp.atomic_add(out, o, 4, d)
    wp.atomic_max(out, o, 5, d)


@wp.kernel
def reset_patches(motion: wp.array(dtype=float), lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3)):
    k = wp.tid()
    motion[k] = 0.0
    lower[k] = wp.vec3(1.0e6)
    upper[k] = wp.vec3(-1.0e6)


@wp.func
def skin_patch(i: int, per_world: int, skin_body: wp.array(dtype=int), bodies: int):
    """Skin vertex i's bone patch: its world's patch of its bone (Model.skin_body; ``bodies`` per
    world, at least 1: a skin without bones is one patch a world)."""
    b = skin_body[i]
    local = int(0)
    if b >= 0:
        local = b % bodies
    return (i // per_world) * bodies + local


@wp.kernel
def skin_patches(x: wp.array(dtype=wp.vec3), prev: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=int),
                 per_world: int, skin_body: wp.array(dtype=int), bodies: int, motion: wp.array(dtype=float),
                 lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3)):
    """Per patch of the skin: the skin triangles whose first corner is on one bone of one world
    (:func:`skin_patch`), every triangle in exactly one patch. Each patch's motion since ``prev``
    (m: the farthest any corner of its triangles moved; a triangle's points move no farther) and the
    bounding box of its triangles' corners now (reset_patches first; keep_points after)."""
    t = wp.tid()
    i0 = faces[t, 0]
    i1 = faces[t, 1]
    i2 = faces[t, 2]
    k = skin_patch(i0, per_world, skin_body, bodies)
    a = x[i0]
    b = x[i1]
    c = x[i2]
    m = wp.max(wp.max(wp.length(a - prev[i0]), wp.length(b - prev[i1])), wp.length(c - prev[i2]))
    wp.atomic_max(motion, k, m)
    wp.atomic_min(lower, k, wp.min(wp.min(a, b), c))
    wp.atomic_max(upper, k, wp.max(wp.max(a, b), c))


@wp.kernel
def keep_points(x: wp.array(dtype=wp.vec3), prev: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    prev[i] = x[i]


@wp.kernel
def keep_poses(pose: wp.array(dtype=wp.transform), prev: wp.array(dtype=wp.transform)):
    g = wp.tid()
    prev[g] = pose[g]


@wp.func
def box_distance(p: wp.vec3, lower: wp.vec3, upper: wp.vec3):
    """Distance (m) from p to the box [lower, upper] (0 inside it)."""
    return wp.length(wp.vec3(wp.max(wp.max(lower[0] - p[0], p[0] - upper[0]), 0.0),
                             wp.max(wp.max(lower[1] - p[1], p[1] - upper[1]), 0.0),
                             wp.max(wp.max(lower[2] - p[2], p[2] - upper[2]), 0.0)))


def points_inside_source(reuse: bool):
    """The Python function of an object-side measure kernel, for ``wp.kernel``:
    :func:`object_points_inside` or, ``reuse``, :func:`object_points_inside_reuse`; both take the
    same arguments (the first reads none of ``prev_pose``, ``geom_radius``, ``motion``,
    ``patch_lower``, ``patch_upper``, ``bodies`` and ``slack``: None, 0)."""
    REUSE = bool(reuse)

    def kernel(
        skin: wp.uint64,
        box: wp.array(dtype=wp.vec3),
        pts: wp.array(dtype=wp.vec3),
        pts_geom: wp.array(dtype=int),
        pose: wp.array(dtype=wp.transform),
        prev_pose: wp.array(dtype=wp.transform),
        geom_radius: wp.array(dtype=float),
        motion: wp.array(dtype=float),
        patch_lower: wp.array(dtype=wp.vec3),
        patch_upper: wp.array(dtype=wp.vec3),
        bodies: int,
        geom_count: wp.array(dtype=int),
        geom_obj: wp.array(dtype=int),
        obj_filter: int,
        row: int,
        geoms_per_world: int,
        rows_per_world: int,
        out: wp.array2d(dtype=float),
        depth: wp.array(dtype=float),
        slack: wp.array(dtype=float),
    ):
        i = wp.tid()
        g = pts_geom[i]
        if g >= geom_count[0]:
            depth[i] = 0.0
            return
        w = g // geoms_per_world
        d = float(0.0)
        if wp.static(REUSE):
            t0 = prev_pose[g]
            t1 = pose[g]
            dq = wp.mul(wp.quat_inverse(wp.transform_get_rotation(t0)), wp.transform_get_rotation(t1))
            p = wp.transform_point(t1, pts[i])
            # how far the point can have come (m), with float rounding at the query's coordinates (worlds are
            # queried up to tens of metres out: ~16 ulp there, and 1 um)
            own = (wp.length(wp.transform_get_translation(t1) - wp.transform_get_translation(t0))
                   + 2.0 * wp.length(wp.vec3(dq[0], dq[1], dq[2])) * geom_radius[g] + 1.0e-6 + 2.0e-6 * wp.length(p))
            s0 = slack[i]
            s = float(0.0)
            if s0 > 0.0:
                s = float(1.0e6)
                for k in range(w * bodies, (w + 1) * bodies):
                    s = wp.min(s, wp.max(s0, box_distance(p, patch_lower[k], patch_upper[k])) - motion[k])
                s = s - own
            if (obj_filter < 0 or geom_obj[g] == obj_filter) and not (s > 0.0):
                lo = box[2 * w]
                hi = box[2 * w + 1]
                s = box_distance(p, lo, hi)
                if s <= 0.0:  # in the skin's box: the winding number, the distance to the skin
                    q = wp.mesh_query_point_no_sign(skin, p, INSIDE_RANGE)
                    s = 0.0  # (no skin within INSIDE_RANGE: outside by the measure's definition; asked again)
                    if q.result:
                        s = wp.length(p - wp.mesh_eval_position(skin, q.face, q.u, q.v))
                        if winding_number(skin, p, 2.0) > 0.5:  # inside: its depth, and asked every time
                            d = s
                            s = 0.0
            slack[i] = s
        elif obj_filter < 0 or geom_obj[g] == obj_filter:
            d = inside_depth(skin, object_point(i, pts, pts_geom, pose), box[2 * w], box[2 * w + 1])
        depth[i] = d
        if d > 0.0:
            add_inside(out, w * rows_per_world + row, d)

    kernel.__name__ = kernel.__qualname__ = "object_points_inside_reuse" if REUSE else "object_points_inside"
    return kernel


object_points_inside = wp.kernel(points_inside_source(False))
""" Object surface points (geom-local ``pts`` of geom ``pts_geom``) inside the skin: adds into
out[row, 3:6] [count, sum of depths m, max depth m]; depth[i] (m, 0 outside) per point.
``obj_filter`` >= 0 keeps only that object's points. Batched worlds (physhand_mj/batch.py): the
point of geom g belongs to world w = g // ``geoms_per_world``, is tested only where it lies in
world w's skin box (``box[2 w]``, ``box[2 w + 1]``: outside it no point is inside the closed skin)
and adds into row w ``rows_per_world`` + ``row`` (one world: the geom capacity, w = 0)."""
object_points_inside_reuse = wp.kernel(points_inside_source(True))
""" :func:`object_points_inside`, asking again only the points whose answer could have changed
(``Config.execution.reuse_outside``). ``slack[i]`` (m) is a lower bound of point i's distance to the skin
(0: ask it). Since it was taken, each skin patch P of the point's world (skin_patches: every
skin triangle belongs to one patch, whose box holds its corners now, and its points moved no
farther than its corners, at most ``motion[P]``) stayed at least max(slack, its box's distance
now) - motion[P] from the point, all along
the way, and the point moved at most |dt| + 2 sin(theta / 2) ``geom_radius`` with its geom (pose
against ``prev_pose``). While the smallest of these stays positive the skin has not crossed the
point, so it is still outside, and that bound is its new slack. A point asked again gets its
distance to the skin (Warp's closest-point search), or to its world's skin box where it lies
outside that box, or 0 inside the skin."""


class ObjectPoints:
    """Surface points of every geom of ``objects`` (geom-local), built once on the host.

    Arrays: ``pts`` (P,) vec3 m, ``geom`` (P,) int, ``kind`` (P,) int (:class:`PointKind`), and
    ``feature`` (the indices of the CORNER and EDGE points) for the contact stage."""

    def __init__(self, objects, edge_spacing: float = 5e-4, surface_spacing: float = 1e-3, edge_subdivide: int = 1,
                 geoms=None, shapes: dict | None = None):
        """``geoms``: only these geoms' points (indices into ``objects``; default all), e.g. a few
        worlds of a batch at a time; ``shapes``: a dict of the shapes sampled so far, to share
        between such pieces (filled here)."""
        geoms = range(len(objects.names)) if geoms is None else [int(g) for g in geoms]
        made = {} if shapes is None else shapes
        keys = self.shapes(objects, geoms, made, edge_spacing, surface_spacing, edge_subdivide)
        # the batch's copies written into arrays made once (W = 4,096 bowls: 220 million points; appending and
        # joining W pieces took ~45 s on the host)
        d = objects.device
        self.n_geoms = len(objects.names)
        counts = np.array([len(made[key][0]) for key in keys], np.int64)
        total = int(counts.sum())
        pts, kind = np.zeros((total, 3)), np.zeros(total, np.int32)
        pts32 = np.zeros((max(total, 1), 3), np.float32)
        o = 0
        for key, c in zip(keys, counts):
            p, k, p32, _ = made[key]
            pts[o:o + c], kind[o:o + c], pts32[o:o + c] = p, k, p32
            o += c
        self.kind_host = kind
        self.geom_host = np.repeat(np.asarray(geoms, dtype=np.int32), counts)
        self.pts_host = pts
        n = max(total, 1)
        self.pts = wp.array(pts32, dtype=wp.vec3, device=d)
        self.geom = wp.array(self.geom_host if total else np.full(1, 1 << 30, np.int32), dtype=int, device=d)
        self.kind = wp.array(kind if total else np.zeros(1, np.int32), dtype=int, device=d)
        # the contact's pushed points: the sharp features (corners, edges) and the faces of walls
        # (wall_half_thickness: a thin geom's face can lie wholly inside the hand, where no skin
        # sample is inside it and no feature is near the skin; docs/contact.md "Thin walls")
        half = np.array([wall_half_thickness(objects, g) for g in range(self.n_geoms)] or [0.0])
        # per geom: 1 a broad wall, a plate or a shell (Tuning.wall_carry: wall_is_broad)
        self.wall_geom = np.array([int(half[g] > 0.0 and wall_is_broad(objects, g)) for g in range(self.n_geoms)],
                                  np.int32)
        on_wall = (kind == int(PointKind.SURFACE)) & (half[self.geom_host] > 0.0) if total else np.zeros(0, bool)
        # per point its geom-local outward normal where it is a wall's face point (the push's gate,
        # features.push_feature), zero elsewhere; a point of the wall's rim (its thin sides, whose
        # sharp edges are features already) is no face point: pushed along its normal, it drags
        # the skin sideways across the wall (the stress suite's 24 mm mesh wall: 30-100 skin
        # samples at the wall's mid-plane for 10 frames, against 5 with the faces alone)
        normal = np.zeros((max(total, 1), 3), np.float32)
        if on_wall.any():
            idx = np.flatnonzero(on_wall)
            nn, face = wall_normals(objects, self.geom_host[idx], pts[idx], half[self.geom_host[idx]])
            on_wall[idx[~face]] = False
            normal[idx[face]] = nn[face]
        feat = np.flatnonzero((kind != int(PointKind.SURFACE)) | on_wall).astype(np.int32)
        self.n_features = len(feat)
        self.n_wall = int(on_wall.sum())
        self.normal = wp.array(normal, dtype=wp.vec3, device=d)
        self.feature = wp.array(feat if len(feat) else np.zeros(1, np.int32), dtype=int, device=d)
        self.depth = wp.zeros(n, dtype=float, device=d)
        # per geom: the farthest of its points from its origin (m; how far a turn can carry them)
        rad = np.zeros(max(self.n_geoms, 1))
        rad[list(geoms)] = [made[key][3] for key in keys]
        self.geom_radius = wp.array(rad, dtype=float, device=d)

    @staticmethod
    def shapes(objects, geoms, made: dict, edge_spacing: float = 5e-4, surface_spacing: float = 1e-3,
               edge_subdivide: int = 1) -> list:
        """The shape key of each of ``geoms``, each distinct shape sampled once into ``made`` (key ->
        (points, kinds, points in float32, the farthest point's distance from the geom's origin (m; how
        far a turn can carry them))): a batch's W worlds share theirs (a mesh: ~0.3 s each)."""
        h = objects._host
        meshes = {int(m.id): m for m in objects._meshes}
        keys = []
        for g in geoms:
            t = GeomType(int(h["gtype"][g]))
            key = (int(t), int(h["mesh"][g][0])) if t == GeomType.MESH else (int(t), *map(float, h["size"][g]))
            key = (*key, float(edge_spacing), float(surface_spacing), int(edge_subdivide))
            if key not in made:
                if t == GeomType.MESH:
                    m = meshes[key[1]]
                    p, k = mesh_points(m.points.numpy(), m.indices.numpy().reshape(-1, 3), edge_spacing,
                                       surface_spacing, edge_subdivide=edge_subdivide)
                else:
                    p, k = primitive_points(t, h["size"][g], edge_spacing, surface_spacing, edge_subdivide)
                made[key] = (p, k, p.astype(np.float32), float(np.linalg.norm(p, axis=1).max()) if len(p) else 0.0)
            keys.append(key)
        return keys

    def __len__(self) -> int:
        return len(self.pts_host)


# A wall: a geom thin enough that the skin can close over it, lying wholly inside the hand with the
# skin on one side of it (a plate pressed face-first, a shell, a rod lying in the palm): half-thickness
# at most WALL_HALF (m), at most WALL_ASPECT x its longest extent. Thicker objects meet the skin
# before their far side is inside the hand (Eq. 9 acts on the skin inside them); walls are thinner
# than the skin's triangles and than a substep's flesh motion, so the skin can also pass wholly
# through them.
WALL_HALF = 1.5e-3
WALL_ASPECT = 0.5


def wall_extents(objects, g: int) -> tuple:
    """(half-thickness, breadth, across) (m) of geom ``g`` of ``objects`` as a wall would have them:
    a box's least, middle and largest half extent (a plate or a rod); a cylinder's least of radius
    and half height, its radius (a disc's breadth; a rod's round section: its half-thickness again)
    and the larger of the two; a capsule's radius, radius, and radius + half length (a rod); a mesh's
    measured half-thickness (objects.mesh_half_thickness: plates and shells of even thickness; 0 for
    others), an unmeasured breadth (inf) and its bounding radius; (0, 0, 0) for other types."""
    h = objects._host
    t = GeomType(int(h["gtype"][g]))
    s = np.asarray(h["size"][g], float)
    if t == GeomType.BOX:
        e = np.sort(s)
        return float(e[0]), float(e[1]), float(e[2])
    if t == GeomType.CYLINDER:
        return float(min(s[0], s[1])), float(s[0]), float(max(s[0], s[1]))
    if t == GeomType.CAPSULE:
        return float(s[0]), float(s[0]), float(s[0] + s[1])
    if t == GeomType.MESH:
        return float(s[2]), float("inf"), float(h["radius"][g])
    return 0.0, 0.0, 0.0


def wall_half_thickness(objects, g: int) -> float:
    """Half the thickness (m) of geom ``g`` of ``objects`` where it is a wall, else 0: its
    half-thickness (:func:`wall_extents`) where that is at most WALL_HALF and at most WALL_ASPECT x
    the geom's largest extent."""
    half, _, across = wall_extents(objects, g)
    return half if 0.0 < half <= WALL_HALF and half <= WALL_ASPECT * across else 0.0


def wall_is_broad(objects, g: int) -> bool:
    """Whether wall ``g`` (:func:`wall_half_thickness` > 0) is broad, a plate or a shell, not a rod:
    its breadth at least twice its half-thickness (:func:`wall_extents`: a box's middle half extent,
    a disc's radius; a rod's round section never; a mesh's breadth is not measured: broad). Across a
    broad wall's face the skin is dragged far enough to fold over its rims (Tuning.wall_carry); round
    a rod it is not."""
    half, breadth, _ = wall_extents(objects, g)
    return breadth >= 2.0 * half


@wp.kernel
def surface_normals(pts: wp.array(dtype=wp.vec3), geom: wp.array(dtype=int), half: wp.array(dtype=float),
                    gtype: wp.array(dtype=int), size: wp.array(dtype=wp.vec3), mesh: wp.array(dtype=wp.vec2ul),
                    out: wp.array(dtype=wp.vec3), face: wp.array(dtype=int)):
    """out[i] = the unit SDF gradient of geom ``geom[i]`` at its local surface point ``pts[i]``;
    face[i] = 1 where the wall's other face lies across it (phi back on the surface, within half of
    ``half[i]``, two half-thicknesses in along the normal), 0 on a rim (deep inside there)."""
    i = wp.tid()
    g = geom[i]
    d, n = geom_sdf_grad(gtype[g], pts[i], size[g], mesh[g])
    n = wp.normalize(n)
    out[i] = n
    h = half[i]
    across, m = geom_sdf_grad(gtype[g], pts[i] - n * (2.0 * h), size[g], mesh[g])
    face[i] = wp.where(across > -0.5 * h, 1, 0)


def wall_normals(objects, geom: np.ndarray, pts: np.ndarray, half: np.ndarray) -> tuple:
    """((n, 3) float32 geom-local outward unit normals, (n,) bool face) at points ``pts`` on the
    surfaces of walls ``geom`` of half-thickness ``half`` (m): the SDF's gradient there (a box's or a
    disc's face normal, a mesh's pseudo normal), and whether the point lies on one of the wall's two
    broad faces (its other face two half-thicknesses in), not on its rim."""
    d = objects.device
    gs = objects.geoms_exact
    out = wp.zeros(len(pts), dtype=wp.vec3, device=d)
    face = wp.zeros(len(pts), dtype=int, device=d)
    wp.launch(surface_normals, len(pts), inputs=[wp.array(np.asarray(pts, np.float32), dtype=wp.vec3, device=d),
                                      wp.array(np.asarray(geom, np.int32), dtype=int, device=d),
                                      wp.array(np.asarray(half, np.float32), dtype=float, device=d), gs.gtype, gs.size,
                                      gs.mesh], outputs=[out, face], device=d)
    return out.numpy(), face.numpy().astype(bool)
