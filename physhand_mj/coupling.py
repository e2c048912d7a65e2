"""SoftHand: the soft hand inside a MuJoCo scene (MuJoCo moves bones and objects, the solver moves
the skin, the skin goes back into MuJoCo).

    hand = SoftHand(model, data)           # finds the bones and the skin geom, gathers the objects
    while ...:
        mujoco.mj_step(model, data)
        hand.step()                         # bones + objects in, one solver frame, skin written back
    hand.skin_vertices, hand.contacts(), hand.metrics()

The skin mesh in ``model.mesh_vert`` / ``mesh_normal`` is updated in place. A ``mujoco.Renderer``
made afterwards shows it; an existing one needs ``mujoco.mjr_uploadMesh(model, renderer._mjr_context,
mesh_id)`` (physhand_mj.render.upload_skin does it); the passive viewer needs
``viewer.update_mesh(mesh_id)``. ``hand.skin_mesh_id`` is that id.
"""

from __future__ import annotations

import contextlib
import time

import mujoco
import numpy as np

from physhand_mj.asset import load_asset
from physhand_mj.contact import Objects
from physhand_mj.contact.bones import BONE_CAP, HOLD_DEPTH, KEPT_OUT_DEPTH
from physhand_mj.contact.objects import MJ_GEOM_TYPES
from physhand_mj.hand_mjcf import PROXY_INSET, SKIN_GEOM, body_ids, enable_self_proxies, set_proxy_margin, skin_geom_id
from physhand_mj.solver import Solver, SolverError, make_model
from physhand_mj.rotations import nlerp, quat_to_mat
from physhand_mj.types import Config, GeomType
from physhand_mj.writeback import SkinWriter



def _mat_to_quat(mats: np.ndarray) -> np.ndarray:
    out = np.empty((len(mats), 4))
    for i, m in enumerate(mats):
        mujoco.mju_mat2Quat(out[i], m)
    return out



@contextlib.contextmanager
def _settling(solver):
    """A settle's frames (the bones move from the rest pose to the scene's on purpose): no fast-motion
    or feature-slack warning, and no skin held by bones the sweep passes through objects
    (Contact.bones_free); a user's warning choices are kept."""
    warn = solver.warn_fast_motion, solver.warn_feature_slack
    solver.warn_fast_motion = solver.warn_feature_slack = False
    try:
        with solver.contact.bones_free() if solver.contact is not None and solver.config.bone_hold \
                else contextlib.nullcontext():
            yield
    finally:
        solver.warn_fast_motion, solver.warn_feature_slack = warn

