"""SoftSkin: a gymnasium wrapper that puts the soft skin on a MyoSuite hand environment.

    env = physhand_myosuite.make("myoHandObjHoldFixed-v0")      # or SoftSkin(gymnasium.make(...))
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    info["physhand"]                     # soft-contact observations of this step (units in the keys)
    env.log[-1]                          # the per-step log row: penetration, contact, ms per stage
    frame = env.render()                 # (H, W, 3) uint8, the deformed skin drawn in the env's scene

How (measured choice, see docs/tasks.md): the env's compiled model is left exactly as MyoSuite built
it (ids, dynamics, rewards unchanged: ObjHoldRandom even edits ``model.geom_size[-1]``, which an
added geom would take over) and ``SoftHand(..., writeback=False)`` runs on it: after every env step
(MyoSuite's ``frame_skip`` MuJoCo steps), one solver frame with ``frame_dt`` = the env's control
step, contact against the env's colliding geoms outside the arm. Pictures add the skin to the
scene as triangles (``SoftHand.draw``). The soft-contact pooling (per hand region and per object:
area, force, contacting vertices, deformation) is physhand_dmc's ``SoftSensor``, launched inside
the frame (no extra host sync).

Two-way coupling (``two_way=True`` or ``config=Config(two_way=True)``): the skin's impulses act on
MuJoCo's bodies, which needs a solver frame per MuJoCo step (``SoftHand``: ``frame_dt`` = the
model's timestep; the exchange moves a free object over exactly one step). The wrapper then runs
the env's ``frame_skip`` steps itself, in the env's own physics hook (``_step_physics``, which
MyoSuite's envs call from ``step``): ``mj_step``, one soft frame, ... then MyoSuite's closing
``mj_forward``, so observations and rewards see the state the skin left. An env step costs
``frame_skip`` soft frames (of timestep / substeps each) instead of one; ``info["physhand"]`` and the
log come from the last of them, with ``objects[name]["applied"]``: the force, torque and friction
the skin applied in it (``SoftHand.applied_wrenches``).
"""

from __future__ import annotations

import csv
import dataclasses
import time
import warnings
from pathlib import Path

import gymnasium
import numpy as np

import physhand_mj as ph  # before mujoco: it picks MuJoCo's offscreen GL backend
import mujoco  # noqa: E402
from physhand_mj.contact.bones import BONE_CAP  # noqa: E402

HAND_ENVS = {"asset": ("myoHandReorient8-v0", "myoHandReorient100-v0", "myoHandPoseFixed-v0", "myoHandReachFixed-v0"),
             "myosuite_old": ("myoHandObjHoldFixed-v0", "myoHandKeyTurnFixed-v0", "myoHandPenTwirlFixed-v0",
                              "myoHandObjHoldRandom-v0", "myoHandKeyTurnRandom-v0", "myoHandPenTwirlRandom-v0")}
"""MyoSuite 3.0.0 hand environments by bone naming (checked by tests/test_myosuite.py for some)."""


def env_dt(env) -> float:
    """The control step (s) of a MyoSuite env: ``dt`` where it has one, else MuJoCo's timestep times
    ``frame_skip`` (myoHandReorient* has no ``dt``)."""
    u = env.unwrapped
    dt = getattr(u, "dt", None)
    if dt is None:
        dt = float(u.model.opt.timestep) * int(getattr(u, "frame_skip", 1))
    return float(dt)


def colliding_objects(model, bones) -> list[int]:
    """Geom ids the skin should touch by default: geoms that collide in MuJoCo (contype or
    conaffinity non-zero) on bodies outside the arm that carries the hand's bones."""
    roots = {int(model.body_rootid[b]) for b in bones}
    return [g for g in range(model.ngeom) if int(model.body_rootid[model.geom_bodyid[g]]) not in roots
            and (model.geom_contype[g] or model.geom_conaffinity[g])]


def hand_collisions(model, bones, objects) -> dict[str, list[str]]:
    """Per free object body among ``objects``' geoms (ids or names): the names of the hand's own
    MuJoCo collision geoms (on the arm that carries ``bones``) that can collide with it by MuJoCo's
    contype/conaffinity rule."""
    from physhand_mj.coupling import free_qpos

    roots = {int(model.body_rootid[b]) for b in bones}
    hand = [g for g in range(model.ngeom) if int(model.body_rootid[model.geom_bodyid[g]]) in roots
            and (model.geom_contype[g] or model.geom_conaffinity[g])]
    out: dict[str, list[str]] = {}
    for g in objects:
        g = model.geom(g).id
        b = int(model.geom_bodyid[g])
        if free_qpos(model, [b])[0] < 0:
            continue  # (a static or jointed object is not moved within the frame)
        hits = [model.geom(h).name or f"geom{h}" for h in hand
                if (model.geom_contype[g] & model.geom_conaffinity[h]) or (model.geom_contype[h] & model.geom_conaffinity[g])]
        if hits:
            out.setdefault(model.body(b).name or f"body{b}", []).extend(hits)
    return out


