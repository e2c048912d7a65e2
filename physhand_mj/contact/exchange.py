"""Two-way coupling's exchange (``Config.two_way``): the skin's contact impulses on the objects and
the bones, the objects moved by them within the frame, and the skin's Coulomb friction.

- **Impulses.** Every contact correction is a position projection of a skin vertex (Eq. 9, the
  feature push, the linear hold). A vertex of mass m moved by dx in a substep of length h gets the
  impulse m dx / h (the multiplier of a hard constraint, as XPBD reads it); by Newton's third law the
  object that pushed it gets -m dx / h at the vertex, and the vertex hands m dx / h on to the bone
  that carries it (``Model.skin_body``; the flesh's own momentum is left out). :func:`record` adds a
  correction to the sums as ``query.apply_vertex`` applies it; each correction lands once on each
  side, so the forces on objects and on bones sum to zero to float rounding. The object of a
  correction is the one the vertex's last push in that pass came from (``PushSums.vertex_obj``).
- **Objects moved at the substep rate.** A free object's frame starts from the pose and velocity
  MuJoCo's step started from; before each stage it moves with that velocity plus what the step's own
  acceleration (gravity and MuJoCo's other forces, ``qacc``) and the skin have given it in the
  substeps before (:func:`move_objects`, :func:`pose_objects`), after each stage it takes the
  stage's impulses (:func:`take_impulses`). The step's velocity change is so spread over the
  substeps, as the skin's is, instead of landing whole at the frame's start. ``SoftHand`` hands the
  frame's pose, velocity change and the bones' reaction back to MuJoCo.
- **Friction** (:func:`skin_friction`, after each stage): each touching vertex's slip against the
  object's surface motion, plus what it still owes from earlier substeps, is undone within mu x its
  running normal load, else cut by that much and the rest owed (up to STICK_SLACK; past it the vertex
  slides). Owing the slip makes sticking a position constraint: with the step's velocity change
  (gravity's g dt) given at once at the frame's start, more than a substep's friction can take, a
  per-substep bound let the object slip a little every frame (a box held at 1.2 x the bound crept
  8 mm/s); spread over the substeps as now, the slack is kept for the flesh's own motion.
- **Damping** (``Config.contact_damping``): a touching object's normal velocity relative to the
  bones under the skin decays over that time, shared over the touching vertices by load.
- **Host traffic**: one packed upload and one read-back a frame (:func:`unpack_inputs`,
  :func:`pack_outputs`); :func:`frame_wrenches` turns the sums into mean forces and torques over the
  frame's s substeps, about each object's and bone's centre of mass c:

    F_obj = -sum(m dx) / (s h^2),  tau_obj = -sum((x - c_obj) x m dx) / (s h^2)
    F_bone = +sum(m dx) / (s h^2), tau_bone = +sum((x - c_bone) x m dx) / (s h^2)
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.bones import BoneHold, held_move
from physhand_mj.contact.inside import shift_poses
from physhand_mj.contact.sdf import GeomSet, geom_sdf_grad

wp.set_module_options({"enable_backward": False})


@wp.struct
class Exchange:
    """Two-way coupling's arrays (one kernel argument; empty arrays: off). S skin vertices, K objects,
    G geoms, B bones; world frame, SI units.

    The skin: mass (S,) kg; body (S,) the bone that carries each vertex (Model.skin_body; -1: none);
    sub_load (S,) m: its normal correction in the current substep; load (S,) m: the running mean of
    that (friction's bound is mu m load / h); fr_obj (S,): the object it touches (-1: none); stick
    (S,) m: the tangential slip against it that its friction has not undone yet (kept while it
    touches); slack m: the longest such slip (STICK_SLACK).
    The objects, set per frame: obj_com, obj_vel, obj_omega (K,): centre of mass, its velocity and angular
    velocity at the frame's start (before MuJoCo's step); obj_acc, obj_alpha (K,): the step's own linear
    and angular acceleration (its velocity change over the frame, spread over the substeps); obj_inv_mass (K,) 1/kg and obj_inv_inertia (K,) 1/(kg m^2): a
    free object's (0: the skin does not move it within the frame); obj_mu (K,): its friction
    coefficient against the skin; base_pose (G,): the geoms' poses at the frame's start.
    Their motion in the frame: dv, dw (K,): the velocity the skin has given each so far; shift (K,) m
    and turn (K,) quat: how far each has moved and turned about its centre; steps (K,): over how many
    substeps (a frame whose stages the solver skipped, nothing near, moved it over none: SoftHand
    moves it over the rest).
    The sums (skin side; objects get minus these): obj_lin / obj_ang (K,) and bone_lin / bone_ang
    (B,): sum(m dx) kg m and sum((x - c) x m dx) kg m^2 over the frame; sub_lin / sub_ang (K,): the
    current substep's; obj_fric (K,): the friction corrections' share of obj_lin.
    The bones, set per frame: bone_com, bone_vel, bone_omega (B,).
    Damping: damp: the share of the normal velocity taken per substep (1 - exp(-h / contact_damping));
    agg_load / agg_n / agg_vb (K,): the touching skin's summed load, load-weighted normals and bone
    velocities this substep; prev_*: the previous substep's. h s: the substep."""

    mass: wp.array(dtype=float)
    body: wp.array(dtype=int)
    h: float
    obj_mu: wp.array(dtype=float)
    sub_load: wp.array(dtype=float)
    load: wp.array(dtype=float)
    fr_obj: wp.array(dtype=int)
    stick: wp.array(dtype=wp.vec3)
    slack: float
    obj_vel: wp.array(dtype=wp.vec3)
    obj_omega: wp.array(dtype=wp.vec3)
    obj_acc: wp.array(dtype=wp.vec3)
    obj_alpha: wp.array(dtype=wp.vec3)
    obj_fric: wp.array(dtype=wp.vec3)
    obj_com: wp.array(dtype=wp.vec3)
    obj_inv_mass: wp.array(dtype=float)
    obj_inv_inertia: wp.array(dtype=wp.mat33)
    sub_lin: wp.array(dtype=wp.vec3)
    sub_ang: wp.array(dtype=wp.vec3)
    dv: wp.array(dtype=wp.vec3)
    dw: wp.array(dtype=wp.vec3)
    shift: wp.array(dtype=wp.vec3)
    turn: wp.array(dtype=wp.quat)
    steps: wp.array(dtype=int)
    base_pose: wp.array(dtype=wp.transform)
    bone_com: wp.array(dtype=wp.vec3)
    bone_vel: wp.array(dtype=wp.vec3)
    bone_omega: wp.array(dtype=wp.vec3)
    damp: float
    agg_load: wp.array(dtype=float)
    agg_n: wp.array(dtype=wp.vec3)
    agg_vb: wp.array(dtype=wp.vec3)
    prev_load: wp.array(dtype=float)
    prev_n: wp.array(dtype=wp.vec3)
    prev_vb: wp.array(dtype=wp.vec3)
    obj_lin: wp.array(dtype=wp.vec3)
    obj_ang: wp.array(dtype=wp.vec3)
    bone_lin: wp.array(dtype=wp.vec3)
    bone_ang: wp.array(dtype=wp.vec3)


