"""Which skin triangles can touch an object: so contact cost follows contact area.

A triangle with centroid c and circumradius r (largest centroid-vertex distance) cannot reach a
geom if phi(c) - r > margin: every SDF is 1-Lipschitz, so no point of the triangle is closer. The
cheap bound |c - o| - R (bounding sphere, centre o, radius R) is tried first, the exact phi(c)
(one query) only for triangles inside it. Surviving triangles are compacted into a list with an
atomic counter, each with the bit mask of the geoms it can reach.

Two levels: once per frame over all triangles with ``Config.contact_frame_margin`` (m: covers the
skin's and the objects' motion within the frame), then every substep over that frame list only
with ``Config.tuning.contact_margin`` (m: covers the motion within one contact stage). Between the passes
of one stage, :func:`keep_moved` keeps only triangles a pass moved: a triangle none of whose
vertices moved has the same decision point as before, which did not penetrate; nor does one whose
lowest phi exceeds how far its vertices moved (1-Lipschitz again), within a stage
(:func:`keep_moved`) and across the stages of a frame (:func:`first_pass_keeps`; objects do not move
within a frame). (A compacted list,
not an early return in the query kernel: Warp's CPU threads copy every array argument, so a
thread of the query kernel costs ~90 ns even when it returns at once.)
"""

import warp as wp

from physhand_mj.contact.sdf import MESH, GeomSet, geom_sdf
from physhand_mj.contact.sdf_mesh import GRID_OFF, grid_lower, grid_node

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

# a mesh's distance grid also accepts the triangles its upper bound proves near (the nearest node's
# distance plus the way to it), without the exact query; False: only its lower bound (for timings)
USE_GRID_UPPER = wp.constant(True)


@wp.struct
class TriList:
    """A triangle list as the kernels take it: skin triangle indices (into ``Model.skin_faces``) and
    per entry the bit mask of its world's geoms near it (:func:`reach_mask`). Made once with its
    arrays (data.FrameLists); its length is a counter slot that changes per pass, passed beside it
    (a recorded launch keeps its arguments)."""

    tri: wp.array(dtype=int)
    mask: wp.array(dtype=int)


def tri_list(tri, mask) -> TriList:
    """A :class:`TriList` over the arrays ``tri`` and ``mask``."""
    s = TriList()
    s.tri, s.mask = tri, mask
    return s


NO_LIST = TriList()  # where a kernel reads no list (find_active's src and out): Warp takes no None for a struct


@wp.func
def triangle_bound(a: wp.vec3, b: wp.vec3, c: wp.vec3):
    """(centroid, circumradius about it): every point of the triangle lies within r of m."""
    m = (a + b + c) * (1.0 / 3.0)
    return m, wp.max(wp.length(a - m), wp.max(wp.length(b - m), wp.length(c - m)))


@wp.func
def world_geoms(t: int, tris_per_world: int, geoms_per_world: int, count: int):
    """[g0, g1): the geoms in use of the world of triangle ``t`` (worlds hold ``tris_per_world``
    triangles and ``geoms_per_world`` geoms each, in blocks)."""
    g0 = (t // tris_per_world) * geoms_per_world
    return g0, wp.min(g0 + geoms_per_world, count)


@wp.func
def reach_mask(t: int, allowed: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), geoms: GeomSet,
               tris_per_world: int, geoms_per_world: int, margin: float):
    """The bit mask of the geoms (of those in ``allowed``) that skin triangle ``t`` can reach within
    ``margin`` (m); 0: none (:func:`find_active`)."""
    m, r = triangle_bound(x[faces[t, 0]], x[faces[t, 1]], x[faces[t, 2]])
    mask = int(0)
    g0, g1 = world_geoms(t, tris_per_world, geoms_per_world, geoms.count[0])
    for g in range(g0, g1):
        bit = int(1 << 30)
        if g - g0 < 31:
            bit = 1 << (g - g0)
        if (allowed & bit) == 0:
            continue
        q = wp.transform_point(geoms.inv_pose[g], m)
        if wp.length(q) - geoms.radius[g] - r <= margin:
            ids = geoms.mesh[g]
            if geoms.gtype[g] == MESH and ids[1] != wp.uint64(0):  # the grid decides what it can prove, in one read:
                dc, s = grid_node(ids[1], q)  # phi(q) within dc -+ s
                # near for sure (on the grid, within the query range, where the exact query answers phi)
                if USE_GRID_UPPER and dc > 0.5 * GRID_OFF and dc + s - r <= margin and wp.abs(dc) + s <= geoms.size[g][0]:
                    mask = mask | bit
                    continue
                if grid_lower(dc, s) - r > margin:  # far for sure
                    continue
                ids = wp.vec2ul(ids[0], wp.uint64(0))  # the rest: the exact distance, once
            if geom_sdf(geoms.gtype[g], q, geoms.size[g], ids) - r <= margin:
                mask = mask | bit  # the world's geoms >= 31 share bit 30: the triangle is active, they are always tried
    return mask


