"""``BatchPhysics``: W copies of a suite domain stepped together, MuJoCo by MuJoCo Warp and the soft
hands by one :class:`~physhand_mj.batch.BatchedHands`, coupled world by world as
:class:`~physhand_dmc.physics.SoftPhysics` couples one (issue 54).

- MuJoCo's side: ``mujoco_warp`` (``mjw.put_model``, ``mjw.put_data(..., nworld=W)``, ``mjw.step``)
  on the solver's device, float32. Chosen over MuJoCo's threaded C rollout (``mujoco.rollout``):
  the two-way exchange needs each world's kinematics at the step's start, its mass matrix factor
  and ``M^-1 J^T`` of the skin's impulses, which MuJoCo Warp keeps for every world on the device
  (``apply_ft``, ``solve_m``) and the rollout's state vectors do not (docs/training.md, the
  measured step costs of both).
- Per MuJoCo step: ``mjw.step``; one-way: ``mjw.kinematics`` after it (dm_control's legacy step
  leaves data's kinematics at the step's end: the soft frame follows the bones there); two-way:
  the step's start (as ``SoftPhysics`` with ``mj_step``). Then one soft frame of every world: the
  bones' and objects' poses (and two-way: the objects' velocities, the step's acceleration, the
  inertial frames) in, and two-way: ``qvel += M^-1 J^T [impulses]`` and a touched free object's
  pose out (``SoftHand._apply_wrenches`` for all worlds at once: ``coupling.apply_impulses``).
- ``sensor``: the soft signals of every world (:class:`~physhand_dmc.sensing.SoftSensor` with
  ``worlds``), pooled after each frame.
- ``reset_worlds(mask, ...)``: a new episode in the masked worlds only (the rest keep their state:
  MuJoCo's and the soft tissue's are put back after the reset's frames).

Worlds never interact (their objects are their own; BatchedHands solves each at its own place).
"""

from __future__ import annotations

import contextlib

import mujoco
import numpy as np
import warp as wp

from physhand_dmc.sensing import SoftSensor
from physhand_mj.asset import load_asset
from physhand_mj.batch import BatchedHands
from physhand_mj.coupling import (check_two_way, free_qpos, friction_coefficients, geom_spec, proxy_margin, rest_placement,
                                  select_object_geoms, _settling)
from physhand_mj.hand_mjcf import body_ids, set_proxy_margin, skin_geom_id
from physhand_mj.rotations import nlerp

# the soft tissue's per-vertex state a reset of some worlds puts back in the others
_SOFT_ARRAYS = ("x", "v", "x_prev", "x_safe", "delta")
# MuJoCo Warp's per-world state a reset of some worlds puts back in the others
_MJ_ARRAYS = ("qpos", "qvel", "act", "ctrl", "qacc_warmstart", "mocap_pos", "mocap_quat", "time", "qacc",
              "xfrc_applied", "qfrc_applied")


@wp.kernel
def _gather(src: wp.array2d(dtype=float), idx: wp.array(dtype=int), width: int, col: int, out: wp.array2d(dtype=float)):
    """out[w, col + j] = component j % width of element idx[j // width] of world w's row of ``src``
    (a MuJoCo Warp field seen as floats: vec3 3, quat 4, mat33 9 row-major, float 1 per element)."""
    w, j = wp.tid()
    i = j // width
    out[w, col + j] = src[w, idx[i] * width + j - i * width]


@wp.kernel
def _add_rows(dst: wp.array2d(dtype=float), add: wp.array2d(dtype=float)):
    w, i = wp.tid()
    dst[w, i] = dst[w, i] + add[w, i]


@wp.kernel
def _set_masked(dst: wp.array2d(dtype=float), idx: wp.array(dtype=int), value: wp.array2d(dtype=float),
                mask: wp.array2d(dtype=int)):
    """dst[w, idx[i]] = value[w, i] where mask[w, i] (a touched free object's qpos)."""
    w, i = wp.tid()
    if mask[w, i] != 0:
        dst[w, idx[i]] = value[w, i]