def make_exchange(model, n_objects: int, on: bool, h: float, g_count: int = 0, damping: float = 0.0) -> Exchange:
    """An :class:`Exchange` for ``model``'s skin against ``n_objects`` objects (``g_count`` geoms),
    substeps of ``h`` s, the flesh's contact damping time ``damping`` s (0: none) (``on`` False:
    empty arrays, :func:`record` and :func:`touch_load` do nothing)."""
    d = model.device
    e = Exchange()
    k, b = (max(n_objects, 1), max(model.n_bodies, 1)) if on else (0, 0)
    inv = model.inv_mass.numpy()[: model.n_skin] if on else np.zeros(0)
    e.mass = wp.array(np.where(inv > 0, 1.0 / np.maximum(inv, 1e-30), 0.0).astype(np.float32), dtype=float, device=d)
    e.body = model.skin_body if on else wp.zeros(0, dtype=int, device=d)
    e.h = float(h)
    vec = {name: wp.zeros(k, dtype=wp.vec3, device=d) for name in (
        "obj_vel", "obj_omega", "obj_acc", "obj_alpha", "obj_fric", "obj_com", "sub_lin", "sub_ang", "dv", "dw", "shift", "obj_lin", "obj_ang",
        "agg_n", "agg_vb", "prev_n", "prev_vb")}
    vec.update({name: wp.zeros(b, dtype=wp.vec3, device=d) for name in ("bone_com", "bone_vel", "bone_omega", "bone_lin",
                                                                        "bone_ang")})
    for name, arr in vec.items():
        setattr(e, name, arr)
    for name in ("obj_mu", "obj_inv_mass", "agg_load", "prev_load"):
        setattr(e, name, wp.zeros(k, dtype=float, device=d))
    ns = model.n_skin if on else 0
    e.sub_load, e.load = wp.zeros(ns, dtype=float, device=d), wp.zeros(ns, dtype=float, device=d)
    e.fr_obj = wp.full(ns, -1, dtype=int, device=d)
    e.stick = wp.zeros(ns, dtype=wp.vec3, device=d)
    e.slack = float(STICK_SLACK)
    e.obj_inv_inertia = wp.zeros(k, dtype=wp.mat33, device=d)
    e.steps = wp.zeros(k, dtype=int, device=d)
    e.turn = wp.array(np.tile(np.array([0, 0, 0, 1.0], np.float32), (k, 1)), dtype=wp.quat, device=d)
    e.base_pose = wp.zeros(max(g_count, 1) if on else 0, dtype=wp.transform, device=d)
    e.damp = float(1.0 - np.exp(-h / damping)) if damping > 0 else 0.0
    return e