class SoftHand:
    """The layered soft hand of ``asset`` (default: the embedded MyoHand) in a compiled MuJoCo model.

    Args:
      model, data: the scene's MjModel / MjData (the hand included from mjcf/hand/ or attached).
      config: solver options (SI units); ``Config.frame_dt`` defaults to ``model.opt.timestep``.
      asset: the layered body; its ``body_names`` must name bodies of the model (after ``prefix``).
      prefix: the prefix the hand's names carry (``MjSpec.attach(..., prefix=...)``).
      naming: how the model names the bones, as for :func:`physhand_mj.add_skin`: ``"asset"``,
        ``"myosuite_old"``, ``"auto"``, a prefix string, a dict ``{asset name: model name}`` or the
        ``naming`` that ``add_skin`` returned (None: the asset's names after ``prefix``).
      writeback: write the skin into the model's skin mesh geom (``prefix + "physhand_skin"``). False:
        the compiled-model path for a model without the skin (no spec at hand): nothing in the model
        changes, ``skin_vertices`` / ``contacts()`` / ``metrics()`` work as usual and
        :meth:`draw` adds the skin to an ``mjvScene`` for pictures.
      object_geoms / object_bodies / object_groups: restrict contact to these geom names (or ids),
        bodies or geom groups (default: every geom not belonging to the hand).
      settle_frames: frames over which the bones move from the rest pose to the model's current pose
        before the first ``step`` (so a grasp keyframe does not start with a jump).
      settle_contact: whether the skin already collides while settling (False: the first ``step``
        starts from the undeformed posed skin, penetrations included, as offline rollouts of grasp
        poses want).
    Raises ValueError for a model without the hand, missing bone bodies, an ``object_*`` entry that
    names nothing outside the hand, unsupported object geoms (height fields, SDF plugins: filter
    them out), SolverError for non-finite bone poses.
    """

    def __init__(self, model, data, config: Config | None = None, *, asset=None, prefix: str = "",
                 object_geoms=None, object_bodies=None, object_groups=None, settle_frames: int = 20,
                 settle_contact: bool = True, naming=None, writeback: bool = True):
        self.model, self.data = model, data
        self.asset = asset if asset is not None else load_asset()
        cfg = config or Config(frame_dt=float(model.opt.timestep))
        self.config = cfg.validate()
        self.naming = None
        if naming is not None:  # the bones' names (and the skin geom's prefix) from a naming scheme
            from physhand_mj.attach import resolve_naming

            self.naming = resolve_naming([model.body(b).name for b in range(model.nbody)], naming, self.asset, prefix)
            prefix = self.naming.prefix
        self.writeback = bool(writeback)
        if self.writeback:
            self.skin_geom = skin_geom_id(model, prefix)
        else:  # compiled-model path: a skin geom, if any, is only kept out of the objects
            self.skin_geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, prefix + SKIN_GEOM)
        self.skin_mesh_id = check_skin_mesh(model, self.skin_geom, self.asset) if self.writeback else -1
        if naming is None:
            self.bones = body_ids(model, [prefix + str(b) for b in self.asset.body_names])
        else:
            self.bones = body_ids(model, self.naming.bones)
        self.prefix = prefix
        # Config.self_collision: MuJoCo keeps the parts' bones a flesh apart (hand_mjcf.enable_self_proxies;
        # turned off again without it, so the model follows the last SoftHand made on it)
        self.self_proxies = enable_self_proxies(model, self.bones, self.config.self_collision and self.config.self_proxies)
        # and from objects: with one-way coupling MuJoCo's proxies alone stop a closing bone, so they keep
        # the flesh's room (Config.tuning.proxy_margin; docs/coupling.md "The bones keep the flesh's room")
        self.proxy_margin = proxy_margin(self.config)
        self.proxies = set_proxy_margin(model, self.bones, self.proxy_margin)
        mujoco.mj_kinematics(model, data)
        self.object_geoms = self._select_objects(object_geoms, object_bodies, object_groups)
        self.objects = Objects(str(self._device()), max(len(self.object_geoms), 1))
        for g in self.object_geoms:
            self._add_geom(g)
        self.solver = Solver(make_model(self.asset, self.config), self.config,
                             objects=self.objects if self.object_geoms else None)
        if self.solver.contact is not None:  # the bones' hold from what MuJoCo does here (contact/bones.py
            # hold_depth): kept out by proxies with a margin, else let a closing bone a little way in (no
            # margin, or no proxies: a skin attached by add_skin)
            kept_out = bool(self.proxy_margin) and len(self.proxies) > 0
            self.solver.contact.set_hold_depth(KEPT_OUT_DEPTH if kept_out else float(HOLD_DEPTH))
        if self.config.two_way:
            check_two_way(model, self.config)
        # Config.two_way: each object's MuJoCo body (Objects.object_names order) and the wrenches applied
        self.object_bodies = object_body_ids(model, self.object_geoms, self.objects)
        self._mu = None  # (K,) friction coefficients, read from the model at the first two-way frame
        self._bones_prev = None  # (centres, quats) of the bones at the last two-way frame
        self._obj_vel = None  # (K, 6) [angular, linear] the objects' velocities after the frame's mj_step
        self._obj_acc = None  # (K, 6) and their accelerations in it (qacc)
        # the skin's sliding friction coefficient (None: the skin geom's, or MuJoCo's default 1 without one)
        self.skin_friction = None
        self._free = free_qpos(model, self.object_bodies)  # (K,) qpos address of a free object's joint, else -1
        self._wrenches = None
        pos, quat = self._bone_poses()
        root_pos, root_quat = self._rest_placement(pos[0], quat[0])
        self.state = self.solver.make_state(root_pos, root_quat)
        self._timing = dict(sync=0.0, solver=0.0, writeback=0.0, frames=0)
        self._writer = None
        self._tail_writer = False  # CUDA: the write-back's device half runs inside the solver's frame graph
        if self.writeback:
            self._writer = SkinWriter(self.model, self.skin_mesh_id, self.asset.skin_faces, self.state.x)
            if not self._writer.device.is_cpu:
                self.solver.set_frame_tail(self._writer.device_ops())
                self._tail_writer = True
        self._last = {}
        rest_pos, rest_quat = self.state.pose_host[1][:, :3].astype(float), self.state.pose_host[1][:, 3:].astype(float)
        rest_quat = np.concatenate([rest_quat[:, 3:], rest_quat[:, :3]], axis=1)  # x y z w -> w x y z
        settler = self.solver if settle_contact or self.solver.contact is None else Solver(self.solver.model, self.config)
        with _settling(settler):
            for k in range(settle_frames):
                a = (k + 1) / settle_frames
                settler.set_body_poses(self.state, (1 - a) * rest_pos + a * pos, nlerp(rest_quat, quat, a))
                settler.step(self.state)
        self._write_back()

    # -- setup -----------------------------------------------------------------------------------
    def _device(self):
        import warp as wp

        return wp.get_device(self.config.device)

    def _select_objects(self, names, bodies, groups) -> list[int]:
        return select_object_geoms(self.model, self.bones, self.skin_geom, names, bodies, groups)

    def _add_geom(self, g: int) -> None:
        spec = geom_spec(self.model, self.data, g)
        if spec["gtype"] == GeomType.MESH:
            spec["mesh_grid_spacing"] = self.config.mesh_grid
        self.objects.add(spec.pop("gtype"), spec.pop("size"), spec.pop("pos"), spec.pop("quat"), **spec)

    def refresh_objects(self) -> int:
        """Re-read the type and size of the object geoms from the model (for scenes that edit
        ``model.geom_size`` / ``geom_type`` between episodes, as MyoSuite's Reorient and ObjHoldRandom
        envs do at reset); returns how many changed. Mesh geoms keep their mesh; a geom that turns
        into or out of a mesh raises ValueError (make a new SoftHand)."""
        from physhand_mj.contact.objects import bounding_radius

        m, h, changed = self.model, self.objects._host, 0
        for i, g in enumerate(self.object_geoms):
            gtype = MJ_GEOM_TYPES.get(int(m.geom_type[g]))
            if gtype is None or (gtype == GeomType.MESH) != (h["gtype"][i] == int(GeomType.MESH)):
                raise ValueError(f"object geom '{m.geom(g).name or g}' changed to or from a mesh or an unsupported "
                                 f"type: make a new SoftHand")
            if gtype == GeomType.MESH:
                continue
            size = np.asarray(m.geom_size[g], np.float32)
            if h["gtype"][i] != int(gtype) or not np.array_equal(h["size"][i], size):
                h["gtype"][i], h["size"][i], h["radius"][i] = int(gtype), size, bounding_radius(gtype, size)
                changed += 1
        if changed:
            self.objects.upload()
        return changed

    def _bone_poses(self):
        pos, quat = self.data.xpos[self.bones].copy(), self.data.xquat[self.bones].copy()
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))):
            bad = [self.model.body(int(b)).name for b, p in zip(self.bones, np.isfinite(pos).all(1) & np.isfinite(quat).all(1)) if not p]
            raise SolverError(f"non-finite MuJoCo pose for bones {bad}: check qpos / ctrl (NaN in data)")
        return pos, quat

    def _rest_placement(self, pos0, quat0):
        return rest_placement(self.asset, pos0, quat0)

    # -- per frame -------------------------------------------------------------------------------
    def step(self) -> dict:
        """One solver frame with the bones and objects where MuJoCo has them now; skin written back."""
        t0 = time.perf_counter()
        two_way = self.config.two_way and self.solver.contact is not None
        pos, quat = self._bone_poses()
        self.solver.set_body_poses(self.state, pos, quat)
        if self.object_geoms:
            g = self.object_geoms
            self.objects.set_poses(self.data.geom_xpos[g], _mat_to_quat(self.data.geom_xmat[g]))
        if self._tail_writer:  # the skin geom's pose for the write-back at the end of the frame's graph
            g = self.skin_geom
            self._writer.set_frame(self.data.geom_xpos[g], self.data.geom_xmat[g].reshape(3, 3))
        if two_way:
            self._send_objects()
        t1 = time.perf_counter()
        out = self.solver.step(self.state)
        t2 = time.perf_counter()
        if two_way:
            self._apply_wrenches()
        self._write_back(after_frame=True)
        t3 = time.perf_counter()
        tm = self._timing
        tm["sync"] += t1 - t0
        tm["solver"] += t2 - t1
        tm["writeback"] += t3 - t2
        tm["frames"] += 1
        self._last = out
        return out

    def _send_objects(self) -> None:
        """Config.two_way: the objects' centres, velocities, friction and, for free bodies, mass and
        inertia, and the bones' centres, to the contact for the next frame."""
        m, d, bodies = self.model, self.data, self.object_bodies
        vel, acc = object_motion(m, d, bodies, self._free)
        mu = None
        if self._mu is None:
            mu = self._mu = friction_coefficients(m, self.skin_geom, self.object_geoms, self.objects.geom_objects,
                                                  len(bodies), self.skin_friction)
        inv_m, inv_i = inverse_inertia(m, d, bodies, self._free)
        com, quat = d.xipos[self.bones].copy(), d.xquat[self.bones].copy()
        bv, bw = bone_velocities(com, quat, self._bones_prev, self.config.frame_dt)
        self._bones_prev = (com, quat)
        self._obj_vel, self._obj_acc = vel, acc
        start = vel - acc * self.config.frame_dt
        self.solver.contact.two_way.set_state(d.xipos[bodies], start[:, 3:], start[:, :3], com, mu, inv_m, inv_i, bv, bw,
                                              acc[:, 3:], acc[:, :3])

    def refresh_friction(self) -> None:
        """Config.two_way: read the friction coefficients (the objects' and the skin's
        ``geom_friction``, ``skin_friction``) from the model again at the next frame; call after
        changing them (they are read once otherwise: a task's per-episode randomisation)."""
        self._mu = None

    def applied_wrenches(self) -> dict:
        """``Config.two_way``: per object (by name, as in :meth:`contacts`), what the skin applied to
        it over the last frame, world frame: ``force`` (3,) N, ``torque`` (3,) N m about its centre of
        mass, ``friction`` (3,) N (the friction part of ``force``); the cheap part of
        :meth:`contacts` (no measures), for logs. Empty without two-way coupling or before a frame."""
        w = self._wrenches
        if w is None:
            return {}
        return {name: dict(force=w["objects"][k][:3].copy(), torque=w["objects"][k][3:].copy(),
                           friction=w["friction"][k].copy()) for k, name in enumerate(self.objects.object_names)}

    def _applied_wrench(self, k: int, idx) -> dict:
        """Config.two_way: what the skin applied to object ``k`` over the last frame (its mean force,
        torque about its centre and friction part, world frame) and where (the contact points, the
        skin vertices ``idx``' positions); nothing without two-way coupling."""
        if self._wrenches is None:
            return {}
        w = self._wrenches
        return dict(force=w["objects"][k][:3].copy(), torque=w["objects"][k][3:].copy(), friction=w["friction"][k].copy(),
                    points=self._skin[idx].copy())

    def _apply_wrenches(self) -> None:
        """Config.two_way: the frame's contact impulses into MuJoCo: every object body that moves and,
        as the reaction, the bones get their impulse (sum m dx / h over the frame, about their
        centres) as one velocity change, qvel += M^-1 J^T [impulses] (mj_applyFT, mj_solveM); a free
        object takes the pose the frame moved it to."""
        m, d = self.model, self.data
        w = self.solver.contact.two_way.wrenches()
        apply_impulses(m, d, self.object_bodies, w["objects"], self.bones, w["bones"], self.config.frame_dt)
        for k, b in enumerate(self.object_bodies):
            a = self._free[k]
            if a < 0 or not np.any(w["objects"][k]):  # untouched: MuJoCo's own step moved it (qpos)
                continue
            # a free object ends where the frame took it: from the pose its step started at (data's
            # kinematics after mj_step), moved at the substep rate from its velocity before the step
            # with the step's acceleration and the skin's impulses (exchange.move_objects); MuJoCo's
            # own move of it in the step is replaced
            c = d.xipos[b]
            q = w["turn"][k][[3, 0, 1, 2]]  # x y z w -> w x y z
            shift = w["shift"][k].copy()
            s, done = self.config.substeps, int(w["steps"][k])
            if done < s:  # substeps without a stage (Config.contact_every > 1, or nothing near): the
                # object moves on over them with its velocity there (the step's acceleration spread on)
                h = self.config.frame_dt / s
                t, ramp = h * (s - done), h * h * (s * (s - 1) - done * (done - 1)) / 2  # sum of (j - 1) h h, j > done
                start = self._obj_vel[k] - self._obj_acc[k] * self.config.frame_dt
                shift += (start[3:] + w["dv"][k]) * t + self._obj_acc[k, 3:] * ramp
                omega = start[:3] + w["dw"][k] + self._obj_acc[k, :3] * (ramp / t)
                ang = float(np.linalg.norm(omega)) * t
                if ang > 0:
                    spin, turned = np.r_[np.cos(ang / 2), omega / np.linalg.norm(omega) * np.sin(ang / 2)], np.zeros(4)
                    mujoco.mju_mulQuat(turned, spin, q)
                    q = turned
            r = quat_to_mat(q[None])[0]
            d.qpos[a: a + 3] = c + shift + r @ (d.xpos[b] - c)
            out = np.zeros(4)
            mujoco.mju_mulQuat(out, q, d.xquat[b])
            d.qpos[a + 3: a + 7] = out / np.linalg.norm(out)
        self._wrenches = w

    def _write_back(self, after_frame: bool = False) -> None:
        """The skin into MuJoCo's mesh; ``after_frame``: right after a ``step`` frame, whose graph
        already ran the write-back's device half on CUDA (only the copies into MuJoCo are left)."""
        if not self.writeback:  # compiled-model path: the world positions only
            skin = self.state.x.numpy()[: self.asset.n_skin].astype(np.float64)
            if not np.all(np.isfinite(skin)):
                raise ValueError("skin vertices hold non-finite values")
            self._skin = skin
            return
        if after_frame and self._tail_writer:
            self._skin = self._writer.finish()
            return
        g = self.skin_geom
        self._skin = self._writer.write(self.data.geom_xpos[g], self.data.geom_xmat[g].reshape(3, 3))

    def draw(self, scene, rgba=(0.87, 0.68, 0.58, 1.0)) -> int:
        """Add the skin as it is now to ``scene`` (a ``mujoco.MjvScene`` after ``mjv_updateScene`` /
        ``Renderer.update_scene``) as one triangle geom per skin face, flat-shaded, colour ``rgba``
        (0-1): the compiled-model path's picture (``writeback=False``); the scene needs room for
        ``len(asset.skin_faces)`` more geoms (``mujoco.Renderer(..., max_geom=...)``). Returns the
        number of triangles added."""
        from physhand_mj.attach import draw_skin

        return draw_skin(scene, self._skin, self.asset.skin_faces, rgba)

    @property
    def skin_vertices(self) -> np.ndarray:
        """(n_skin, 3) world-frame skin positions (m) after the last step (a copy)."""
        return self._skin.copy()

    def reset(self, settle_frames: int = 20) -> None:
        """Start over (a new episode): the rest shape placed at the hand's first bone where MuJoCo has
        it now, velocities, multipliers and timing zeroed, then ``settle_frames`` frames moving the
        bones to their current pose with contact against the objects where they are now (as at
        construction with ``settle_contact=True``). Reuses the state's arrays (recorded frames stay)."""
        import warp as wp

        mujoco.mj_kinematics(self.model, self.data)
        pos, quat = self._bone_poses()
        fresh = self.solver.make_state(*self._rest_placement(pos[0], quat[0]))
        for name in ("x", "v", "x_prev", "x_safe", "delta", "lam_edge", "lam_tet", "lam_dih", "body_pose", "body_sub",
                     "guard"):
            wp.copy(getattr(self.state, name), getattr(fresh, name))
        self.state.pose_host[:] = fresh.pose_host
        self.state.pose_fresh, self.state.time, self.state.frames = fresh.pose_fresh, 0.0, 0
        if self.object_geoms:
            g = self.object_geoms
            self.objects.set_poses(self.data.geom_xpos[g], _mat_to_quat(self.data.geom_xmat[g]))
        rest_pos = fresh.pose_host[1][:, :3].astype(float)
        rest_quat = fresh.pose_host[1][:, [6, 3, 4, 5]].astype(float)  # x y z w -> w x y z
        self.solver.wake(self.state)  # a new episode settles before it may sleep
        self._bones_prev = None  # (Config.two_way: the bones' velocities start over with the episode,
        self._wrenches = None  # and the last episode's applied wrenches are gone)
        if self.solver.contact is not None:  # (its settling frames as the first episode's: no slack, object
            self.solver.contact.new_episode()  # velocity or friction anchor carried over; the friction
            self._mu = None  # coefficients are sent again with the first frame's state)
        with _settling(self.solver):
            for k in range(settle_frames):
                a = (k + 1) / settle_frames
                self.solver.set_body_poses(self.state, (1 - a) * rest_pos + a * pos, nlerp(rest_quat, quat, a))
                self._last = self.solver.step(self.state)
        self._timing = dict(sync=0.0, solver=0.0, writeback=0.0, frames=0)
        self._write_back()

    def contacts(self) -> dict:
        """Contact report of the last frame.

        Returns ``{"objects": {name: {...}}, "pressure_pa": (n_skin,) array}``. Per object (geoms
        grouped by MuJoCo body): ``vertices`` (skin vertex ids the contact moved), ``area_m2`` (their
        share of the skin area), ``force_n`` (normal force estimate: each Eq. 9 projection of a
        vertex of mass m by dx in a substep of length h is an impulse m dx / h, i.e. the multiplier of
        a hard constraint; forces are averaged over the frame's substeps), ``penetration_count`` and
        ``deepest_um`` (the 21-sample metric against that object alone), ``object_in_skin_count``
        and ``object_in_skin_deepest_um`` (that object's surface points inside the skin), and its bones:
        ``bone_clearance_mm`` (the least distance of a skeleton vertex from it; negative: a bone inside it,
        that deep, so no penetration-free skin exists there), ``bones_inside`` (the bodies with a
        vertex inside it) and ``skin_held`` (skin vertices the last frame's contact left where their
        bones carry them because it holds their bone: Config.tuning.bone_hold, contact/bones.py).
        With ``Config.two_way`` also what the skin applied to the object in the last frame (its MuJoCo
        body took it): ``force`` (3,) N and ``torque`` (3,) N m about its centre of mass (means over the
        frame, world frame), ``friction`` (3,) N (the friction part of ``force``) and ``points`` (n, 3) m
        (the skin vertices of ``vertices``).
        ``pressure_pa`` is force per vertex area, a heat map over the skin; ``bone_clearance_mm`` the
        least over all objects (50 mm where no bone is nearer).
        """
        n = self.asset.n_skin
        c = self.solver.contact
        if c is None:
            return {"objects": {}, "pressure_pa": np.zeros(n), "bone_clearance_mm": BONE_CAP * 1e3}
        h, s = self.config.substep_dt, self.config.substeps
        push = c.push.numpy()[:n].astype(float)
        vobj = c.vertex_obj.numpy()[:n]
        force = self.asset.mass[:n] * push / (h * h * s)
        area = vertex_areas(self._skin, self.asset.skin_faces)
        pressure = np.where(area > 0, force / np.maximum(area, 1e-12), 0.0)
        out = {}
        bones = c.bone_report(self.state)
        for k, name in enumerate(self.objects.object_names):
            row = self._measure(k)
            idx = np.flatnonzero((vobj == k) & (push > 0))
            b = bones["objects"].get(k, dict(clearance_m=BONE_CAP, bones=[], skin_held=0))
            out[name] = dict(vertices=idx, area_m2=float(area[idx].sum()), force_n=float(force[idx].sum()),
                             **self._applied_wrench(k, idx),
                             penetration_count=int(round(float(row[0]))), deepest_um=float(row[2]) * 1e6,
                             object_in_skin_count=int(round(float(row[3]))),
                             object_in_skin_deepest_um=float(row[5]) * 1e6,
                             bone_clearance_mm=b["clearance_m"] * 1e3, bones_inside=b["bones"],
                             skin_held=b["skin_held"])
        return {"objects": out, "pressure_pa": pressure, "bone_clearance_mm": bones["bone_clearance_m"] * 1e3}

    def _measure(self, obj: int = -1, order: int = 5) -> np.ndarray:
        """Both measures of the skin as it is now (against object ``obj``, -1: all): [count, sum depth
        m, max depth m] of skin samples on the order-``order`` lattice inside objects, then of object
        surface points inside the skin."""
        return self.solver.contact.measure(self.state, obj=obj, order=order)

    def object_points_inside(self) -> tuple[np.ndarray, np.ndarray]:
        """The objects' surface points inside the skin as it is now: world points (k, 3) m and their
        depths (k,) m (distance to the closest skin point), for pictures and checks."""
        c = self.solver.contact
        return c.object_points_inside(self.state) if c is not None else (np.zeros((0, 3)), np.zeros(0))

    def penetrating_samples(self, order: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """The penetrating skin samples (order-``order`` lattice; the metric's: 5) as the skin is
        now: world points (k, 3) m and their depths (k,) m (for pictures and checks)."""
        c = self.solver.contact
        return c.penetrating_samples(self.state, order) if c is not None else (np.zeros((0, 3)), np.zeros(0))

    def penetration(self, order: int = 5, check: bool = False) -> dict:
        """Both penetration measures of the skin as it is now (e.g. before the first step):
        penetration_count / _max_um / _avg_um (skin samples on the order-``order`` lattice inside
        objects; the paper's metric is order 5, checks use 9 or more) and object_in_skin_count /
        _max_um / _avg_um (object surface points inside the closed skin; ``check``: the denser
        points of ``Contact.check_points``, none of which the contact's feature push uses)."""
        from physhand_mj.contact.metrics import summarize

        if self.solver.contact is None:
            return summarize(np.zeros(6))
        if check:
            return summarize(self.solver.contact.measure(self.state, order=order, check=True))
        return summarize(self._measure(order=order))

    def metrics(self) -> dict:
        """Both penetration measures at the end of the last frame (DESIGN definitions: skin samples
        inside objects, ``penetration_*``; object surface points inside the skin, ``object_in_skin_*``,
        evaluated now unless Config.object_metrics evaluated it in the frame), the guard counts,
        finite flag, the mean time per frame of each stage (ms), and what the last frame ran
        (physhand_mj/solver/activity.py): ``objects_near`` (objects in the work set; -1 on CUDA, where the
        host does not decide it), ``triangles_frame`` / ``triangles_stage`` (the frame's and the
        stages' broadphase lists), ``triangles_tested`` (triangles the contact passes queried),
        ``features_listed``, ``ops_run`` / ``contact_ops_run`` (recorded launches, memsets and refits
        run; with no object near no contact op runs); with object feature points,
        ``feature_slack_mm``, ``skin_motion_mm`` and ``feature_slack_exceeded`` (the last frame with
        contact: the slack its feature lists allowed for, its skin's largest move, whether that move
        reached half the slack: Config.tuning.feature_slack); with Config.region_sleep also
        ``regions_asleep`` (names), ``vertices_asleep`` and ``constraints_solved``
        (physhand_mj/solver/regions.py)."""
        tm = self._timing
        n = max(tm["frames"], 1)
        out = dict(penetration_count=0, penetration_max_um=0.0, penetration_avg_um=0.0, object_in_skin_count=0,
                   object_in_skin_max_um=0.0, object_in_skin_avg_um=0.0)
        out.update(self._last)
        cfg = self.config
        if self.solver.contact is not None and not (cfg.object_metrics and cfg.frame_metrics) and tm["frames"]:
            from physhand_mj.contact.metrics import summarize  # on demand what the frame did not measure (Config.
            # object_metrics, frame_metrics)

            row = self.solver.contact.measure(self.state, objects_side=not cfg.object_metrics)
            asked = ("object_in_skin",) * (not cfg.object_metrics) + ("penetration",) * (not cfg.frame_metrics)
            out.update({k: v for k, v in summarize(row).items() if k.startswith(asked)})
        out["finite"] = bool(np.all(np.isfinite(self._skin)))
        out.update(ms_sync=1e3 * tm["sync"] / n, ms_solver=1e3 * tm["solver"] / n, ms_writeback=1e3 * tm["writeback"] / n,
                   ms_per_frame=1e3 * (tm["sync"] + tm["solver"] + tm["writeback"]) / n, frames=tm["frames"])
        return out


def proxy_margin(config) -> float | None:
    """The MuJoCo contact margin (m) for the hand's object proxies under ``config``
    (``Config.tuning.proxy_margin``; None: ``PROXY_INSET`` with one-way coupling, 0 (the shipped
    proxies' own) with two-way, so a model follows the last SoftHand made on it)."""
    m = config.proxy_margin
    if m is None:
        return 0.0 if config.two_way else PROXY_INSET
    return float(m)


def select_object_geoms(model, bones, skin_geom: int, names=None, bodies=None, groups=None) -> list[int]:
    """The geoms the skin collides with: every geom outside the hand (the trees of the ``bones``'
    bodies) but the skin geom, restricted to geom ``names`` (or ids), ``bodies`` and geom ``groups``
    when given. Raises ValueError for an entry of ``names`` / ``bodies`` / ``groups`` that matches no
    geom outside the hand (a misspelt name would otherwise turn contact off without a word), and for
    a geom type the skin cannot collide with."""
    m = model
    rootid = m.body_rootid.tolist()
    roots = {rootid[int(b)] for b in bones}
    hand = {b for b in range(m.nbody) if rootid[b] in roots and b != 0}
    body_of = m.geom_bodyid.tolist()  # (plain lists and mj_id2name: no per-geom accessor objects)
    cand = [(g, mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or "",
             mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, body_of[g]) or "", int(m.geom_group[g]))
            for g in range(m.ngeom) if g != skin_geom and body_of[g] not in hand]
    # a lone name or number is a list of one (else "bal" in "ball" would match a substring)
    names, bodies, groups = ([x] if isinstance(x, (str, int, np.integer)) else x for x in (names, bodies, groups))
    for arg, noun, nouns, given, col in (("object_geoms", "geom", "geoms", names, 1),
                                         ("object_bodies", "body", "bodies", bodies, 2),
                                         ("object_groups", "geom group", "geom groups", groups, 3)):
        have = {c[col] for c in cand} | ({c[0] for c in cand} if col == 1 else set())  # (geoms: ids too)
        unknown = [x for x in (given or ()) if x not in have]
        if unknown:
            listed = sorted({str(c[col]) for c in cand if c[col] != ""})
            more = f", ... ({len(listed)} in all)" if len(listed) > 8 else ""
            raise ValueError(f"{arg}: no {noun} {', '.join(map(repr, unknown))} outside the hand; the model's "
                             f"{nouns} outside the hand: {', '.join(listed[:8]) or 'none'}{more}")
    out = []
    for g, name, body, group in cand:
        if names is not None and name not in names and g not in names:  # names or ids (unnamed geoms)
            continue
        if bodies is not None and body not in bodies:
            continue
        if groups is not None and group not in groups:
            continue
        if int(m.geom_type[g]) not in MJ_GEOM_TYPES:
            kind = mujoco.mjtGeom(int(m.geom_type[g])).name
            raise ValueError(f"geom '{name or g}' is a {kind}, which the soft skin cannot collide with; "
                             f"leave it out with object_geoms / object_bodies / object_groups")
        out.append(g)
    return out