@wp.func
def keep_if_moved(t: int, mask: int, faces: wp.array2d(dtype=int), moved: wp.array(dtype=int),
                  disp: wp.array(dtype=float), stamp: int, bound: wp.array(dtype=float), out: TriList,
                  out_count: wp.array(dtype=int)):
    """:func:`keep_moved` for active triangle ``t`` (broadphase mask ``mask``)."""
    m = float(0.0)
    for j in range(3):
        v = faces[t, j]
        if moved[v] == stamp:
            m = wp.max(m, disp[v])
    if m == 0.0:
        return
    if bound[t] > m:
        bound[t] = bound[t] - m
        return
    slot = wp.atomic_add(out_count, 0, 1)
    out.tri[slot] = t
    out.mask[slot] = mask


@wp.kernel
def keep_moved(
    faces: wp.array2d(dtype=int),
    active: TriList,
    active_count: wp.array(dtype=int),
    moved: wp.array(dtype=int),
    disp: wp.array(dtype=float),
    stamp: int,
    bound: wp.array(dtype=float),
    counters: wp.array(dtype=int),
    flag_slots: wp.array(dtype=int),
    pass_move: wp.array(dtype=float),
    stage_tol: wp.array(dtype=float),
    stage: int,
    out: TriList,
    out_count: wp.array(dtype=int),
    flag: wp.array(dtype=wp.int32),
):
    """Next contact pass: the triangles of the stage's ``active`` list that the last pass moved
    (``moved[i] == stamp`` for a vertex, by ``disp[i]``) and that can now reach an object: a point
    of a triangle moves at most as far as its farthest vertex, so a lowest phi ``bound[t]`` above
    that displacement m stays positive (the bound drops by m and the triangle is skipped).
    Thread 0 also sets ``flag[0]`` to 1 when one of ``counters`` at ``flag_slots`` (the last pass's
    touched vertices) is not zero, else 0: whether the next pass runs at all (activity.py level 2, a
    conditional graph node on CUDA); with Config.tuning.contact_pass_tol (``pass_move`` not empty) also
    only when the last pass's largest move pass_move[stamp] exceeds its stage's ``stage_tol``
    (0 in the frame's last stage), and a pass that will not run gets an empty list. Launch at least
    one thread."""
    k = wp.tid()
    go = True
    if pass_move.shape[0] > 0:
        tol = stage_tol[stage]
        go = tol <= 0.0 or pass_move[stamp] > tol
    if k == 0:
        total = int(0)
        for j in range(flag_slots.shape[0]):
            total += counters[flag_slots[j]]
        flag[0] = wp.where(go and total > 0, 1, 0)
    if k >= active_count[0] or not go:
        return
    keep_if_moved(active.tri[k], active.mask[k], faces, moved, disp, stamp, bound, out, out_count)


@wp.func
def first_pass_keeps(t: int, mask: int, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3),
                     bound: wp.array(dtype=float), bound_mask: wp.array(dtype=int), eval_x: wp.array2d(dtype=wp.vec3)):
    """Whether active triangle ``t`` (near the geoms of ``mask``) goes into its stage's first-pass
    list: not when an earlier stage of this frame found it clear by ``bound[t]`` (m) that is still
    above how far its vertices moved since (``eval_x``: their positions then) and that was taken
    over all the geoms now near it (``bound_mask``); such a triangle keeps a bound lowered by that
    distance, re-anchored."""
    a = x[faces[t, 0]]
    b = x[faces[t, 1]]
    c = x[faces[t, 2]]
    m = wp.max(wp.length(a - eval_x[t, 0]), wp.max(wp.length(b - eval_x[t, 1]), wp.length(c - eval_x[t, 2])))
    if bound[t] > m and (mask & ~bound_mask[t]) == 0:  # the bound covers every geom now near
        bound[t] = bound[t] - m
        eval_x[t, 0] = a
        eval_x[t, 1] = b
        eval_x[t, 2] = c
        return False
    return True