@wp.func
def touch_load(ex: Exchange, i: int, obj: int, dxn: wp.vec3):
    """Skin vertex ``i``'s normal contact correction ``dxn`` by object ``obj``, for its friction."""
    if i >= ex.sub_load.shape[0] or obj < 0:
        return
    ex.sub_load[i] = ex.sub_load[i] + wp.length(dxn)
    ex.fr_obj[i] = obj


# the running mean's weight of a substep's normal correction: the skin under a resting object is
# pushed out in some substeps and not in others, and its friction bound is the mean normal impulse
LOAD_RATE = wp.constant(0.25)
# m: the longest slip a touching skin vertex owes (Exchange.stick); past it the vertex slides and the
# point it sticks to is dragged along. (Chosen when MuJoCo's step gave the object gravity's g dt at
# the frame's start, which moved an object held at its bound about g dt^2 / 2, 0.12 mm at 5 ms,
# against the skin and back within the frame: physhand_mj/bench/pinch.py, a 10 g box at 1.25 x the
# bound: 30 um left it creeping 1 mm/s, 0.1 mm less than 0.1 mm/s)
STICK_SLACK = 1.0e-4
# m: how far outside its object a skin vertex still counts as touching it (Eq. 9 leaves it 20 um out, the
# feature push moves triangles whose vertices can end farther; 0.5 mm: the stage margin)
TOUCH_GAP = wp.constant(5.0e-4)


@wp.func
def obj_lin_vel(ex: Exchange, k: int):
    """Object ``k``'s velocity in the current substep (the ``steps``-th): its frame's start velocity
    plus what the physics step's acceleration and the skin's impulses gave it in the substeps before
    (both act at the end of their substep: an object resting on the skin ends the frame at rest)."""
    return ex.obj_vel[k] + ex.obj_acc[k] * (float(ex.steps[k] - 1) * ex.h) + ex.dv[k]


@wp.func
def obj_ang_vel(ex: Exchange, k: int):
    """Object ``k``'s angular velocity in the current substep (as :func:`obj_lin_vel`)."""
    return ex.obj_omega[k] + ex.obj_alpha[k] * (float(ex.steps[k] - 1) * ex.h) + ex.dw[k]


@wp.func
def object_phi(x: wp.vec3, k: int, geoms: GeomSet, base: int, n: int):
    """(phi m, outward unit normal, world) of the nearest geom of object ``k`` among a world's geoms."""
    best = float(1.0e30)
    nrm = wp.vec3(0.0, 0.0, 1.0)
    for j in range(n):
        g = base + j
        if geoms.obj[g] == k:
            q = wp.transform_point(geoms.inv_pose[g], x)
            phi, grad = geom_sdf_grad(geoms.gtype[g], q, geoms.size[g], geoms.mesh[g])
            if phi < best:
                best = phi
                nrm = wp.transform_vector(wp.transform_inverse(geoms.inv_pose[g]), grad)
    return best, wp.normalize(nrm)