def geom_spec(model, data, g: int) -> dict:
    """:meth:`Objects.add`'s arguments for MuJoCo geom ``g`` as ``data`` has it now: ``gtype``,
    ``size`` (m), ``pos`` (m), ``quat`` (w x y z), ``name``, ``obj`` (its body's name: geoms of one
    body form one object) and, for a mesh, ``vertices``, ``faces`` and ``mesh_range``."""
    m, d = model, data
    gtype = MJ_GEOM_TYPES[int(m.geom_type[g])]
    name = m.geom(g).name or f"geom{g}"
    body = m.body(int(m.geom_bodyid[g])).name or name
    quat = _mat_to_quat(d.geom_xmat[g].reshape(1, 9))[0]
    if gtype == GeomType.MESH:
        mid = int(m.geom_dataid[g])
        va, vn = m.mesh_vertadr[mid], m.mesh_vertnum[mid]
        fa, fn = m.mesh_faceadr[mid], m.mesh_facenum[mid]
        return dict(gtype=gtype, size=None, pos=d.geom_xpos[g], quat=quat, name=name, obj=body,
                    vertices=m.mesh_vert[va: va + vn], faces=m.mesh_face[fa: fa + fn],
                    mesh_range=float(2 * m.geom_rbound[g] + 0.01))
    return dict(gtype=gtype, size=m.geom_size[g], pos=d.geom_xpos[g], quat=quat, name=name, obj=body)


