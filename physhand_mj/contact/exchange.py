"""The skin's contact impulses, summed per object and per bone: what two-way coupling hands to MuJoCo.

Every contact correction is a position projection of a skin vertex (Eq. 9, the feature push, the
linear hold). A vertex of mass m moved by dx in a substep of length h gets the impulse m dx / h (the
multiplier of a hard constraint, as XPBD reads it); by Newton's third law the object that pushed it
gets -m dx / h at the vertex, and the vertex hands m dx / h on to its bones through the flesh (in the
quasi-static limit the flesh's own momentum is left out: the impulse goes to the bone that carries
the vertex, ``Model.skin_body``). :func:`record` adds one correction to the sums as it is applied
(``query.apply_vertex``); :func:`frame_wrenches` turns a frame's sums into mean forces and torques:

    F_obj = -sum(m dx) / (s h^2),  tau_obj = -sum((x - c_obj) x m dx) / (s h^2)
    F_bone = +sum(m dx) / (s h^2), tau_bone = +sum((x - c_bone) x m dx) / (s h^2)

over the frame's s substeps, about each object's and bone's centre of mass ``c`` (MuJoCo's
``xipos``). Sum over objects + sum over bones = 0 term by term (each correction lands once on each
side), so Newton's third law holds to float rounding. The object of a correction is the one the
vertex's last push in that pass came from (``PushSums.vertex_obj``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.struct
class Exchange:
    """The sums one frame's contact corrections add to (one kernel argument; empty arrays: off).

    mass (V,) float kg: each vertex's mass (0 for kinematic ones); body (V,) int: the bone that
    carries skin vertex i (Model.skin_body; -1: none); h s: the substep; obj_mu (K,): each object's
    Coulomb friction coefficient against the skin; obj_vel (K,) vec3 m/s and obj_omega (K,) vec3 rad/s:
    its velocity at its centre and angular velocity (world frame, set per frame); obj_fric (K,) vec3
    kg m: the friction corrections' share of obj_lin; obj_inv_mass (K,) 1/kg and obj_inv_inertia
    (K,) mat33 1/(kg m^2, world frame): a movable object's (0: static or kinematic); sub_lin / sub_ang
    (K,): obj_lin / obj_ang of the current substep only; dv / dw (K,) m/s, rad/s: the velocity the
    skin has given each object so far this frame; shift (K,) m and turn (K,) quat: how far that has
    moved and turned it about its centre; base_pose (G,) transform: the geoms' poses MuJoCo gave the
    frame (Objects.pose before the skin moved them); obj_com (K,) vec3 m and bone_com (B,) vec3 m:
    the centres of mass torques are taken about (set per frame); obj_lin / obj_ang (K,) vec3 and
    bone_lin / bone_ang (B,) vec3: sum(m dx) (kg m) and sum((x - c) x m dx) (kg m^2) of the frame's
    corrections, on the skin's side (the objects get minus these)."""

    mass: wp.array(dtype=float)
    body: wp.array(dtype=int)
    h: float
    obj_mu: wp.array(dtype=float)
    obj_vel: wp.array(dtype=wp.vec3)
    obj_omega: wp.array(dtype=wp.vec3)
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
    base_pose: wp.array(dtype=wp.transform)
    bone_com: wp.array(dtype=wp.vec3)
    obj_lin: wp.array(dtype=wp.vec3)
    obj_ang: wp.array(dtype=wp.vec3)
    bone_lin: wp.array(dtype=wp.vec3)
    bone_ang: wp.array(dtype=wp.vec3)


def make_exchange(model, n_objects: int, on: bool, h: float, g_count: int = 0) -> Exchange:
    """An :class:`Exchange` for ``model``'s skin against ``n_objects`` objects, substeps of ``h`` s
    (``on`` False: empty arrays, :func:`record` and :func:`friction` do nothing)."""
    d = model.device
    e = Exchange()
    k, b = (max(n_objects, 1), max(model.n_bodies, 1)) if on else (0, 0)
    inv = model.inv_mass.numpy()[: model.n_skin] if on else np.zeros(0)
    e.mass = wp.array(np.where(inv > 0, 1.0 / np.maximum(inv, 1e-30), 0.0).astype(np.float32), dtype=float, device=d)
    e.body = model.skin_body if on else wp.zeros(0, dtype=int, device=d)
    e.h = float(h)
    e.obj_mu = wp.zeros(k, dtype=float, device=d)
    e.obj_vel, e.obj_omega = wp.zeros(k, dtype=wp.vec3, device=d), wp.zeros(k, dtype=wp.vec3, device=d)
    e.obj_fric = wp.zeros(k, dtype=wp.vec3, device=d)
    e.obj_com = wp.zeros(k, dtype=wp.vec3, device=d)
    e.obj_inv_mass = wp.zeros(k, dtype=float, device=d)
    e.obj_inv_inertia = wp.zeros(k, dtype=wp.mat33, device=d)
    e.sub_lin, e.sub_ang = wp.zeros(k, dtype=wp.vec3, device=d), wp.zeros(k, dtype=wp.vec3, device=d)
    e.dv, e.dw = wp.zeros(k, dtype=wp.vec3, device=d), wp.zeros(k, dtype=wp.vec3, device=d)
    e.shift = wp.zeros(k, dtype=wp.vec3, device=d)
    e.turn = wp.array(np.tile(np.array([0, 0, 0, 1.0], np.float32), (k, 1)), dtype=wp.quat, device=d)
    e.base_pose = wp.zeros(max(g_count, 1) if on else 0, dtype=wp.transform, device=d)
    e.bone_com = wp.zeros(b, dtype=wp.vec3, device=d)
    e.obj_lin, e.obj_ang = wp.zeros(k, dtype=wp.vec3, device=d), wp.zeros(k, dtype=wp.vec3, device=d)
    e.bone_lin, e.bone_ang = wp.zeros(b, dtype=wp.vec3, device=d), wp.zeros(b, dtype=wp.vec3, device=d)
    return e