@wp.kernel
def skin_friction(ex: Exchange, hold: BoneHold, geoms: GeomSet, n_geoms: int, vertex_world: wp.array(dtype=int),
                  geoms_per_world: int, x_start: wp.array(dtype=wp.vec3), x: wp.array(dtype=wp.vec3)):
    """After a substep's contact: Coulomb friction of every skin vertex touching an object. Its slip
    over the substep (its motion less the object's surface motion there, tangent to the surface)
    plus the slip it still owes (``ex.stick``) is undone where within mu x its mean normal correction
    (sticking), else cut by that much (sliding) and the rest owed, at most ``ex.slack`` (beyond it the
    point it sticks to is dragged along: it slides); the correction's impulse goes to the object and
    the bones (:func:`record`). A vertex that was
    pushed recently but not this substep still holds (its mean load decays); one that left the object
    (farther than TOUCH_GAP) lets go. Batched worlds (``geoms_per_world`` > 0): the object's geoms
    are looked for among the vertex's world's only (one world: all ``n_geoms``)."""
    i = wp.tid()
    k = ex.fr_obj[i]
    if k < 0:
        return
    sub = ex.sub_load[i]
    ex.sub_load[i] = 0.0
    load = ex.load[i] + LOAD_RATE * (sub - ex.load[i])
    xi = x[i]
    base = int(0)
    count = n_geoms
    if geoms_per_world > 0:
        base = vertex_world[i] * geoms_per_world
        count = geoms_per_world
    phi, n = object_phi(xi, k, geoms, base, count)
    if (sub <= 0.0 and phi > TOUCH_GAP) or load <= 0.0:
        ex.load[i] = 0.0
        ex.fr_obj[i] = -1
        ex.stick[i] = wp.vec3(0.0)
        return
    ex.load[i] = load
    r = xi - ex.obj_com[k] - ex.shift[k]
    vo = obj_lin_vel(ex, k)
    vel = vo + wp.cross(obj_ang_vel(ex, k), r)
    b = ex.body[i]
    if b >= 0 and ex.damp > 0.0:  # the flesh's damping: the object's normal velocity relative to the
        # bones under it (the previous substep's load-weighted means) decays, shared by load. (Damped at
        # each vertex along its own normal instead, a box on the slab stopped rocking, but one sliding was
        # braked by the contacts at its leading edge: mu 0.6 slid 2.4 deg past atan(mu). Of a pinch's
        # opposed contacts the mean normal is a residual: up in the hand's pinch, braking a card's fall.)
        vb = ex.bone_vel[b] + wp.cross(ex.bone_omega[b], xi - ex.bone_com[b])
        wp.atomic_add(ex.agg_load, k, load)
        wp.atomic_add(ex.agg_n, k, n * load)
        wp.atomic_add(ex.agg_vb, k, vb * load)
        pl = ex.prev_load[k]
        im = ex.obj_inv_mass[k]
        if pl > 0.0 and im > 0.0 and ex.mass[i] > 0.0:
            nk = wp.normalize(ex.prev_n[k])
            vn = wp.dot(vo - ex.prev_vb[k] / pl, nk)
            jn = -ex.damp * vn / im * (load / pl)  # N s on the object along nk
            record(ex, i, k, xi, nk * (-jn * ex.h / ex.mass[i]), wp.vec3(0.0))
    u = ex.stick[i] + xi - x_start[i] - vel * ex.h
    ut = u - n * wp.dot(u, n)
    s = wp.length(ut)
    lim = ex.obj_mu[k] * load
    dxf = -ut
    if s > lim:
        dxf = -ut * (lim / s)
    dx = held_move(hold, i, x, xi, dxf)
    record(ex, i, k, xi, dx, dx)
    x[i] = xi + dx
    owe = ut + dx
    left = wp.length(owe)
    if left > ex.slack:
        owe = owe * (ex.slack / left)
    ex.stick[i] = owe