def check_two_way(model, config) -> None:
    """What two-way coupling needs of the MuJoCo model (ValueError saying what to change): a solver
    frame as long as MuJoCo's step (the impulses are the step's, and a free object is moved over
    it), and a one-stage integrator (after ``mj_step`` data's kinematics must be the step's start)."""
    dt = float(model.opt.timestep)
    if abs(config.frame_dt - dt) > 1e-12 * max(dt, 1.0):
        raise ValueError(f"Config.two_way: Config.frame_dt ({config.frame_dt} s) must equal the model's timestep "
                         f"({dt} s): set Config(frame_dt={dt}, ...) or model.opt.timestep")
    if model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4:
        raise ValueError("Config.two_way: MuJoCo's RK4 integrator leaves data's kinematics at its last stage, not "
                         "the step's start; use Euler or implicitfast (model.opt.integrator)")


# -- the MuJoCo side of two-way coupling (Config.two_way), per MjModel / MjData: SoftHand's and the
# batched rollout's (batch_rollout.py, one call per world) ----------------------------------------
def object_motion(model, data, bodies, free) -> tuple[np.ndarray, np.ndarray]:
    """(vel, acc), each (K, 6) [angular rad/s, linear m/s at the centre of mass], world frame, of the
    object ``bodies`` after ``mj_step``: a free body's velocity is the one its step ended with (qvel;
    data.cvel is the step's start) and ``acc`` the step's own velocity change per second (data.qacc:
    what mj_step integrated; exactly so for Euler, to the gyroscopic terms for the implicit
    integrators), spread over the frame's substeps by the exchange (an object starts the frame with
    ``vel - acc dt`` instead of taking the whole step's gravity at once); other bodies: their velocity
    (mj_objectVelocity) and no acceleration. ``free``: :func:`free_qpos`."""
    vel = np.zeros((len(bodies), 6))
    acc = np.zeros((len(bodies), 6))
    for k, b in enumerate(bodies):
        if free[k] >= 0:
            dof = model.jnt_dofadr[model.body_jntadr[b]]
            rot, r = data.xmat[b].reshape(3, 3), data.xipos[b] - data.xpos[b]
            w = rot @ data.qvel[dof + 3: dof + 6]
            vel[k] = np.r_[w, data.qvel[dof: dof + 3] + np.cross(w, r)]
            al = rot @ data.qacc[dof + 3: dof + 6]
            acc[k] = np.r_[al, data.qacc[dof: dof + 3] + np.cross(al, r)]
        else:
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, int(b), vel[k], 0)
    return vel, acc