def mat_to_quat(mats: np.ndarray) -> np.ndarray:
    """(..., 4) w x y z unit quaternions of rotation matrices (..., 3, 3) (Shepperd's method, every
    branch computed and the stable one kept: vectorised ``mju_mat2Quat``)."""
    m = np.asarray(mats, np.float64)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cands = np.stack([
        np.stack([1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
        np.stack([m[..., 2, 1] - m[..., 1, 2], 1 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                  m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
        np.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                  1 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2], m[..., 1, 2] + m[..., 2, 1]], -1),
        np.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1],
                  1 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2]], -1)], -2)
    diag = np.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    pick = np.argmax(diag, -1)
    q = np.take_along_axis(cands, pick[..., None, None], -2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


class BatchPhysics:
    """W worlds of one compiled MuJoCo ``model`` (a suite domain's), each with the soft hand; see the
    module docstring. ``config``: the soft hand's (``frame_dt`` = the model's timestep; its
    ``device`` runs both MuJoCo Warp and the solver); ``object_bodies``: the bodies the skin
    collides with (as ``SoftHand``'s). ``nconmax`` / ``njmax``: MuJoCo Warp's contact and
    constraint rows per world (None: its defaults)."""

    def __init__(self, model: mujoco.MjModel, worlds: int, config, object_bodies=None, *, asset=None,
                 nconmax: int | None = None, njmax: int | None = None):
        import mujoco_warp as mjw

        self.mjw = mjw
        self.model, self.worlds = model, int(worlds)
        self.config = config.validate()
        self.two_way = bool(self.config.two_way)
        if self.two_way:
            check_two_way(model, self.config)
        self.asset = asset if asset is not None else load_asset()
        self.device = wp.get_device(self.config.device)
        data = mujoco.MjData(model)
        mujoco.mj_resetDataKeyframe(model, data, 0) if model.nkey else mujoco.mj_resetData(model, data)
        mujoco.mj_forward(model, data)
        self.bones = body_ids(model, [str(b) for b in self.asset.body_names])
        set_proxy_margin(model, self.bones, proxy_margin(self.config))  # (MuJoCo's side as SoftHand's: coupling.proxy_margin)
        skin = skin_geom_id(model, "")
        self.geoms = select_object_geoms(model, self.bones, skin, bodies=object_bodies)
        specs = [geom_spec(model, data, g) for g in self.geoms]
        first: dict[str, int] = {}  # each object (a MuJoCo body, as BatchedHands groups geoms) -> its first geom
        for i, s in enumerate(specs):
            first.setdefault(s["obj"], i)
        index = {name: j for j, name in enumerate(first)}
        self.object_names = list(first)
        self.object_bodies = np.array([int(model.geom_bodyid[self.geoms[i]]) for i in first.values()], np.int64)
        self.free = free_qpos(model, self.object_bodies)
        static = model.body_weldid[self.object_bodies] == 0
        if np.any((self.free < 0) & ~static):
            bad = [model.body(int(b)).name for b, f, s in zip(self.object_bodies, self.free, static) if f < 0 and not s]
            raise ValueError(f"BatchPhysics: objects {bad} are neither free nor fixed to the world (mocap or jointed "
                             "objects are not batched yet): use SoftPhysics")
        self.free_dof = np.array([model.jnt_dofadr[model.body_jntadr[b]] if f >= 0 else -1
                                  for b, f in zip(self.object_bodies, self.free)], np.int64)
        W = self.worlds
        self._skin, self._geom_objects = skin, [index[s["obj"]] for s in specs]
        mu = friction_coefficients(model, skin, self.geoms, self._geom_objects, len(self.object_bodies))
        mass = np.where(self.free >= 0, model.body_mass[self.object_bodies], 0.0)
        two_way = dict(object_mass=np.tile(mass, (W, 1)), object_inertia=np.tile(model.body_inertia[self.object_bodies],
                                                                                  (W, 1, 1)),
                       object_friction=np.tile(mu, (W, 1))) if self.two_way and specs else {}
        place = rest_placement(self.asset, data.xpos[self.bones[0]], data.xquat[self.bones[0]])
        self.hands = BatchedHands(self.asset, W, self.config, np.tile(place[0], (W, 1)), np.tile(place[1], (W, 1)),
                                  objects=specs, **two_way)
        self.sensor = SoftSensor(self.hands, W)
        with wp.ScopedDevice(self.device):
            self.m = mjw.put_model(model)
            self.d = mjw.put_data(model, data, nworld=W, nconmax=nconmax, njmax=njmax)
            self._qfrc = wp.zeros((W, model.nv), dtype=float)
            self._dq = wp.zeros((W, model.nv), dtype=float)
        self.dt = float(model.opt.timestep)
        self._plan()
        self._graph = None  # CUDA: the MuJoCo step captured once (launch-bound otherwise)
        self._fields: dict[str, np.ndarray] = {}  # batch_model_fields: each world's values (float64, as written)
        self.frames = 0
        self.bad = np.zeros(W, bool)  # worlds whose MuJoCo state turned non-finite (the env ends their episode)
        self._good = None  # the last finite poses of every world (a bad world's frame keeps them)

    def _plan(self) -> None:
        """What a frame reads of MuJoCo Warp, gathered on the device into one (W, F) buffer (one copy
        to the host a frame instead of a copy of every field)."""
        b, g, o = self.bones, np.asarray(self.geoms, np.int64), self.object_bodies
        dofs = np.concatenate([np.arange(d, d + 6) for d in self.free_dof if d >= 0] or [np.zeros(0, np.int64)])
        plan = [("xpos", b, 3), ("xquat", b, 4), ("geom_xpos", g, 3), ("geom_xmat", g, 9)]
        if self.two_way:
            plan += [("xpos", o, 3, "obj_xpos"), ("xquat", o, 4, "obj_xquat"), ("xipos", o, 3, "obj_xipos"),
                     ("ximat", o, 9, "obj_ximat"), ("xmat", o, 9, "obj_xmat"), ("xipos", b, 3, "bone_xipos"),
                     ("qvel", dofs, 1, "qvel"), ("qacc", dofs, 1, "qacc")]
        self._gathers, col = [], 0
        for field, idx, width, *key in plan:
            src = getattr(self.d, field)
            if not src.is_contiguous:
                raise RuntimeError(f"MuJoCo Warp's {field} is not contiguous: the frame's gather reads it as floats")
            flat = wp.array(ptr=src.ptr, dtype=float, shape=(self.worlds, src.shape[1] * width), device=self.device)
            self._gathers.append((key[0] if key else field, flat, wp.array(np.asarray(idx, np.int32), dtype=int,
                                                                          device=self.device), col, len(idx), width))
            col += len(idx) * width
        self._buf = wp.zeros((self.worlds, max(col, 1)), dtype=float, device=self.device)
        self._buf_host = wp.zeros(self._buf.shape, dtype=float, device="cpu", pinned=self.device.is_cuda)
        self._free_cols = np.concatenate([np.arange(a, a + 7) for a in self.free if a >= 0] or [np.zeros(0, np.int64)])
        self._free_idx = wp.array(self._free_cols.astype(np.int32), dtype=int, device=self.device)
        # the exchange's uploads a frame, allocated once: impulses per body, touched free objects' poses
        pin = self.device.is_cuda
        self._ft = wp.zeros((self.worlds, self.model.nbody), dtype=wp.spatial_vector, device=self.device)
        self._ft_host = wp.zeros(self._ft.shape, dtype=wp.spatial_vector, device="cpu", pinned=pin)
        nf = max(len(self._free_cols), 1)
        self._moved = wp.zeros((self.worlds, nf), dtype=float, device=self.device)
        self._moved_host = wp.zeros((self.worlds, nf), dtype=float, device="cpu", pinned=pin)
        self._touched = wp.zeros((self.worlds, nf), dtype=int, device=self.device)
        self._touched_host = wp.zeros((self.worlds, nf), dtype=int, device="cpu", pinned=pin)

    def _gather(self) -> dict:
        """The frame's inputs of every world (see _plan), float64 host arrays shaped (W, n, width)."""
        for key, flat, idx, col, n, width in self._gathers:
            if n:
                wp.launch(_gather, (self.worlds, n * width), inputs=[flat, idx, width, col], outputs=[self._buf],
                          device=self.device)
        wp.copy(self._buf_host, self._buf)
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
        buf = self._buf_host.numpy().astype(np.float64)
        out = {}
        for key, flat, idx, col, n, width in self._gathers:
            a = buf[:, col: col + n * width].reshape(self.worlds, n, width)
            out[key] = a[..., 0] if width == 1 else (a.reshape(self.worlds, n, 3, 3) if width == 9 else a)
        return out

    # -- MuJoCo Warp's arrays, on the host ---------------------------------------------------------
    def host(self, name: str) -> np.ndarray:
        """MuJoCo Warp data field ``name`` of every world as float64 NumPy (a copy)."""
        return getattr(self.d, name).numpy().astype(np.float64)

    def set_host(self, name: str, value: np.ndarray) -> None:
        arr = getattr(self.d, name)
        arr.assign(wp.array(np.asarray(value, np.float32).reshape(arr.shape), dtype=arr.dtype, device="cpu"))

    def set_ctrl(self, ctrl: np.ndarray) -> None:
        """Each world's actuator controls (W, nu), in the actuators' units."""
        self.set_host("ctrl", np.asarray(ctrl, np.float64).reshape(self.worlds, self.model.nu))

    # -- per-world model fields (a task's per-episode randomisation) -----------------------------
    def batch_model_fields(self, *names: str) -> None:
        """MuJoCo Warp model fields ``names`` with one row per world (batchable fields, shaped
        ``("*", ...)`` in ``mujoco_warp.Model``: ``body_mass``, ``body_inertia``, ``geom_friction``,
        ...; MuJoCo Warp's kernels read row ``world % rows``), each the model's value until
        :meth:`set_model_field` writes it. Allocated once: later writes go into the same arrays (a
        captured CUDA graph holds their pointers); a new allocation drops the graph, captured again
        at the next step."""
        import dataclasses

        from mujoco_warp._src import types

        specs = {f.name: f.type for f in dataclasses.fields(types.Model)}
        for name in names:
            if name in self._fields:
                continue
            shape = getattr(specs.get(name), "shape", ())
            if not shape or shape[0] != "*":
                raise ValueError(f"MuJoCo Warp model field {name!r} is not batchable (its shape is not ('*', ...))")
            arr = getattr(self.m, name)
            host = np.array(getattr(self.model, name), np.float64)
            host = np.broadcast_to(host.reshape((1,) + host.shape), (self.worlds,) + host.shape).copy()
            new = wp.array(host.astype(np.float32), dtype=arr.dtype, device=self.device)
            new._is_batched = True  # (as mujoco_warp.put_model marks its batched arrays)
            setattr(self.m, name, new)
            self._fields[name] = host
            self._graph = None

    def model_field(self, name: str) -> np.ndarray:
        """(W, ...) each world's value of MuJoCo model field ``name`` (float64, as written: MuJoCo Warp
        holds it in float32); the model's, tiled, for a field not batched."""
        if name in self._fields:
            return self._fields[name].copy()
        host = np.array(getattr(self.model, name), np.float64)
        return np.broadcast_to(host.reshape((1,) + host.shape), (self.worlds,) + host.shape).copy()

    def set_model_field(self, name: str, value, mask=None) -> None:
        """Write ``value`` (W, ...), or what broadcasts to it, into MuJoCo Warp model field ``name``
        in the worlds of ``mask`` (W,) bool (None: all; the others keep theirs), batching the field
        first (:meth:`batch_model_fields`). Two-way: the soft side's object masses, inertias and
        friction coefficients follow (as SoftHand reads MuJoCo's)."""
        self.batch_model_fields(name)
        host = self._fields[name]
        value = np.broadcast_to(np.asarray(value, np.float64), host.shape)
        if mask is None:
            host[:] = value
        else:
            mask = np.asarray(mask, bool)
            host[mask] = value[mask]
        arr = getattr(self.m, name)
        arr.assign(wp.array(host.astype(np.float32), dtype=arr.dtype, device="cpu"))  # (in place)
        if name in ("body_mass", "body_inertia", "geom_friction"):
            self._objects_from_model()

    def _objects_from_model(self) -> None:
        """Two-way: each world's object masses, inertias (``body_mass`` / ``body_inertia``) and friction
        coefficients (MuJoCo's rule on ``geom_friction``: ``coupling.friction_coefficients``) to the
        soft side, from the per-world fields."""
        tw = self.hands.two_way
        if not (self.two_way and tw is not None):
            return
        b = self.object_bodies
        mass = np.where(self.free >= 0, self.model_field("body_mass")[:, b], 0.0)
        tw.set_mass(mass, self.model_field("body_inertia")[:, b])
        skin = float(self.model.geom_friction[self._skin][0]) if self._skin >= 0 else 1.0
        gf = self.model_field("geom_friction")[:, np.asarray(self.geoms, np.int64), 0]
        mu = np.full((self.worlds, len(b)), skin)
        for i, k in enumerate(self._geom_objects):
            mu[:, k] = np.maximum(mu[:, k], gf[:, i])
        tw.mu = mu

    # -- stepping ----------------------------------------------------------------------------------
    def step(self, nstep: int = 1) -> None:
        """``nstep`` MuJoCo steps of every world, each followed by one soft frame (SoftPhysics.step)."""
        for _ in range(int(nstep)):
            self.step_mujoco()
            self.soft_frame()

    def step_mujoco(self) -> None:
        """One MuJoCo Warp step of every world (one-way: with the kinematics of its end after it)."""
        if self.device.is_cuda:
            if self._graph is None:
                with wp.ScopedDevice(self.device), wp.ScopedCapture() as cap:
                    self._mujoco_ops()
                self._graph = cap.graph
            wp.capture_launch(self._graph)
        else:
            self._mujoco_ops()

    def _mujoco_ops(self) -> None:
        with wp.ScopedDevice(self.device):
            self.mjw.step(self.m, self.d)
            if not self.two_way:  # (dm_control's legacy step: kinematics at the step's end)
                self.mjw.kinematics(self.m, self.d)

    def forward(self) -> None:
        """MuJoCo Warp's forward dynamics of every world (kinematics of qpos, as ``mj_forward``)."""
        with wp.ScopedDevice(self.device):
            self.mjw.forward(self.m, self.d)

    def _poses(self, g: dict | None = None):
        """The bones' poses (W, B, 3) / (W, B, 4) and the object geoms' (W, k, 3) / (W, k, 4), and the
        gathered frame inputs (a world whose MuJoCo state is not finite keeps its last finite poses
        and is marked in ``bad``)."""
        g = self._gather() if g is None else g
        keys = ("xpos", "xquat", "geom_xpos", "geom_xmat")
        ok = np.ones(self.worlds, bool)
        for k in keys:
            ok &= np.isfinite(g[k].reshape(self.worlds, -1)).all(1)
        if not ok.all():
            if self._good is None:
                raise FloatingPointError(f"non-finite MuJoCo state in worlds {np.flatnonzero(~ok).tolist()} before any "
                                         "frame: check the model's keyframe / qpos")
            self.bad |= ~ok
            for k in g:  # (every input of the frame: the two-way exchange's too; a bad world's
                if k in ("qvel", "qacc"):  # object stands still in it until the env resets the world)
                    g[k][~ok] = 0.0
                else:
                    g[k][~ok] = self._good[k][~ok]
        self._good = {k: g[k].copy() for k in g}
        return g["xpos"], g["xquat"], g["geom_xpos"], mat_to_quat(g["geom_xmat"]), g

    def soft_frame(self) -> dict:
        """One soft frame of every world with the bones and objects where MuJoCo Warp has them (two-way:
        and the exchange back into MuJoCo Warp's qvel / qpos); the sensor pooled after it."""
        pos, quat, gpos, gquat, g = self._poses()
        if not (self.two_way and self.hands.two_way is not None):
            out = self.hands.step(pos, quat, gpos, gquat)
        else:
            vel, acc = self._object_motion(g)
            out = self.hands.step(pos, quat, gpos, gquat, object_vel=vel, object_vel_start=vel - acc * self.dt,
                                  object_com=g["obj_xipos"], object_iquat=mat_to_quat(g["obj_ximat"]),
                                  bone_com=g["bone_xipos"])
            self._apply(out["two_way"], g["obj_xpos"], g["obj_xquat"])
        self.sensor.launch(self.hands)
        self.frames += 1
        self.last = out
        return out

    def _object_motion(self, g: dict):
        """(vel, acc) (W, n, 6) [linear at the centre of mass, angular], world frame, of each object
        after the step (``coupling.object_motion`` for every world: a free body's qvel / qacc; fixed
        objects 0)."""
        W, n = self.worlds, len(self.object_bodies)
        vel, acc = np.zeros((W, n, 6)), np.zeros((W, n, 6))
        k = 0
        for j in np.flatnonzero(self.free >= 0):  # (objects, not worlds: one or two)
            rot, r = g["obj_xmat"][:, j], g["obj_xipos"][:, j] - g["obj_xpos"][:, j]
            qv, qa = g["qvel"][:, k: k + 6], g["qacc"][:, k: k + 6]
            k += 6
            w = np.einsum("wij,wj->wi", rot, qv[:, 3:])
            al = np.einsum("wij,wj->wi", rot, qa[:, 3:])
            vel[:, j] = np.c_[qv[:, :3] + np.cross(w, r), w]
            acc[:, j] = np.c_[qa[:, :3] + np.cross(al, r), al]
        return vel, acc

    def _apply(self, rep: dict, obj_xpos, obj_xquat) -> None:
        """The frame's impulses into every world's qvel (``M^-1 J^T``, MuJoCo Warp's ``apply_ft`` at
        the bodies' centres of mass and ``solve_m`` with the step's factor) and touched free objects
        to the poses the frame moved them to (``coupling.apply_impulses``, ``SoftHand._apply_wrenches``)."""
        from mujoco_warp._src import support

        m = self.model
        W = self.worlds
        ft = self._ft_host.numpy()  # (W, nbody, 6) float32 view of the pinned buffer (the last frame's
        ft[:] = 0.0  # upload finished: _gather synchronised since)
        movable = (m.body_weldid[self.object_bodies] != 0) & (m.body_mocapid[self.object_bodies] < 0)
        ft[:, self.object_bodies[movable]] += rep["wrench"][:, movable] * self.dt
        ft[:, self.bones] += rep["bones"] * self.dt
        with wp.ScopedDevice(self.device):
            wp.copy(self._ft, self._ft_host)
            support.apply_ft(self.m, self.d, self._ft, self._qfrc, False)
            self.mjw.solve_m(self.m, self.d, self._dq, self._qfrc)
            wp.launch(_add_rows, (W, m.nv), inputs=[self.d.qvel, self._dq])
        touched = np.any(rep["wrench"] != 0, axis=-1) & (self.free >= 0)[None]
        if np.any(touched):
            p, q = BatchedHands.two_way_poses(rep, obj_xpos, obj_xquat)
            free = np.flatnonzero(self.free >= 0)
            self._moved_host.numpy()[:] = np.concatenate([np.c_[p[:, j], q[:, j]] for j in free], axis=1)  # 7 each
            self._touched_host.numpy()[:] = np.repeat(touched[:, free], 7, axis=1)
            wp.copy(self._moved, self._moved_host)
            wp.copy(self._touched, self._touched_host)
            wp.launch(_set_masked, (W, self._moved.shape[1]), inputs=[self.d.qpos, self._free_idx, self._moved,
                                                                       self._touched], device=self.device)

    def reset_keyframe(self, key: int, mask) -> None:
        """The worlds of ``mask`` (W,) bool to MuJoCo keyframe ``key`` (``mj_resetDataKeyframe``: the
        rest of their data zeroed); the others untouched."""
        keys = np.where(np.asarray(mask, bool), int(key), -1).astype(np.int32)
        with wp.ScopedDevice(self.device):
            self.mjw.reset_data_keyframe(self.m, self.d, wp.array(keys, dtype=int))

    # -- episodes ----------------------------------------------------------------------------------
    @contextlib.contextmanager
    def keep_others(self, mask: np.ndarray):
        """Worlds outside ``mask`` (W,) bool come out of the block as they went in (MuJoCo Warp's state
        and the soft tissue's), whatever the block ran in every world (a reset's frames)."""
        mask = np.asarray(mask, bool)
        if mask.all():
            yield
            return
        keep = ~mask
        mj = {k: getattr(self.d, k).numpy().copy() for k in _MJ_ARRAYS if hasattr(self.d, k)}
        st = self.hands.state
        from physhand_mj.solver.model import vertex_world

        vw = vertex_world(self.hands.solver.model.n_vertices, self.hands.solver.model.n_skin, self.worlds)
        soft = {k: getattr(st, k).numpy().copy() for k in _SOFT_ARRAYS}
        body = st.body_pose.numpy().copy()
        host = st.pose_host.copy()
        tw = self.hands.two_way
        prev = None if tw is None or tw._bones_prev is None else tuple(a.copy() for a in tw._bones_prev)
        fresh = None if tw is None else tw._fresh.copy()
        sensor = (self.sensor.region_host.copy(), self.sensor.obj_host.copy())
        bad, good = self.bad.copy(), None if self._good is None else {k: v.copy() for k, v in self._good.items()}
        c = self.hands.solver.contact
        slack = None if c is None or c.slack_check is None else {
            k: getattr(c.slack_check.data, k).numpy().copy() for k in ("slack", "near_motion")}
        ex = None if tw is None else tw.exchange.data  # the skin's friction anchors and loads (two-way)
        anchors = None if ex is None else {k: getattr(ex, k).numpy().copy() for k in ("stick", "load")}
        try:
            yield
        finally:
            for k, a in mj.items():
                now = getattr(self.d, k).numpy().copy()
                now[keep] = a[keep]
                getattr(self.d, k).assign(wp.array(now, dtype=getattr(self.d, k).dtype, device="cpu"))
            rows = keep[vw]
            for k, a in soft.items():
                now = getattr(st, k).numpy().copy()
                now[rows] = a[rows]
                getattr(st, k).assign(wp.array(now, dtype=wp.vec3, device="cpu"))
            B = len(self.asset.body_names)
            brow = np.repeat(keep, B)
            now = st.body_pose.numpy().copy()
            now[:, brow] = body[:, brow]
            st.body_pose.assign(wp.array(now, dtype=wp.transform, device="cpu"))
            st.pose_host[:, brow] = host[:, brow]
            if tw is not None and prev is not None:  # the kept worlds' bones go on from their last pose
                if tw._bones_prev is None:  # (no frame since the reset: the reset worlds start at rest)
                    tw._bones_prev = prev
                    tw._fresh[:] = fresh
                    tw.forget_bones(mask)
                else:
                    tw._bones_prev = tuple(np.where(keep[:, None, None], p, q) for p, q in zip(prev, tw._bones_prev))
                    tw._fresh[keep] = fresh[keep]
            self.bad[keep] = bad[keep]
            if good is not None and self._good is not None:
                for k in self._good:
                    self._good[k][keep] = good[k][keep]
            if anchors is not None:
                srow = np.repeat(keep, self.asset.n_skin)
                for k, a in anchors.items():
                    arr = getattr(ex, k)
                    now = arr.numpy().copy()
                    now[srow] = a[srow]
                    arr.assign(wp.array(now, dtype=arr.dtype, device="cpu"))
            if slack is not None:  # (the feature lists' slack per world: the kept worlds' own)
                for k, a in slack.items():
                    arr = getattr(c.slack_check.data, k)
                    now = arr.numpy().copy()
                    now[keep] = a[keep]
                    arr.assign(wp.array(now, dtype=arr.dtype, device="cpu"))
            R = len(self.sensor.region_names)
            self.sensor.region_host[np.repeat(keep, R)] = sensor[0][np.repeat(keep, R)]
            n = self.sensor.obj_host.shape[0] // self.worlds
            self.sensor.obj_host[np.repeat(keep, n)] = sensor[1][np.repeat(keep, n)]

    def restart_soft(self, settle_frames: int) -> None:
        """The soft tissue of every world back to rest at its bones' current pose, then
        ``settle_frames`` frames moving the bones there with contact (``SoftHand.reset``)."""
        self.forward()
        pos, quat, gpos, gquat, _ = self._poses()
        place = [rest_placement(self.asset, pos[w, 0], quat[w, 0]) for w in range(self.worlds)]
        self.hands.restart(np.array([p[0] for p in place]), np.array([p[1] for p in place]))
        self.hands.set_object_poses(gpos, gquat)
        solver, state = self.hands.solver, self.hands.state
        hp = state.pose_host[1]
        rest_pos = hp[:, :3].astype(float)
        rest_quat = hp[:, [6, 3, 4, 5]].astype(float)  # x y z w -> w x y z
        target_pos, target_quat = pos.reshape(-1, 3), quat.reshape(-1, 4)
        with _settling(solver):
            for k in range(settle_frames):
                a = (k + 1) / settle_frames
                solver.set_body_poses(state, (1 - a) * rest_pos + a * target_pos, nlerp(rest_quat, target_quat, a))
                solver.step(state)
        self.sensor.launch(self.hands)
        self.sync()

    def sync(self) -> None:
        """Wait for the device (the sensor's copies to the host buffers)."""
        if not self.device.is_cpu:
            wp.synchronize_device(self.device)

    def penetration(self) -> tuple[np.ndarray, np.ndarray]:
        """Per world, the last frame's penetrating skin samples (W,) and deepest (W,) um."""
        return self.hands.last_penetration()

    def close(self) -> None:
        self.hands.close()