@wp.func
def record(ex: Exchange, i: int, obj: int, xi: wp.vec3, dx: wp.vec3, dxf: wp.vec3):
    """Add skin vertex ``i``'s correction ``dx`` (at ``xi``, before it; ``dxf`` its friction part) by
    object ``obj`` to the sums."""
    if i >= ex.mass.shape[0] or obj < 0 or obj >= ex.obj_lin.shape[0]:
        return
    p = dx * ex.mass[i]
    a = wp.cross(xi - ex.obj_com[obj] - ex.shift[obj], p)
    wp.atomic_add(ex.obj_fric, obj, dxf * ex.mass[i])
    wp.atomic_add(ex.obj_lin, obj, p)
    wp.atomic_add(ex.obj_ang, obj, a)
    wp.atomic_add(ex.sub_lin, obj, p)
    wp.atomic_add(ex.sub_ang, obj, a)
    b = ex.body[i]
    if b >= 0:
        wp.atomic_add(ex.bone_lin, b, p)
        wp.atomic_add(ex.bone_ang, b, wp.cross(xi - ex.bone_com[b], p))


@wp.kernel
def reset_objects(ex: Exchange):
    """Per frame: the sums and the objects' in-frame motion back to zero."""
    k = wp.tid()
    ex.obj_lin[k] = wp.vec3(0.0)
    ex.obj_ang[k] = wp.vec3(0.0)
    ex.sub_lin[k] = wp.vec3(0.0)
    ex.sub_ang[k] = wp.vec3(0.0)
    ex.dv[k] = wp.vec3(0.0)
    ex.dw[k] = wp.vec3(0.0)
    ex.shift[k] = wp.vec3(0.0)
    ex.turn[k] = wp.quat_identity()
    ex.steps[k] = 0


@wp.kernel
def take_impulses(ex: Exchange):
    """After a substep's contact: each movable object takes the substep's impulse from the skin
    (minus the skin's: -sum(m dx) / h) into its velocity change."""
    k = wp.tid()
    lin = ex.sub_lin[k]
    ang = ex.sub_ang[k]
    ex.sub_lin[k] = wp.vec3(0.0)
    ex.sub_ang[k] = wp.vec3(0.0)
    ex.prev_load[k] = ex.agg_load[k]
    ex.prev_n[k] = ex.agg_n[k]
    ex.prev_vb[k] = ex.agg_vb[k]
    ex.agg_load[k] = 0.0
    ex.agg_n[k] = wp.vec3(0.0)
    ex.agg_vb[k] = wp.vec3(0.0)
    im = ex.obj_inv_mass[k]
    if im <= 0.0:
        return
    ex.dv[k] = ex.dv[k] - lin * (im / ex.h)
    ex.dw[k] = ex.dw[k] - ex.obj_inv_inertia[k] * ang * (1.0 / ex.h)


@wp.kernel
def move_objects(ex: Exchange):
    """Before a substep's contact: each movable object moves over the substep with its velocity (its
    velocity at the frame's start, plus the physics step's acceleration over the substeps so far and
    what the skin has changed in the frame so far: :func:`obj_lin_vel`). Its frame pose is the one
    MuJoCo's step started from, so its whole motion in the frame is integrated here, at the substep
    rate, with the skin's force in it."""
    k = wp.tid()
    if ex.obj_inv_mass[k] <= 0.0:
        return
    ex.steps[k] = ex.steps[k] + 1
    ex.shift[k] = ex.shift[k] + obj_lin_vel(ex, k) * ex.h
    w = obj_ang_vel(ex, k)
    a = wp.length(w) * ex.h
    if a > 0.0:
        ex.turn[k] = wp.normalize(wp.quat_from_axis_angle(wp.normalize(w), a) * ex.turn[k])


@wp.kernel
def pose_objects(ex: Exchange, obj: wp.array(dtype=int), pose: wp.array(dtype=wp.transform),
                 inv_pose: wp.array(dtype=wp.transform)):
    """Each geom of a movable object at its frame pose moved by its object's shift and turn about the
    object's centre (pose and inverse, as the contact reads them)."""
    g = wp.tid()
    k = obj[g]
    if ex.obj_inv_mass[k] <= 0.0:
        return
    b = ex.base_pose[g]
    c = ex.obj_com[k]
    q = ex.turn[k]
    t = wp.transform(c + ex.shift[k] + wp.quat_rotate(q, wp.transform_get_translation(b) - c),
                     q * wp.transform_get_rotation(b))
    pose[g] = t
    inv_pose[g] = wp.transform_inverse(t)