def friction_coefficients(model, skin_geom: int, geoms, geom_objects, n_objects: int, skin_friction=None) -> np.ndarray:
    """(K,) each object's friction coefficient against the skin, by MuJoCo's rule for two geoms of
    equal priority (the larger sliding coefficient): the skin's (``skin_friction``, else the skin
    geom's, else MuJoCo's default 1) against each of the object's ``geoms`` (``geom_objects``: the
    object of each)."""
    skin = skin_friction if skin_friction is not None else (
        float(model.geom_friction[skin_geom][0]) if skin_geom >= 0 else 1.0)
    mu = np.full(n_objects, skin)
    for k, g in zip(geom_objects, geoms):
        mu[k] = max(mu[k], float(model.geom_friction[g][0]))
    return mu


def inverse_inertia(model, data, bodies, free) -> tuple[np.ndarray, np.ndarray]:
    """(K,) inverse masses 1/kg and (K, 3, 3) world inverse inertias of the free ``bodies`` (the skin
    moves those within the frame: exchange.move_objects); zero for the others."""
    inv_m = np.zeros(len(bodies))
    inv_i = np.zeros((len(bodies), 3, 3))
    for k, b in enumerate(bodies):
        if free[k] >= 0:
            inv_m[k] = 1.0 / model.body_mass[b]
            r = data.ximat[b].reshape(3, 3)
            inv_i[k] = r @ np.diag(1.0 / np.maximum(model.body_inertia[b], 1e-12)) @ r.T
    return inv_m, inv_i