def warn_double_push(model, bones, objects) -> None:
    """Two-way coupling with a free object that MyoHand's own collision geoms also touch: a
    RuntimeWarning saying what to change. MyoHand's capsules lie on the skin (not inside it, as
    physhand's proxies do), so both push the object (ObjHold's object was lost that way:
    docs/tasks.md)."""
    hits = hand_collisions(model, bones, objects)
    if hits:
        which = "; ".join(f"{body}: {len(g)} hand geoms ({', '.join(g[:3])}{', ...' if len(g) > 3 else ''})"
                          for body, g in hits.items())
        warnings.warn(f"two-way coupling: MyoHand's own collision geoms also collide with {which} in MuJoCo, and they "
                      "lie on the soft skin, so both push the object (docs/tasks.md, ObjHold: the object was lost). "
                      "For the skin alone to hold it, take the object out of their collisions before wrapping, e.g. "
                      "physhand_myosuite.hold.skin_only(env.unwrapped.model, BODY)", RuntimeWarning, stacklevel=3)


class SoftSkin(gymnasium.Wrapper):
    """The soft skin on a MyoSuite hand env (see the module docstring).

    Args:
      env: a MyoSuite hand env (``gymnasium.make("myoHand...")``); its ``unwrapped.model`` / ``.data``
        must have the MyoHand bones under either naming.
      naming: the bones' naming (``"auto"``, ``"asset"``, ``"myosuite_old"``, a prefix or a name map).
      config: solver options (SI units); ``frame_dt`` is set to the env's control step (s).
      device, substep_dt: without ``config``: the Warp device (``"cpu"``, ``"cuda"``) and the longest
        solver substep (s): substeps = ceil(env dt / substep_dt), 40 for a 20 ms env step. At 2 ms
        substeps (10 per 20 ms) the fingertip skin sags 2.4 mm off its bones instead of 0.2 mm.
        max_speed (m/s): skin/object speed the frame broadphase covers (``contact_frame_margin`` =
        max_speed x env dt, at least the default 10 mm), and the object feature lists with it
        (``feature_slack`` = that margin: a random policy moves the fingertips 12-20 mm in a 10 ms
        step, past lists cut to the last step's move, which then warn).
      two_way: two-way coupling (``Config.two_way``; or a ``config`` with it): a soft frame after every
        MuJoCo step of the env's frame skip (see the module docstring), ``frame_dt`` the model's timestep.
      object_geoms: geom names or ids the skin collides with (default :func:`colliding_objects`).
      observe: append the soft-contact vector (:attr:`soft_obs_names`) to the observation.
      settle_frames: solver frames that bring the skin from rest to the env's pose at each reset.
      width, height: picture size (pixels) of :meth:`render`; camera: a model camera name, or None for
        a free camera on the hand (``distance`` m, ``azimuth`` / ``elevation`` degrees).
    """

    def __init__(self, env, *, naming="auto", config: ph.Config | None = None, device: str = "cpu",
                 substep_dt: float = 0.0005, max_speed: float = 2.0, two_way: bool = False,
                 object_geoms=None, observe: bool = False, settle_frames: int = 10, width: int = 640,
                 height: int = 480, camera: str | None = None, distance: float = 0.45, azimuth: float = 150.0,
                 elevation: float = -25.0):
        super().__init__(env)
        from physhand_dmc import SensedHand  # the dm-control suite's soft-contact pooling, shared

        u = env.unwrapped
        if getattr(u, "model", None) is None or getattr(u, "data", None) is None:
            raise ValueError(f"{type(u).__name__} has no MuJoCo model/data (env.unwrapped.model, .data): "
                             f"wrap a MyoSuite MuJoCo env")
        self.model, self.data = u.model, u.data
        self.dt = env_dt(env)
        self.two_way = bool(two_way or (config is not None and config.two_way))
        frame = self.dt
        if self.two_way:  # a soft frame per MuJoCo step, run in the env's physics hook
            if not callable(getattr(u, "_step_physics", None)):
                raise ValueError(f"two-way coupling needs a soft frame after every MuJoCo step, and {type(u).__name__} "
                                 f"has no _step_physics hook (MyoSuite's envs step their frame skip there)")
            frame = float(self.model.opt.timestep)
        if config is None:  # the project scenes' substep (5 ms / 10): longer ones let the tissue sag
            margin = max(ph.Config.contact_frame_margin, max_speed * frame)
            config = ph.Config(device=device, substeps=max(1, int(np.ceil(frame / substep_dt - 1e-9))),
                               contact_frame_margin=margin, tuning=ph.Tuning(feature_slack=margin),
                               two_way=self.two_way)
        self.config = dataclasses.replace(config, frame_dt=frame, two_way=self.two_way).validate()
        asset = ph.load_asset()
        from physhand_mj.attach import resolve_naming

        nm = resolve_naming([self.model.body(b).name for b in range(self.model.nbody)], naming, asset)
        bones = [self.model.body(b).id for b in nm.bones]
        objects = colliding_objects(self.model, bones) if object_geoms is None else list(object_geoms)
        if self.two_way:
            warn_double_push(self.model, bones, objects)
        mujoco.mj_forward(self.model, self.data)
        self.hand = SensedHand(self.model, self.data, self.config, asset=asset, naming=nm, writeback=False,
                               object_geoms=objects, settle_frames=0)  # reset() settles
        self.sensor = self.hand.attach_sensor()
        self.settle_frames = settle_frames
        self.observe = observe
        regions = self.sensor.region_names
        self.soft_obs_names = tuple([f"{r}_force_n" for r in regions] + [f"{r}_area_cm2" for r in regions]
                                    + [f"{r}_deformation_mm" for r in regions]
                                    + ["penetration_count", "penetration_max_mm"])
        """Names (with units) of the soft-contact vector appended to the observation (``observe``)."""
        if observe:
            base = env.observation_space
            n = len(self.soft_obs_names)
            self.observation_space = gymnasium.spaces.Box(
                np.concatenate([base.low, np.full(n, -np.inf, np.float32)]).astype(np.float32),
                np.concatenate([base.high, np.full(n, np.inf, np.float32)]).astype(np.float32), dtype=np.float32)
        self.log: list[dict] = []
        self._view = dict(width=width, height=height, camera=camera, distance=distance, azimuth=azimuth,
                          elevation=elevation)
        self._renderer = None
        self._steps = 0
        if self.two_way:
            self._frame, self._soft_s = None, 0.0  # the last soft frame of an env step, its soft time (s)
            u._step_physics = self._step_physics_two_way  # (this env instance's hook only)

    # -- gymnasium ---------------------------------------------------------------------------------
    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.hand.refresh_objects()  # MyoSuite's Reorient / ObjHoldRandom resize their object at reset
        self.hand.reset(self.settle_frames)  # the env's new pose; velocities and multipliers zeroed
        self.log, self._steps = [], 0
        if self.two_way:
            self._frame = None
        soft = self._soft_info()
        info["physhand"] = soft
        return self._observation(obs, soft), info

    def _step_physics_two_way(self, nstep: int | None = None) -> None:
        """The env's physics hook with two-way coupling: per MuJoCo step of the frame skip one soft
        frame (it reads the step's start from data and writes the skin's impulses into qvel, a free
        object's pose into qpos), then MyoSuite's ``mj_forward`` for the observations."""
        u = self.env.unwrapped
        n = int(u.frame_skip) if nstep is None else int(nstep)
        for _ in range(n):
            mujoco.mj_step(self.model, self.data)
            t = time.perf_counter()
            self._frame = self.hand.step()
            self._soft_s += time.perf_counter() - t
        mujoco.mj_forward(self.model, self.data)

    def step(self, action):
        t0 = time.perf_counter()
        if self.two_way:
            self._soft_s = 0.0
        obs, reward, terminated, truncated, info = self.env.step(action)
        t1 = time.perf_counter()
        if self.two_way:  # (the frames ran inside the env's step: its time less theirs is the env's)
            frame = self._frame if self._frame is not None else self.hand._last
            t1 -= self._soft_s
            t2 = t1 + self._soft_s
        else:
            frame = self.hand.step()  # bones + objects where MuJoCo left them, one frame, pooling launched
            t2 = time.perf_counter()
        soft = self._soft_info(frame)
        obs = self._observation(obs, soft)
        t3 = time.perf_counter()
        self._steps += 1
        row = dict(step=self._steps, penetration_count=soft["penetration_count"],
                   penetration_max_um=soft["penetration_max_um"], penetration_avg_um=soft["penetration_avg_um"],
                   contact_vertices=int(self.sensor.region_host[:, 2].sum()),
                   contact_area_cm2=float(self.sensor.region_host[:, 0].sum() * 1e4),
                   contact_force_n=float(self.sensor.region_host[:, 1].sum()), finite=soft["finite"],
                   ms_env=1e3 * (t1 - t0), ms_soft=1e3 * (t2 - t1), ms_obs=1e3 * (t3 - t2))
        for k in ("object_in_skin_count", "object_in_skin_max_um"):
            if k in frame:  # Config.object_metrics: the second measure, evaluated in the frame
                row[k] = frame[k]
        row.update(bone_clearance_mm=soft["bone_clearance_mm"], bones_inside=" ".join(soft["bones_inside"]))
        self.log.append(row)
        info["physhand"] = soft
        return obs, reward, terminated, truncated, info

    def _soft_info(self, frame: dict | None = None) -> dict:
        """The soft-contact observations of the last frame (host reads of the sensor's outputs)."""
        frame = frame if frame is not None else self.hand._last
        reg, obj = self.sensor.region_host, self.sensor.obj_host
        applied = self.hand.applied_wrenches() if self.two_way else {}  # (Config.two_way: what the skin applied)
        names = self.sensor.region_names
        # the bones against the env's objects (contact/bones.py): a bone inside an object leaves no
        # penetration-free skin there, so a deep penetration with a negative clearance is the pose's
        # (MuJoCo's), not the contact's; a task or controller can react to it
        c = self.hand.solver.contact
        bones = c.bone_report(self.hand.state) if c is not None else dict(objects={}, bone_clearance_m=BONE_CAP)
        return dict(
            bone_clearance_mm=float(bones["bone_clearance_m"]) * 1e3,
            bones_inside=sorted({b for o in bones["objects"].values() for b in o["bones"]}),
            region_names=names,
            region_force_n=reg[:, 1].astype(np.float64), region_area_m2=reg[:, 0].astype(np.float64),
            region_vertices=reg[:, 2].astype(np.int64), region_deformation_m=reg[:, 3].astype(np.float64),
            objects={o: dict(area_m2=float(obj[k, 0]), force_n=float(obj[k, 1]), vertices=int(obj[k, 2]),
                             **({"applied": applied[o]} if o in applied else {}))
                     for k, o in enumerate(self.sensor.object_names)},
            penetration_count=int(frame.get("penetration_count", 0)),
            penetration_max_um=float(frame.get("penetration_max_um", 0.0)),
            penetration_avg_um=float(frame.get("penetration_avg_um", 0.0)),
            finite=bool(frame.get("nonfinite", 0) == 0),
        )

    def soft_vector(self, soft: dict) -> np.ndarray:
        """The soft-contact vector (float32, :attr:`soft_obs_names`) of a ``_soft_info`` dict."""
        return np.concatenate([soft["region_force_n"], soft["region_area_m2"] * 1e4, soft["region_deformation_m"] * 1e3,
                               [soft["penetration_count"], soft["penetration_max_um"] * 1e-3]]).astype(np.float32)

    def _observation(self, obs, soft):
        return np.concatenate([np.asarray(obs, np.float32), self.soft_vector(soft)]) if self.observe else obs

    # -- pictures and logs ---------------------------------------------------------------------------
    @property
    def render_mode(self):
        return "rgb_array"

    def render(self):
        """(height, width, 3) uint8 picture of the env's scene with the deformed skin (flat-shaded
        triangles added to the scene: the env's compiled model has no skin mesh)."""
        v = self._view
        if self._renderer is None:
            w, h = min(v["width"], self.model.vis.global_.offwidth), min(v["height"], self.model.vis.global_.offheight)
            try:  # room for the env's geoms and one triangle per skin face
                self._renderer = mujoco.Renderer(self.model, height=h, width=w,
                                                 max_geom=10_000 + len(self.hand.asset.skin_faces))
            except Exception as e:  # no OpenGL backend: one clear line
                raise ph.RenderUnavailable(f"no offscreen OpenGL for MuJoCo (set MUJOCO_GL=egl or osmesa): {e}") from e
        r = self._renderer
        if v["camera"] is not None:
            r.update_scene(self.data, camera=v["camera"])
        else:
            from physhand_mj.render import look_at_camera

            skin = self.hand.skin_vertices
            r.update_scene(self.data, camera=look_at_camera(0.5 * (skin.min(0) + skin.max(0)), v["distance"],
                                                            v["azimuth"], v["elevation"]))
        self.hand.draw(r.scene)
        return r.render()

    def write_log(self, path) -> Path:
        """The per-step log as CSV (one row per env step since the last reset)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        keys = list(dict.fromkeys(k for row in self.log for k in row))
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, keys)
            w.writeheader()
            w.writerows(self.log)
        return path

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()


def make(env_id: str, **kwargs) -> SoftSkin:
    """``SoftSkin(gymnasium.make(env_id), **kwargs)`` for a MyoSuite env id (registers MyoSuite's envs)."""
    import myosuite  # noqa: F401  (registers the envs)

    if env_id not in gymnasium.registry:
        hands = sorted(e for e in gymnasium.registry if e.startswith("myoHand"))
        raise ValueError(f"unknown env '{env_id}'; MyoSuite's hand envs: {hands}")
    return SoftSkin(gymnasium.make(env_id), **kwargs)