def zero_ops(ex: Exchange, objects=None) -> list:
    """The per-frame resets of the sums and of the objects' in-frame motion, and the geoms' frame
    poses kept (empty when off)."""
    if ex.obj_lin.shape[0] == 0:
        return []
    ops = [ex.obj_fric.zero_, ex.bone_lin.zero_, ex.bone_ang.zero_, ex.sub_load.zero_,
           lambda: wp.launch(reset_objects, ex.obj_lin.shape[0], [ex], device=ex.obj_lin.device)]
    if objects is not None:
        ops.append(lambda: wp.copy(ex.base_pose, objects.pose, count=min(ex.base_pose.shape[0], objects.pose.shape[0])))
    return ops


# the per-frame traffic with the host, packed (one upload and one read-back a frame: on CUDA each
# array's own copy cost a sync): per object [com 3, vel 3, omega 3, inv_mass, inv_inertia 9, mu, acc 3, alpha 3] in,
# [lin 3, ang 3, fric 3, dv 3, dw 3, shift 3, turn 4, steps] out; per bone [com 3, vel 3, omega 3] in, [lin 3,
# ang 3] out
IN_OBJ, IN_BONE, OUT_OBJ, OUT_BONE = 26, 9, 23, 6


@wp.func
def _v3(buf: wp.array(dtype=float), a: int):
    return wp.vec3(buf[a], buf[a + 1], buf[a + 2])


@wp.func
def _put3(buf: wp.array(dtype=float), a: int, v: wp.vec3):
    buf[a] = v[0]
    buf[a + 1] = v[1]
    buf[a + 2] = v[2]


@wp.kernel
def unpack_inputs(ex: Exchange, buf: wp.array(dtype=float), n_obj: int, n_bone: int):
    """The frame's inputs from one packed buffer (IN_OBJ per object, then IN_BONE per bone)."""
    t = wp.tid()
    if t < n_obj:
        a = t * IN_OBJ
        ex.obj_com[t] = _v3(buf, a)
        ex.obj_vel[t] = _v3(buf, a + 3)
        ex.obj_omega[t] = _v3(buf, a + 6)
        ex.obj_inv_mass[t] = buf[a + 9]
        ex.obj_inv_inertia[t] = wp.mat33(buf[a + 10], buf[a + 11], buf[a + 12], buf[a + 13], buf[a + 14], buf[a + 15],
                                         buf[a + 16], buf[a + 17], buf[a + 18])
        ex.obj_mu[t] = buf[a + 19]
        ex.obj_acc[t] = _v3(buf, a + 20)
        ex.obj_alpha[t] = _v3(buf, a + 23)
    if t < n_bone:
        a = n_obj * IN_OBJ + t * IN_BONE
        ex.bone_com[t] = _v3(buf, a)
        ex.bone_vel[t] = _v3(buf, a + 3)
        ex.bone_omega[t] = _v3(buf, a + 6)


@wp.kernel
def pack_outputs(ex: Exchange, buf: wp.array(dtype=float), n_obj: int, n_bone: int):
    """The frame's sums and the objects' in-frame motion into one packed buffer (OUT_OBJ, OUT_BONE)."""
    t = wp.tid()
    if t < n_obj:
        a = t * OUT_OBJ
        _put3(buf, a, ex.obj_lin[t])
        _put3(buf, a + 3, ex.obj_ang[t])
        _put3(buf, a + 6, ex.obj_fric[t])
        _put3(buf, a + 9, ex.dv[t])
        _put3(buf, a + 12, ex.dw[t])
        _put3(buf, a + 15, ex.shift[t])
        q = ex.turn[t]
        buf[a + 18] = q[0]
        buf[a + 19] = q[1]
        buf[a + 20] = q[2]
        buf[a + 21] = q[3]
        buf[a + 22] = float(ex.steps[t])
    if t < n_bone:
        a = n_obj * OUT_OBJ + t * OUT_BONE
        _put3(buf, a, ex.bone_lin[t])
        _put3(buf, a + 3, ex.bone_ang[t])