def bone_velocities(com, quat, prev, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(linear m/s, angular rad/s), each (B, 3), of bones at centres ``com`` (B, 3) and orientations
    ``quat`` (B, 4) w x y z from their poses a frame earlier (``prev``: (com, quat), None: at rest);
    from poses because mocap bones have no qvel."""
    bv, bw = np.zeros((len(com), 3)), np.zeros((len(com), 3))
    if prev is not None:
        bv = (com - prev[0]) / dt
        for j in range(len(com)):
            dq = np.zeros(4)
            mujoco.mju_mulQuat(dq, quat[j], prev[1][j] * np.array([1.0, -1.0, -1.0, -1.0]))
            mujoco.mju_quat2Vel(bw[j], dq, dt)
    return bv, bw


def apply_impulses(model, data, object_bodies, object_wrench, bones, bone_wrench, dt: float) -> None:
    """A two-way frame's contact impulses into MuJoCo as one velocity change, qvel += M^-1 J^T
    [impulses] (mj_applyFT at the bodies' centres of mass, mj_solveM): ``object_wrench`` (K, 6) [N,
    N m] on every object body that can move (not welded to the world, not mocap) and the bones'
    reaction ``bone_wrench`` (B, 6), each times ``dt`` (s)."""
    qimp = np.zeros(model.nv)
    for k, b in enumerate(object_bodies):
        if model.body_weldid[b] != 0 and model.body_mocapid[b] < 0:
            imp = object_wrench[k] * dt
            mujoco.mj_applyFT(model, data, imp[:3], imp[3:], data.xipos[b], int(b), qimp)
    for j, b in enumerate(bones):
        imp = bone_wrench[j] * dt
        mujoco.mj_applyFT(model, data, imp[:3], imp[3:], data.xipos[b], int(b), qimp)
    if model.nv:
        dq = np.zeros(model.nv)
        mujoco.mj_solveM(model, data, dq.reshape(1, -1), qimp.reshape(1, -1))
        data.qvel[:] += dq


def free_qpos(model, bodies) -> np.ndarray:
    """(K,) int: the qpos address of each body's free joint where it has one (a free object), else -1."""
    out = np.full(len(bodies), -1, np.int64)
    for k, b in enumerate(bodies):
        j = model.body_jntadr[b]
        if model.body_jntnum[b] == 1 and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            out[k] = model.jnt_qposadr[j]
    return out


def object_body_ids(model, geoms, objects) -> np.ndarray:
    """(K,) int: the MuJoCo body of each of ``objects``' objects (``Objects.object_names`` order), from
    the geoms ``geoms`` that were added in order."""
    out = np.zeros(len(objects.object_names), np.int64)
    for k, g in zip(objects.geom_objects, geoms):
        out[k] = int(model.geom_bodyid[g])
    return out


def inertia_quats(data, bodies) -> np.ndarray:
    """(k, 4) w x y z orientations of ``bodies``' inertial frames (data.ximat) as ``data`` has them now."""
    return _mat_to_quat(data.ximat[bodies].reshape(-1, 9))


def geom_quats(data, geoms) -> np.ndarray:
    """(k, 4) w x y z orientations of ``geoms`` as ``data`` has them now."""
    return _mat_to_quat(data.geom_xmat[geoms])


def check_skin_mesh(model, skin_geom: int, asset) -> int:
    """The skin geom's mesh id, after checking that it has the asset's skin vertex count."""
    mid = int(model.geom_dataid[skin_geom])
    if model.mesh_vertnum[mid] != asset.n_skin:
        raise ValueError(f"the skin mesh has {model.mesh_vertnum[mid]} vertices, the asset "
                         f"{asset.n_skin}: the MJCF and the asset come from different builds")
    return mid


def rest_placement(asset, pos0, quat0):
    """World pose (position m, quaternion w x y z) of the asset frame when its bone 0 is at
    (pos0, quat0): T_world = T_bone T_bone_rest^-1."""
    r0 = quat_to_mat(asset.body_rest_quat[0])
    rw = quat_to_mat(quat0)
    rot = rw @ r0.T
    pos = pos0 - rot @ asset.body_rest_pos[0]
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, rot.ravel())
    return pos, q


def vertex_areas(x: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A third of the area of each vertex's triangles (m^2)."""
    f = np.asarray(faces)
    a = 0.5 * np.linalg.norm(np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]), axis=1)
    return np.bincount(f.ravel(), np.repeat(a / 3.0, 3), minlength=len(x))