@wp.func
def friction(ex: Exchange, i: int, obj: int, xi: wp.vec3, x_start: wp.vec3, dxn: wp.vec3):
    """Coulomb friction of skin vertex ``i`` (at ``xi``; ``x_start`` at the substep's start) against
    object ``obj``, whose contact correction ``dxn`` this pass is the normal impulse m |dxn| / h: the
    vertex's slip over the substep, its motion less the object's surface motion there, tangent to
    ``dxn``, is undone where it is within mu |dxn| (sticking), else cut by mu |dxn| (sliding).
    Returns the correction to add (0 where two-way coupling is off)."""
    if i >= ex.mass.shape[0] or obj < 0 or obj >= ex.obj_lin.shape[0]:
        return wp.vec3(0.0)
    dn = wp.length(dxn)
    if dn <= 0.0:
        return wp.vec3(0.0)
    n = dxn / dn
    x1 = xi + dxn
    u = x1 - x_start - (ex.obj_vel[obj] + wp.cross(ex.obj_omega[obj], x1 - ex.obj_com[obj])) * ex.h
    ut = u - n * wp.dot(u, n)
    s = wp.length(ut)
    lim = ex.obj_mu[obj] * dn
    if s <= lim:
        return -ut
    return -ut * (lim / s)


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


@wp.kernel
def move_objects(ex: Exchange):
    """After a substep's contact: each movable object takes the substep's impulse from the skin
    (minus the skin's: -sum(m dx) / h) into its velocity change, and moves by the velocity change so
    far over the substep (the object's own motion is MuJoCo's: the frame's pose already has it)."""
    k = wp.tid()
    lin = ex.sub_lin[k]
    ang = ex.sub_ang[k]
    ex.sub_lin[k] = wp.vec3(0.0)
    ex.sub_ang[k] = wp.vec3(0.0)
    im = ex.obj_inv_mass[k]
    if im <= 0.0:
        return
    dv = ex.dv[k] - lin * (im / ex.h)
    dw = ex.dw[k] - ex.obj_inv_inertia[k] * ang * (1.0 / ex.h)
    ex.dv[k] = dv
    ex.dw[k] = dw
    ex.shift[k] = ex.shift[k] + dv * ex.h
    a = wp.length(dw) * ex.h
    if a > 0.0:
        ex.turn[k] = wp.normalize(wp.quat_from_axis_angle(wp.normalize(dw), a) * ex.turn[k])


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
    ops = [ex.obj_fric.zero_, ex.bone_lin.zero_, ex.bone_ang.zero_,
           lambda: wp.launch(reset_objects, ex.obj_lin.shape[0], [ex], device=ex.obj_lin.device)]
    if objects is not None:
        ops.append(lambda: wp.copy(ex.base_pose, objects.pose, count=min(ex.base_pose.shape[0], objects.pose.shape[0])))
    return ops


def frame_wrenches(ex: Exchange, substep_dt: float, substeps: int) -> dict:
    """The last frame's mean wrenches (N, N m, world frame): ``objects`` (K, 6) [force, torque about
    each object's centre] that the skin applied to each object, ``friction`` (K, 3) the friction
    part of each force, ``bones`` (B, 6) the reaction on each bone. ``objects.sum(0)[:3] ==
    -bones.sum(0)[:3]`` to float rounding."""
    if ex.obj_lin.shape[0] == 0:
        return dict(objects=np.zeros((0, 6)), friction=np.zeros((0, 3)), bones=np.zeros((0, 6)))
    scale = 1.0 / (substeps * substep_dt * substep_dt)
    obj = np.concatenate([ex.obj_lin.numpy(), ex.obj_ang.numpy()], axis=1).astype(np.float64) * -scale
    bone = np.concatenate([ex.bone_lin.numpy(), ex.bone_ang.numpy()], axis=1).astype(np.float64) * scale
    return dict(objects=obj, friction=ex.obj_fric.numpy().astype(np.float64) * -scale, bones=bone,
                dv=ex.dv.numpy().astype(np.float64), dw=ex.dw.numpy().astype(np.float64),
                shift=ex.shift.numpy().astype(np.float64), turn=ex.turn.numpy().astype(np.float64))