def list_source(stage: bool):
    """The Python function of a triangle-list kernel, for ``wp.kernel``: :func:`find_active` (the
    frame's list over every triangle) or, ``stage``, :func:`stage_lists` (a stage's two lists over
    the frame's list ``src``). Both take the same arguments; find_active reads no ``src``, ``bound``,
    ``bound_mask``, ``eval_x`` nor ``out`` (None; :data:`NO_LIST` for the lists)."""
    STAGE = bool(stage)

    def kernel(
        faces: wp.array2d(dtype=int),
        x: wp.array(dtype=wp.vec3),
        geoms: GeomSet,
        tris_per_world: int,
        geoms_per_world: int,
        margin: float,
        src: TriList,
        src_count: wp.array(dtype=int),
        bound: wp.array(dtype=float),
        bound_mask: wp.array(dtype=int),
        eval_x: wp.array2d(dtype=wp.vec3),
        active: TriList,
        active_count: wp.array(dtype=int),
        out: TriList,
        out_count: wp.array(dtype=int),
    ):
        k = wp.tid()
        t = k
        allowed = int(-1)
        if wp.static(STAGE):
            if k >= src_count[0]:
                return
            t = src.tri[k]
            allowed = src.mask[k]
        mask = reach_mask(t, allowed, faces, x, geoms, tris_per_world, geoms_per_world, margin)
        if mask == 0:
            return
        slot = wp.atomic_add(active_count, 0, 1)
        active.tri[slot] = t
        active.mask[slot] = mask
        if wp.static(STAGE):
            if first_pass_keeps(t, mask, faces, x, bound, bound_mask, eval_x):
                slot = wp.atomic_add(out_count, 0, 1)
                out.tri[slot] = t
                out.mask[slot] = mask

    kernel.__name__ = kernel.__qualname__ = "stage_lists" if STAGE else "find_active"  # (the kernel's key: tests)
    return kernel


find_active = wp.kernel(list_source(False))
""" Append each triangle that can reach a geom within ``margin``, with the bit mask of those geoms,
so decision points query only the geoms near their triangle (the frame's list; a stage's comes
from that list by :func:`stage_lists`).
World-indexed (batched worlds, physhand_mj/batch.py): triangle t belongs to world w = t //
``tris_per_world`` and tests only that world's geoms [w k, (w + 1) k), k =
``geoms_per_world``, so a world's broadphase work does not grow with the number of worlds; one
world passes its triangle count and the geom capacity (w = 0: every geom in use). Mask bits are
world-relative: bit j is geom w k + j (j < 31; the world's geoms from its 31st on share bit 30,
and the decision points, query.world_phi, always try those, within the world's [w k, (w + 1) k)
only); one world's bits are its global geom indices, as before batching. A mesh's distance grid
(objects.mesh_grid) rejects the triangles its lower bound proves far and takes those its upper
bound proves near (within the mesh's query range); the others are asked the exact distance, so
the lists are those of the exact distance. Arguments: :func:`list_source`."""
stage_lists = wp.kernel(list_source(True))
""" A contact stage's two lists in one launch: :func:`find_active` over the frame's list ``src``
(near the geoms of its masks ``src.mask``: the stage's active triangles, ``active``) and, of those,
its first pass's (``out``, :func:`first_pass_keeps`)."""


@wp.kernel
def tally_worlds(
    items: wp.array(dtype=int),
    count: wp.array(dtype=int),
    per_world: int,
    item_world: wp.array(dtype=int),
    col: int,
    out: wp.array2d(dtype=int),
):
    """Batched worlds: count the entries of a list (``count[0]`` long) per world into out[w, col];
    an entry's world is item // ``per_world`` (triangles), or item_world[item] when per_world is 0
    (vertices)."""
    k = wp.tid()
    if k >= count[0]:
        return
    i = items[k]
    w = int(0)
    if per_world > 0:
        w = i // per_world
    else:
        w = item_world[i]
    wp.atomic_add(out, w, col, 1)
