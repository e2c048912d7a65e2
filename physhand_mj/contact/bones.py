"""Bones inside objects: where no penetration-free skin exists, and the report of it.

Contact moves only the skin; the bones go where MuJoCo puts them. When MuJoCo lets a bone into an
object (position control closing on a box, a keyframe placed by hand), no skin there can leave the
object without leaving its bone. Pushing it out anyway dragged the skin through the finger and
back every frame (a 30 mm sphere 5-15 mm past the distal phalanx: skin 10-22 mm from rest, 160-340
inverted tets; a 40 mm box past a palm bone: 25 mm, the tether's bound, and 20-40 mm a frame while
the box stood still). So (``Config.tuning.bone_hold``, on):

- **The hold.** Every skin vertex has an *anchor*, the skeleton vertex nearest it at rest
  (``Model.skin_anchor``, in the bone's frame), and a *flesh thickness*, its rest distance to it.
  Once per frame with an object near, :func:`hold_skin` finds, at the frame's last bone pose, where
  the bone carries the vertex (``Model.skin_local``, the tether's point) and whether an object holds
  the anchor more than :func:`hold_depth` deep (0.5 mm where MuJoCo keeps the bones out of objects,
  the default with one-way coupling; 2 mm where its soft contacts let them in); such a vertex is
  *held* and its world *gripped*. Every contact push (Eq. 9, the feature push, the linear hold) is
  applied by ``query.apply_vertex`` through :func:`held_move`: a held vertex is not moved, and in a
  gripped world a push that would leave a vertex farther from where its bone carries it than its
  flesh thickness + REACH_SLACK (or than it already was) is not applied. Held skin stays inside the
  object: the penetration is the answer, stated by the report below. A bone less deep inside grips
  nothing. In a gripped world a push is also cut short where it would flatten one of the vertex's
  tets past KEEP of its rest volume: held and pushed skin side by side otherwise shear the
  skin-layer tets inside out (the palm with a bone 5 mm in a sphere: 389 inverted -> 6). After each
  contact stage of a frame that holds skin, :func:`restore_tets` grows the skin-layer tets the
  substep flattened past KEEP back to it (6 -> 0 there; RESTORE_ROUNDS_LAST rounds after the frame's
  last stage, whose positions the frame ends with).
- **The report** (:func:`bone_clearance`, :func:`bone_report`, on demand, not per frame): per
  skeleton vertex its clearance from the nearest object (m, negative inside) and that object's
  geom; ``SoftHand.contacts()`` gives per object the bones it holds and how deep, and how many
  skin vertices the frame held.

Where no anchor lies that deep inside an object, results are bit for bit those without the hold
(the project's hard cases, the HOI grasps, the demo's glass, whose bones the proxies' margin keeps
2 mm clear).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.sdf import FAR, GeomSet, geom_sdf
from physhand_mj.contact.tet_room import skin_tet_lists, tet_room

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
# m: how deep inside an object an anchor must lie to hold its skin where MuJoCo lets bones in (the
# proxies without a margin: two-way). A bone just inside (position control closing a grasp lets a
# fingertip bone ~1 mm into an object) keeps the skin pushed out over it, as before the hold: the
# skin passes the bone's surface by that much, where a held fingertip showed 3.5 mm of skin inside
# the demo's glass, and two-way grasps hold by that skin's push
HOLD_DEPTH = wp.constant(2.0e-3)
# m: the same where MuJoCo keeps the bones out of objects (the hand's proxies with a contact margin:
# coupling.proxy_margin, one-way by default), so that a bone inside is an infeasible start however
# shallow: a fingertip bone 1 mm inside a sphere kept 48 tets inverted at HOLD_DEPTH, 0 at this
KEPT_OUT_DEPTH = 0.5e-3


def hold_depth(config) -> float:
    """How deep (m) an anchor must lie inside an object to hold its skin under ``config`` (validated):
    KEPT_OUT_DEPTH where MuJoCo keeps the bones out (``coupling.proxy_margin``'s rule: the
    proxies' margin, None meaning 2.5 mm with one-way coupling and 0 with two-way), else HOLD_DEPTH
    (MuJoCo's soft contacts let a closing bone a little way in, and the skin there must still push:
    two-way grasps hold by it)."""
    margin = config.proxy_margin
    kept_out = (not config.two_way) if margin is None else margin > 0
    return KEPT_OUT_DEPTH if kept_out else float(HOLD_DEPTH)


# share of its rest volume below which a push in a gripped world may not flatten a tet of the pushed
# vertex (contact/tet_room.py: the push is cut short there, and a tet already below it may only
# grow). Held and pushed skin side by side sheared the skin-layer tets inside out: 15-389 stayed
# inverted while the object stayed (docs/contact.md "Bones inside objects"). 0.02 and 0.3 leave
# the same few (0-17) as 0.1; a larger share keeps more skin inside the object.
KEEP = 0.1
# In a gripped world the cut pushes keep moving the skin a little in every pass (one vertex's cut
# move changes its neighbours' room), so a stage there runs all its passes (CPU, the palm's 5 mm
# bone: 8-13 % more time a frame); a push cut below 1 um and dropped did not change that.

# rounds of restore_tets after each contact stage of a frame that holds skin (2 left the palm's 15 mm
# bone one inverted tet in every frame from the 6th; 4: 0-1, docs/contact.md "Bones inside objects")
RESTORE_ROUNDS = 4
# rounds after the frame's last stage, whose positions the frame ends with: there the palm's 15 mm
# bone's last inverted tet was 2-24 % of its rest volume inside out and a round takes back ~10 % of
# it, so 4 rounds left it inverted in 7 of 20 frames; 32 leave none from the 4th frame at any
# placement (16: 1 in 20). No cost measurable on an H200; ~7 ms of a 105-170 ms gripped CPU frame.
RESTORE_ROUNDS_LAST = 32


@wp.struct
class BoneHold:
    """What a contact push may do to each skin vertex, from its bones (one kernel argument, made once:
    :func:`make_bone_hold`; empty arrays: no bound). held (S,) int: 1 + the geom that holds the
    vertex's anchor (no push moves it), 0 elsewhere; carried (S,) vec3 m: where its bone carries
    the vertex at the frame's last bone pose (its rest offset, Model.skin_local); reach (S,) float
    m: how far from there a push may leave it in a gripped world; world (S,) int: its world
    (Model.vertex_world); gripped (W,) int: 1 for a world with a held vertex this frame; count (1,)
    int: the skin vertices held this frame, all worlds (a slot of the contact's frame counters, zeroed
    with them: the gate of restore_tets reads it); layer (L,) int: one world's tets with a skin
    vertex (restore_tets' rows); depth (1,)
    float m: how deep an anchor must lie to be held (:func:`hold_depth`; ``Contact.bones_free``: never);
    keep: KEEP (0: the hold off); ns1, nt1, vt_off, vt, tets, vol0: one world's skin vertices and
    tets per world, and the tets of each skin vertex with their rest 6 x volumes
    (contact/tet_room.py skin_tet_lists), for the cut in a gripped world."""

    held: wp.array(dtype=int)
    carried: wp.array(dtype=wp.vec3)
    reach: wp.array(dtype=float)
    world: wp.array(dtype=int)
    gripped: wp.array(dtype=int)
    count: wp.array(dtype=int)
    layer: wp.array(dtype=int)
    depth: wp.array(dtype=float)
    keep: float
    ns1: int
    nt1: int
    vt_off: wp.array(dtype=int)
    vt: wp.array(dtype=int)
    tets: wp.array2d(dtype=int)
    vol0: wp.array(dtype=float)


def make_bone_hold(model, on: bool = True, count: wp.array | None = None, depth: float = HOLD_DEPTH) -> BoneHold:
    """A :class:`BoneHold` for ``model``'s skin (``on`` False: empty arrays, no bound; ``count``: the
    (1,) int array hold_skin counts the held vertices in, a new one if None; ``depth``: m, an
    anchor's depth that holds its skin, :func:`hold_depth`)."""
    n, d = (model.n_skin if on else 0), model.device
    h = BoneHold()
    h.count = count if count is not None else wp.zeros(1, dtype=int, device=d)
    h.held = wp.zeros(n, dtype=int, device=d)
    h.carried = wp.zeros(n, dtype=wp.vec3, device=d)
    h.reach = wp.zeros(n, dtype=float, device=d)
    h.world = model.vertex_world if on else wp.zeros(0, dtype=int, device=d)
    h.gripped = wp.zeros(model.worlds if on else 0, dtype=int, device=d)
    h.depth = wp.full(1, float(depth), dtype=float, device=d)
    h.keep = float(KEEP) if on else 0.0
    h.ns1 = int(model.n_skin) // max(int(model.worlds), 1)
    if on and h.ns1:
        h.tets, h.nt1, h.vol0, h.vt_off, h.vt = skin_tet_lists(model, h.ns1)
        h.layer = wp.array(np.unique(h.vt.numpy()).astype(np.int32), dtype=int, device=d)
    else:
        h.nt1 = 0
        h.tets = wp.zeros((0, 4), dtype=int, device=d)
        h.vol0 = wp.zeros(0, dtype=float, device=d)
        h.vt_off = wp.zeros(0, dtype=int, device=d)
        h.vt = wp.zeros(0, dtype=int, device=d)
        h.layer = wp.zeros(0, dtype=int, device=d)
    return h


def record_restore(rec, hold: BoneHold, slot: int, inv_mass, x, rounds: int = RESTORE_ROUNDS) -> None:
    """Record :func:`restore_tets` (``rounds`` launches over every world's skin-layer tets) in a
    block that runs only in a frame that holds skin (``rec.gated`` level 2 on the held count, counter
    slot ``slot``: activity.py; a CUDA conditional node). Nothing where the hold has no tets."""
    if not hold.nt1:
        return
    n = hold.gripped.shape[0] * hold.layer.shape[0]  # (worlds x one world's skin-layer tets)

    def restore(sub):
        for _ in range(rounds):
            rec.launch(restore_tets, n, [hold, inv_mass], [x])
    rec.gated(restore, 2, (slot,), hold.count)


@wp.func
def held_move(hold: BoneHold, i: int, x: wp.array(dtype=wp.vec3), xi: wp.vec3, dx: wp.vec3):
    """Contact correction ``dx`` of skin vertex ``i`` (at ``xi``) where its bones allow it, else 0:
    not where an object holds its anchor, nor, in a gripped world, where it would leave the vertex
    farther from where its bone carries it than its reach (or than it already was); and there cut
    short where it would flatten one of the vertex's tets (at ``x``, every world's positions) past
    KEEP of its rest volume."""
    if i >= hold.held.shape[0]:
        return dx
    if hold.held[i] != 0:
        return wp.vec3(0.0)
    if hold.gripped[hold.world[i]] == 0:
        return dx
    c = hold.carried[i]
    if wp.length(xi + dx - c) > wp.max(hold.reach[i], wp.length(xi - c)):
        return wp.vec3(0.0)
    if hold.keep > 0.0:  # no push that flattens a tet of the vertex past KEEP of its rest volume
        w = hold.world[i]
        return dx * tet_room(i, i - w * hold.ns1, dx, x, hold.vt_off, hold.vt, hold.tets, hold.vol0, hold.keep, w * hold.nt1)
    return dx


@wp.func
def movable(hold: BoneHold, inv_mass: wp.array(dtype=float), j: int):
    """Vertex j's inverse mass for restore_tets: 0 for held skin (and bones: their own 0)."""
    if j < hold.held.shape[0]:
        if hold.held[j] != 0:
            return float(0.0)
    return inv_mass[j]


@wp.kernel
def restore_tets(hold: BoneHold, inv_mass: wp.array(dtype=float), x: wp.array(dtype=wp.vec3)):
    """In a gripped world, after a contact stage: every skin-layer tet (``hold.layer``: one world's
    tets with a skin vertex; a thread per tet of every world) below KEEP of its rest volume is grown back
    to it, its movable vertices (soft flesh and skin not held; ``inv_mass`` 0 for the bones; a tet
    of held skin only moves its held skin) moved along the volume's gradient by their inverse mass:
    one XPBD step of the inequality at infinite stiffness, by atomic adds (the volume is cubic in
    the positions and neighbours share vertices, so a round leaves a remainder: RESTORE_ROUNDS,
    RESTORE_ROUNDS_LAST). The substep (prediction and constraints)
    flattens skin-layer tets that the stage's cut pushes may not move: held skin beside pushed skin
    is sheared."""
    tid = wp.tid()
    n1 = hold.layer.shape[0]
    w = tid / n1
    if hold.keep <= 0.0 or hold.gripped[w] == 0:
        return
    e = hold.layer[tid - w * n1]
    ge = e + w * hold.nt1
    a = hold.tets[ge, 0]
    b = hold.tets[ge, 1]
    c = hold.tets[ge, 2]
    d = hold.tets[ge, 3]
    xa = x[a]
    ab = x[b] - xa
    ac = x[c] - xa
    ad = x[d] - xa
    v = wp.dot(ab, wp.cross(ac, ad))
    s0 = hold.vol0[e]
    sg = float(1.0)
    if s0 < 0.0:
        sg = -1.0
    lo = hold.keep * s0 * sg
    if v * sg >= lo:
        return
    gb = wp.cross(ac, ad)
    gc = wp.cross(ad, ab)
    gd = wp.cross(ab, ac)
    ga = -(gb + gc + gd)
    wa = movable(hold, inv_mass, a)
    wb = movable(hold, inv_mass, b)
    wc = movable(hold, inv_mass, c)
    wd = movable(hold, inv_mass, d)
    den = wa * wp.dot(ga, ga) + wb * wp.dot(gb, gb) + wc * wp.dot(gc, gc) + wd * wp.dot(gd, gd)
    if den <= 0.0:  # a tet of held skin only (and bones): its held skin moves, as the substep moved it
        wa = inv_mass[a]
        wb = inv_mass[b]
        wc = inv_mass[c]
        wd = inv_mass[d]
        den = wa * wp.dot(ga, ga) + wb * wp.dot(gb, gb) + wc * wp.dot(gc, gc) + wd * wp.dot(gd, gd)
    if den <= 0.0:
        return
    lam = sg * (lo - v * sg) / den
    wp.atomic_add(x, a, ga * (wa * lam))
    wp.atomic_add(x, b, gb * (wb * lam))
    wp.atomic_add(x, c, gc * (wc * lam))
    wp.atomic_add(x, d, gd * (wd * lam))


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
    anchor ``skin_anchor[i]``, plus REACH_SLACK) and whether an object holds the anchor (deeper than
    ``hold.depth`` inside it), which grips its world (``hold.gripped``, zeroed before)."""
    i = wp.tid()
    h = int(0)
    b = skin_body[i]
    if b >= 0:
        base, n = geoms_of_world(vertex_world[i], geoms_per_world, geom_count)
        pose = body_sub[sub, b]
        phi, g = nearest_geom(wp.transform_point(pose, skin_anchor[i]), geoms, base, n, -hold.depth[0])
        if g >= 0:
            h = g + 1
            hold.gripped[vertex_world[i]] = 1
            wp.atomic_add(hold.count, 0, 1)
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


def skeleton_clearance(model, objects, x, geoms_per_world: int, skel: np.ndarray) -> tuple:
    """(clearance (k,) float m, nearest geom (k,) int) of skeleton vertices ``skel`` (vertex ids)
    from their worlds' objects (:func:`bone_clearance`, one launch)."""
    dev = model.device
    clear = wp.zeros(len(skel), dtype=float, device=dev)
    near = wp.zeros(len(skel), dtype=int, device=dev)
    wp.launch(bone_clearance, len(skel), [x, wp.array(skel, dtype=int, device=dev), model.vertex_world, objects.geoms,
                                          geoms_per_world, objects.count, BONE_CAP], [clear, near], device=dev)
    return clear.numpy().astype(float), near.numpy()


def world_clearances(model, objects, x, geoms_per_world: int) -> np.ndarray:
    """(W,) float: per world the skeleton's least clearance from its objects (m; negative: a bone
    that deep inside one; BONE_CAP where none is nearer), one launch for every world."""
    vb, vw = model.vertex_body.numpy(), model.vertex_world.numpy()
    skel = np.flatnonzero(vb >= 0).astype(np.int32)
    out = np.full(model.worlds, BONE_CAP)
    if len(skel):
        np.minimum.at(out, vw[skel], skeleton_clearance(model, objects, x, geoms_per_world, skel)[0])
    return out


def bone_report(model, objects, x, geoms_per_world: int, held=None, world: int = 0) -> dict:
    """The bones of world ``world`` against its objects, for ``x`` (the state's positions): per
    object index (``objects.obj`` of a geom) ``clearance_m`` (its least clearance from any skeleton
    vertex, m; negative: a bone inside it, that deep), ``bones`` (the bodies with a vertex inside,
    sorted names) and, given the last frame's ``held`` (BoneHold.held), ``skin_held`` (its skin
    vertices the frame held: it holds their anchor; 0 for an object that holds no bone now); and
    ``bone_clearance_m``, the least over objects (BONE_CAP where none is near)."""
    vb = model.vertex_body.numpy()
    vw = model.vertex_world.numpy()
    skel = np.flatnonzero((vb >= 0) & (vw == world)).astype(np.int32)
    out = dict(objects={}, bone_clearance_m=BONE_CAP)
    if not len(skel):
        return out
    c, g = skeleton_clearance(model, objects, x, geoms_per_world, skel)
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
            row = out["objects"].get(int(o))
            if row is not None and row["clearance_m"] < 0.0:  # (held is the last frame's with an object near:
                row["skin_held"] = int(n_held)  # an object that holds no bone now holds no skin)
    out["bone_clearance_m"] = float(c.min())
    return out
