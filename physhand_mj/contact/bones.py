"""Bones inside objects: where no penetration-free skin exists, and the report of it.

Contact moves only the skin; the bones go where MuJoCo puts them. When MuJoCo lets a bone into an
object (position control closing on a box, a keyframe placed by hand), no skin there can leave the
object without leaving its bone, and pushing it out anyway drags it across the object (measured
before this module: a 40 mm box 5-15 mm past a palm bone moved skin 25 mm, the tether's bound, and
26-40 mm a frame while the box stood still, with 400-800 inverted tets). So:

- **Held skin** (``Config.tuning.bone_hold``, on): every skin vertex has an *anchor*, the skeleton
  vertex nearest it at rest (``Model.skin_anchor``, in the bone's frame). Once per frame with an
  object near, :func:`hold_skin` marks the skin vertices whose anchor an object holds (phi < 0 at
  the frame's last bone pose; ``Contact.held``: 1 + the geom). Every contact push (Eq. 9, the
  feature push, the linear hold) is applied by ``query.apply_vertex``, which moves no held vertex:
  it stays where its flesh and bones carry it, at most its flesh thickness (its rest distance to
  its anchor) plus the anchor's depth inside the object (SDFs are 1-Lipschitz). Its unheld
  neighbours are pushed out as before; where no anchor is inside, nothing changes (bit for bit).
- **The report** (:func:`bone_clearance`, on demand, not per frame): per skeleton vertex its
  clearance from the nearest object (m, negative inside) and that object's geom; ``SoftHand.contacts()``
  gives per object the bones it holds and how deep, and how many skin vertices it held.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.sdf import FAR, GeomSet, geom_sdf

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time


@wp.func
def nearest_geom(p: wp.vec3, geoms: GeomSet, base: int, n: int, cap: float):
    """(phi, geom) of world point ``p`` against a world's geoms [base, base + n): the least SDF and
    its geom where it is below ``cap`` (m), else (cap, -1). A geom whose bounding sphere lies farther
    than the best so far costs no SDF."""
    best = float(cap)
    arg = int(-1)
    for j in range(n):
        g = base + j
        q = wp.transform_point(geoms.inv_pose[g], p)
        if wp.length(q) - geoms.radius[g] < best:
            d = geom_sdf(geoms.gtype[g], q, geoms.size[g], geoms.mesh[g])
            if d < best:
                best = d
                arg = g
    return best, arg


@wp.func
def geoms_of_world(w: int, geoms_per_world: int, geom_count: wp.array(dtype=int)):
    """(first geom, geoms in use) of world ``w``: its geoms are [w k, w k + k)."""
    base = w * geoms_per_world
    return base, wp.max(wp.min(geoms_per_world, geom_count[0] - base), 0)


# m: how much farther than its flesh thickness from where its bone carries it a push may leave a
# skin vertex (unless it already was farther: posed skin between two bones)
REACH_SLACK = wp.constant(2.0e-3)


@wp.struct
class BoneHold:
    """What a contact push may do to each skin vertex, from its bones (one kernel argument, made once:
    :func:`make_bone_hold`; empty arrays: no bound). held (S,) int: 1 + the geom that holds the
    vertex's anchor (no push moves it), 0 elsewhere; carried (S,) vec3 m: where its bone carries
    the vertex at the frame's last bone pose (its rest offset, Model.skin_local); reach (S,) float
    m: how far from there a push may leave it."""

    held: wp.array(dtype=int)
    carried: wp.array(dtype=wp.vec3)
    reach: wp.array(dtype=float)


def make_bone_hold(n_skin: int, device, on: bool = True) -> BoneHold:
    """A :class:`BoneHold` for ``n_skin`` skin vertices (``on`` False: empty, no bound)."""
    n = n_skin if on else 0
    h = BoneHold()
    h.held = wp.zeros(n, dtype=int, device=device)
    h.carried = wp.zeros(n, dtype=wp.vec3, device=device)
    h.reach = wp.zeros(n, dtype=float, device=device)
    return h


@wp.func
def held_move(hold: BoneHold, i: int, xi: wp.vec3, dx: wp.vec3):
    """Contact correction ``dx`` of skin vertex ``i`` (at ``xi``) where its bones allow it, else 0:
    not where an object holds its anchor, nor where it would leave the vertex farther from where
    its bone carries it than its reach (or than it already was)."""
    if i >= hold.held.shape[0]:
        return dx
    if hold.held[i] != 0:
        return wp.vec3(0.0)
    c = hold.carried[i]
    if wp.length(xi + dx - c) > wp.max(hold.reach[i], wp.length(xi - c)):
        return wp.vec3(0.0)
    return dx


@wp.kernel
def hold_skin(
    skin_body: wp.array(dtype=int),
    skin_local: wp.array(dtype=wp.vec3),
    skin_anchor: wp.array(dtype=wp.vec3),
    vertex_world: wp.array(dtype=int),
    body_sub: wp.array2d(dtype=wp.transform),
    sub: int,
    geoms: GeomSet,
    geoms_per_world: int,
    geom_count: wp.array(dtype=int),
    hold: BoneHold,
):
    """Skin vertex i's hold for the frame, at bone ``skin_body[i]``'s pose of substep ``sub``: where
    the bone carries it (``skin_local[i]``), its reach (its flesh thickness, the rest distance to its
    anchor ``skin_anchor[i]``, plus REACH_SLACK) and whether an object holds the anchor (phi < 0)."""
    i = wp.tid()
    h = int(0)
    b = skin_body[i]
    if b >= 0:
        base, n = geoms_of_world(vertex_world[i], geoms_per_world, geom_count)
        pose = body_sub[sub, b]
        phi, g = nearest_geom(wp.transform_point(pose, skin_anchor[i]), geoms, base, n, 0.0)
        if g >= 0:
            h = g + 1
        hold.carried[i] = wp.transform_point(pose, skin_local[i])
        hold.reach[i] = wp.length(skin_local[i] - skin_anchor[i]) + REACH_SLACK
    else:
        hold.reach[i] = 1.0e30  # (no skeleton: no bound)
    hold.held[i] = h


@wp.kernel
def bone_clearance(
    x: wp.array(dtype=wp.vec3),
    skeleton: wp.array(dtype=int),
    vertex_world: wp.array(dtype=int),
    geoms: GeomSet,
    geoms_per_world: int,
    geom_count: wp.array(dtype=int),
    cap: float,
    clearance: wp.array(dtype=float),
    nearest: wp.array(dtype=int),
):
    """Per skeleton vertex ``skeleton[k]``: its clearance from its world's objects (m, the least phi;
    negative inside; ``cap`` where none is nearer) and that geom (``nearest``; -1: none within ``cap``)."""
    k = wp.tid()
    i = skeleton[k]
    base, n = geoms_of_world(vertex_world[i], geoms_per_world, geom_count)
    phi, g = nearest_geom(x[i], geoms, base, n, cap)
    clearance[k] = phi
    nearest[k] = g


BONE_CAP = 0.05  # m: clearances are reported up to this (a bone farther from every object reads 50 mm)
assert BONE_CAP < FAR


def bone_report(model, objects, x, geoms_per_world: int, held=None, world: int = 0) -> dict:
    """The bones of world ``world`` against its objects, for ``x`` (the state's positions): per
    object index (``objects.obj`` of a geom) ``clearance_m`` (its least clearance from any skeleton
    vertex, m; negative: a bone inside it, that deep), ``bones`` (the bodies with a vertex inside,
    sorted names) and, given the last frame's ``held`` (Contact.held), ``skin_held`` (its skin
    vertices held: the object holds their anchor); and ``bone_clearance_m``, the least over objects (BONE_CAP where none is near)."""
    dev = model.device
    vb = model.vertex_body.numpy()
    vw = model.vertex_world.numpy()
    skel = np.flatnonzero((vb >= 0) & (vw == world)).astype(np.int32)
    out = dict(objects={}, bone_clearance_m=BONE_CAP)
    if not len(skel):
        return out
    clear = wp.zeros(len(skel), dtype=float, device=dev)
    near = wp.zeros(len(skel), dtype=int, device=dev)
    wp.launch(bone_clearance, len(skel), [x, wp.array(skel, dtype=int, device=dev), model.vertex_world, objects.geoms,
                                          geoms_per_world, objects.count, BONE_CAP], [clear, near], device=dev)
    c, g = clear.numpy().astype(float), near.numpy()
    obj_of = objects.obj.numpy()
    names = model.body_names
    for o in sorted({int(obj_of[j]) for j in g[g >= 0]}):
        mine = (g >= 0) & (obj_of[np.maximum(g, 0)] == o)
        inside = mine & (c < 0.0)
        out["objects"][o] = dict(clearance_m=float(c[mine].min()),
                                 bones=sorted({names[b] for b in vb[skel[inside]]}), skin_held=0)
    if held is not None and held.shape[0] == model.n_skin:  # (empty: Config.tuning.bone_hold off)
        ns = model.n_skin
        h = held.numpy()[:ns][vw[:ns] == world]
        for o, n_held in zip(*np.unique(obj_of[h[h > 0] - 1], return_counts=True)):
            out["objects"].setdefault(int(o), dict(clearance_m=BONE_CAP, bones=[], skin_held=0))["skin_held"] = int(n_held)
    out["bone_clearance_m"] = float(c.min())
    return out