def frame_wrenches(out: np.ndarray, n_obj: int, n_bone: int, substep_dt: float, substeps: int) -> dict:
    """The last frame's mean wrenches (N, N m, world frame) from :func:`pack_outputs`' buffer ``out``:
    ``objects`` (K, 6) [force, torque about each object's centre] that the skin applied to each object,
    ``friction`` (K, 3) the friction part of each force, ``bones`` (B, 6) the reaction on each bone
    (``objects.sum(0)[:3] == -bones.sum(0)[:3]`` to float rounding), and the objects' in-frame motion
    ``dv``, ``dw``, ``shift``, ``turn`` (x y z w) and ``steps``."""
    o = np.asarray(out, np.float64)[: n_obj * OUT_OBJ].reshape(n_obj, OUT_OBJ)
    bo = np.asarray(out, np.float64)[n_obj * OUT_OBJ: n_obj * OUT_OBJ + n_bone * OUT_BONE].reshape(n_bone, OUT_BONE)
    scale = 1.0 / (substeps * substep_dt * substep_dt)
    return dict(objects=o[:, :6] * -scale, friction=o[:, 6:9] * -scale, bones=bo * scale,
                dv=o[:, 9:12], dw=o[:, 12:15], shift=o[:, 15:18], turn=o[:, 18:22], steps=o[:, 22].astype(int))


class TwoWay:
    """A contact's two-way coupling on the host side (``Config.two_way``; off: nothing recorded and
    :attr:`data` holds empty arrays): the :class:`Exchange` its kernels take, the stages' launches
    and the frame's packed traffic with ``SoftHand``."""

    def __init__(self, model, objects, config, space=None, geoms_per_world: int = 0):
        # batched worlds (BatchedHands): objects and bones are rows of every world's (world w's
        # objects [w k, (w + 1) k), its bones [w B, (w + 1) B)), so every kernel maps row by row;
        # ``space`` (contact.QuerySpace): the object side's poses, moved per world, kept current
        # as the objects move within the frame; ``geoms_per_world``: friction looks for an object's
        # geoms in its vertex's world only
        self.model, self.objects, self.config = model, objects, config
        self.space = space
        self.geoms_per_world = int(geoms_per_world) if model.worlds > 1 else 0
        self.on = bool(config.two_way)
        self.data = make_exchange(model, len(objects.object_names), self.on, config.frame_dt / config.substeps,
                                  objects.pose.shape[0], config.contact_damping)
        k, b, d = self.data.obj_com.shape[0], self.data.bone_com.shape[0], model.device
        self.n_obj, self.n_bone = k, b
        self._in = np.zeros(k * IN_OBJ + b * IN_BONE, np.float32)  # (one upload and one read-back a frame)
        self._dev_in = wp.zeros(len(self._in), dtype=float, device=d)
        self._dev_out = wp.zeros(k * OUT_OBJ + b * OUT_BONE, dtype=float, device=d)

    def zero_ops(self) -> list:
        """The per-frame resets (:func:`zero_ops`)."""
        return zero_ops(self.data, self.objects) if self.on else []

    def record_move(self, rec) -> None:
        """Before a substep's contact: the movable objects move over the substep (move_objects, pose_objects)."""
        if self.on:
            o = self.objects
            rec.launch(move_objects, self.n_obj, [self.data], [])
            rec.launch(pose_objects, len(o.names), [self.data, o.obj], [o.pose, o.inv_pose])
            sp = self.space
            if sp is not None and sp.poses is not None:  # batched worlds queried apart: their moved copy
                rec.launch(shift_poses, sp.poses.shape[0], [o.pose, sp.offsets, sp.geoms_per_world], [sp.poses])

    def record_take(self, rec, state, hold) -> None:
        """After a substep's contact: the skin's friction (``hold``: the contact's bones.BoneHold), then the
        substep's impulses into the movable objects' velocities (skin_friction, take_impulses)."""
        if self.on:
            o = self.objects
            rec.launch(skin_friction, self.model.n_skin, [self.data, hold, o.geoms, len(o.names), self.model.vertex_world,
                                                          self.geoms_per_world, state.x_prev], [state.x])
            rec.launch(take_impulses, self.n_obj, [self.data], [])

    def set_state(self, obj_com, obj_vel, obj_omega, bone_com, obj_mu=None, inv_mass=None, inv_inertia=None,
                  bone_vel=None, bone_omega=None, obj_acc=None, obj_alpha=None) -> None:
        """The objects' state for the next frame (world frame, ``Objects.object_names`` order): centres
        of mass ``obj_com`` (K, 3) m, velocities there ``obj_vel`` (K, 3) m/s, angular velocities
        ``obj_omega`` (K, 3) rad/s at the frame's start; ``obj_acc`` / ``obj_alpha`` (K, 3) m/s^2,
        rad/s^2: the physics step's own acceleration of each, spread over the frame's substeps (None:
        0, the velocity as given for the whole frame); the bones' centres ``bone_com`` (B, 3) m (asset body order), about
        which torques are taken; ``obj_mu`` (K,): friction coefficients; ``inv_mass`` (K,) 1/kg and
        ``inv_inertia`` (K, 3, 3) 1/(kg m^2): the objects the skin moves within the frame (0: none);
        ``bone_vel`` / ``bone_omega`` (B, 3): the bones' velocities, m/s at their centres and rad/s
        (None: each as last set). One upload (unpack_inputs)."""
        if not self.on:
            raise ValueError("TwoWay.set_state: Config.two_way is off")
        k, b = self.n_obj, self.n_bone
        o = self._in[: k * IN_OBJ].reshape(k, IN_OBJ)
        bo = self._in[k * IN_OBJ:].reshape(b, IN_BONE)
        n = len(np.asarray(obj_com).reshape(-1, 3))
        o[:n, 0:3], o[:n, 3:6], o[:n, 6:9] = (np.asarray(v, np.float32).reshape(-1, 3) for v in (obj_com, obj_vel, obj_omega))
        o[:n, 20:23] = 0.0 if obj_acc is None else np.asarray(obj_acc, np.float32).reshape(-1, 3)
        o[:n, 23:26] = 0.0 if obj_alpha is None else np.asarray(obj_alpha, np.float32).reshape(-1, 3)
        nb = len(np.asarray(bone_com).reshape(-1, 3))
        bo[:nb, 0:3] = np.asarray(bone_com, np.float32).reshape(-1, 3)
        if obj_mu is not None:
            mu = np.asarray(obj_mu, np.float32).reshape(-1)
            if not (np.all(np.isfinite(mu)) and np.all(mu >= 0)):
                raise ValueError(f"friction coefficients must be finite and >= 0, got {mu}")
            o[: len(mu), 19] = mu
        if bone_vel is not None:
            bo[:nb, 3:6] = np.asarray(bone_vel, np.float32).reshape(-1, 3)
            bo[:nb, 6:9] = np.asarray(bone_omega, np.float32).reshape(-1, 3)
        if inv_mass is not None:
            im = np.asarray(inv_mass, np.float32).reshape(-1)
            o[: len(im), 9] = im
            o[: len(im), 10:19] = np.asarray(inv_inertia, np.float32).reshape(-1, 9)
        self._dev_in.assign(self._in)
        wp.launch(unpack_inputs, max(k, b), [self.data, self._dev_in, k, b], device=self.model.device)

    def clear(self) -> None:
        """A new episode: every object's and bone's state zeroed (the friction coefficients too: the
        next set_state must give them) and the skin's friction anchors and loads forgotten, as after construction (the next frames run as the first episode's did until
        :meth:`set_state`: a reset's settling frames do not carry the last episode's velocities)."""
        if not self.on:
            return
        self._in[:] = 0.0
        self._dev_in.assign(self._in)
        wp.launch(unpack_inputs, max(self.n_obj, self.n_bone), [self.data, self._dev_in, self.n_obj, self.n_bone],
                  device=self.model.device)
        self.data.stick.zero_()
        self.data.load.zero_()

    def wrenches(self) -> dict:
        """The last frame's mean contact wrenches and the objects' in-frame motion (:func:`frame_wrenches`;
        one launch and one read-back)."""
        if not self.on:
            return dict(objects=np.zeros((0, 6)), friction=np.zeros((0, 3)), bones=np.zeros((0, 6)))
        wp.launch(pack_outputs, max(self.n_obj, self.n_bone), [self.data, self._dev_out, self.n_obj, self.n_bone],
                  device=self.model.device)
        cfg = self.config
        return frame_wrenches(self._dev_out.numpy(), self.n_obj, self.n_bone, cfg.frame_dt / cfg.substeps, cfg.substeps)
