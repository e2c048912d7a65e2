"""hand_hold: the soft hand holds one of the paper's HOI objects against gravity.

The object (apple, bowl, box, glass1, glass2, phone, toothpaste) and the grasp keyframe come from
``mjcf/scenes/hoi_<object>.xml``; here the object is free (a free joint, dynamic in MuJoCo) and
collides with the hand's capsule proxies, which push it; the soft skin deforms against it (SoftHand).
An episode starts in the grasp keyframe (ctrl = its pose) with the object moved by up to
``object_jitter`` (m) per axis, drawn from the task's RNG.

Gravity: ``gravity="palm"`` (default) points it into the palm (-y: the palm faces +y), so the
fingers cradle the object and must keep it from rolling off; ``gravity="down"`` keeps the HOI
scenes' -z, along the palm, where the grasp must hold by friction alone. A floor perpendicular to
gravity 20 cm from the palm catches a dropped object.

Holding by the skin (``Config(two_way=True)``, docs/coupling.md; the default with ``gravity="down"``
and no ``config``: along the palm one-way coupling holds none of the seven from their HOI keyframes
and two from the holding grasps, two-way six): the HOI keyframes start with the
skin 2.5-3.8 mm into the object, which the skin, now pushing, would throw out of an unbalanced grasp.
So with two-way coupling the reset by default (1) starts from the object's holding grasp where it
has one (``grasp="hold"``: glass1, glass2, the phone, the toothpaste, whose HOI keyframes touch the
object on the palm's side only; a second keyframe ``hold`` from ``hand_hold_grasps.json``, made by
``benchmarks/hold_grasps.py``: the object on the palm, the hand closed round it, the thumb opposing),
else from the HOI keyframe with the position targets at ``squeeze`` (1.2) x its joint angles, so the
actuators press the fingers onto the object, and (2) runs ``float_frames`` (60: 0.3 s) with gravity
off, in which the object settles where the skin's and the proxies' pushes balance; the episode (and
its start position) begins there. One-way coupling keeps the HOI keyframe as it was (squeeze 1, no
float); every option can be set either way. ``object_proxies=False`` takes the object out of the
proxies' MuJoCo collisions (the skin alone holds it).

Domain randomisation (per episode, from the task's RNG after the start offset's draw; None, the
default: the model's values, nothing drawn): ``mass_range=(lo, hi)`` kg draws the object's mass
uniformly (its principal moments of inertia scale with it from the model's, and so do the fields
MuJoCo derives from the mass: :class:`MassFields`, the model compiled with that mass), then
``friction_range=(lo, hi)`` its geoms' sliding friction coefficient. MuJoCo's rule (the larger of
two geoms' coefficients) applies to every contact, the skin's included: against the hand's
coefficient 1 (skin and proxies) only draws above 1 change a grasp (the floor's is 1 too).

Reward (in [0, 1]): ``hold * (0.5 + 0.5 * firm) * no_penetration`` with ``hold`` = 1 while the
object is within 1 cm of its start (Gaussian tail to 0.1 at 6 cm), ``firm`` = 1 from
``min_force`` N of soft-contact normal force on the object (linear below), ``no_penetration`` = 1
while the skin's deepest penetrating sample is < 0.05 mm (0.1 at 1.05 mm).
"""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
from dm_control.mujoco import wrapper
from dm_control.utils import containers, rewards

from physhand_dmc.physics import SoftPhysics
from physhand_dmc.batch_physics import BatchPhysics
from physhand_dmc.task import SoftTask, batch_config, check_nonneg, check_positive, make_environment, solver_config
from physhand_dmc.batch_task import BatchTask
from physhand_mj import Config
from physhand_mj.hand_mjcf import SCENES_DIR

XML = Path(__file__).with_suffix(".xml")
# Holding grasps (a second keyframe "hold") for the objects whose HOI keyframe the skin cannot hold
# against gravity along the palm: hand qpos, ctrl targets and the object's pose (benchmarks/hold_grasps.py).
HOLD_GRASPS = json.loads(Path(__file__).with_name("hand_hold_grasps.json").read_text())
GRASPS = ("hoi", "hold")
OBJECTS = ("apple", "bowl", "box", "glass1", "glass2", "phone", "toothpaste")
# Object masses (kg): light household objects (an empty glass, a small apple, ...).
MASS = dict(apple=0.12, bowl=0.15, box=0.10, glass1=0.15, glass2=0.15, phone=0.15, toothpaste=0.10)
GRAVITY = {"palm": (0.0, -9.81, 0.0), "down": (0.0, 0.0, -9.81)}
_DEFAULT_TIME_LIMIT = 2.0  # s
_CONTROL_TIMESTEP = 0.01  # s: two MuJoCo steps (and two soft-hand frames) per env step
# Config(two_way=True)'s reset: targets 1.2 x the keyframe's angles, 0.3 s settling with gravity off
SQUEEZE, FLOAT_FRAMES = 1.2, 60
_MU_UNIT = "(sliding friction coefficient, no unit)"

SUITE = containers.TaggedTasks()


def build_model(obj: str, gravity: str = "palm", grasp: str = "hoi") -> mujoco.MjModel:
    """The domain XML with ``obj`` (free, colliding with the hand's proxies) and its grasp keyframe
    ``grasp`` (the HOI scene's); ``grasp="hold"`` adds the holding grasp as a second keyframe ``hold``."""
    if obj not in OBJECTS:
        raise ValueError(f"unknown object {obj!r}; choose one of {list(OBJECTS)}")
    if gravity not in GRAVITY:
        raise ValueError(f"gravity must be one of {list(GRAVITY)}, got {gravity!r}")
    scene = SCENES_DIR / f"hoi_{obj}.xml"
    hoi = mujoco.MjSpec.from_file(str(scene))
    spec = mujoco.MjSpec.from_file(str(XML))
    spec.option.gravity = GRAVITY[gravity]
    src = hoi.body(obj)
    body = spec.worldbody.add_body(name=obj, pos=list(src.pos), quat=list(src.quat))
    body.add_freejoint(name=f"{obj}_free")
    for g in src.geoms:
        geom = body.add_geom(name=g.name, type=g.type, size=list(g.size), pos=list(g.pos), quat=list(g.quat),
                             rgba=list(g.rgba), contype=1, conaffinity=1, condim=4, friction=[1.0, 0.01, 0.001],
                             mass=MASS[obj] / len(src.geoms))
        if g.type == mujoco.mjtGeom.mjGEOM_MESH:
            mesh = hoi.mesh(g.meshname)
            spec.add_mesh(name=mesh.name, file=str((scene.parent / mesh.file).resolve()),
                          inertia=mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL)
            geom.meshname = mesh.name
    down = np.asarray(GRAVITY[gravity]) / 9.81
    floor_pos = np.asarray(src.pos) + 0.2 * down
    floor_quat = [0.7071068, -0.7071068, 0, 0] if gravity == "palm" else [1, 0, 0, 0]  # normal against gravity
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.5, 0.5, 0.01],
                            pos=floor_pos.tolist(), quat=floor_quat, rgba=[0.55, 0.58, 0.62, 1])
    key = hoi.key("grasp")
    nq_hand = len(key.qpos)
    spec.add_key(name="grasp", qpos=list(key.qpos)[:nq_hand] + list(src.pos) + list(src.quat),
                 ctrl=list(key.ctrl), mpos=list(key.mpos), mquat=list(key.mquat))
    if grasp not in GRASPS:
        raise ValueError(f"grasp must be one of {list(GRASPS)}, got {grasp!r}")
    if grasp == "hold":
        if obj not in HOLD_GRASPS:
            raise ValueError(f"no holding grasp for {obj!r} (have {sorted(HOLD_GRASPS)}); use grasp='hoi'")
        h = HOLD_GRASPS[obj]
        spec.add_key(name="hold", qpos=h["qpos"] + h["pos"] + h["quat"], ctrl=h["ctrl"], mpos=list(key.mpos),
                     mquat=list(key.mquat))
    return spec.compile()


def without_proxies(model: mujoco.MjModel, obj: str) -> None:
    """Take ``obj``'s geoms out of the hand's proxies' collisions (their bit 1), keeping the floor's."""
    body = model.body(obj).id
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == body:
            model.geom_contype[g], model.geom_conaffinity[g] = 2, 2
        elif model.geom(g).name == "floor":
            model.geom_contype[g], model.geom_conaffinity[g] = 3, 3


def hold_still(obj: str, seconds: float = 2.0, **task_kwargs):
    """An episode of ``hand_hold`` with ``obj`` (``random=0``, ``gravity="down"`` unless given in
    ``task_kwargs``) that holds the reset's ctrl for ``seconds`` s: (the object's largest offset from
    its start, m; the environment at the episode's end). The holding measure of docs/dm_control.md."""
    from physhand_dmc import suite

    kw = dict(random=0, gravity="down", time_limit=seconds)
    kw.update(task_kwargs)
    env = suite.load("hand_hold", obj, task_kwargs=kw)
    ts = env.reset()
    act = env.task.normalise_ctrl(env.physics, env.physics.data.ctrl.copy())
    worst = 0.0
    while not ts.last():
        ts = env.step(act)
        worst = max(worst, float(np.linalg.norm(ts.observation["object_offset"])))
    return worst, env


def make_physics(obj: str, gravity: str, config, object_proxies: bool = True, grasp: str = "hoi") -> SoftPhysics:
    model = build_model(obj, gravity, grasp)
    if not object_proxies:
        without_proxies(model, obj)
    physics = SoftPhysics.from_model(wrapper.MjModel(model))
    physics.reset(0)
    physics.make_soft(solver_config(config, float(model.opt.timestep)), object_bodies=[obj])
    return physics


class MassFields:
    """The model's fields that follow the free object's mass, kept at the model's values to scale
    from (never compounding episode to episode): its mass, its principal moments (x m / m0), the
    subtree masses (its own, the world's: + m - m0; MuJoCo's centre-of-mass frames read them) and its
    body's and dofs' inverse weights (x m0 / m) and its dofs' diagonal inertias ``dof_M0`` (x m / m0;
    both set the constraints' softness), as the compiler computes them for a body alone in its
    kinematic tree: the model compiled with that mass (the trajectory alike to the digit, MuJoCo C;
    only the solver statistic ``stat.meaninertia`` and the cameras' ``poscom0`` keep the model's).
    MuJoCo Warp has no ``dof_M0`` (BatchHold batches the others)."""

    FIELDS = ("body_mass", "body_inertia", "body_subtreemass", "body_invweight0", "dof_invweight0", "dof_M0")

    def __init__(self, model, body: int, dof: int):
        if model.body_parentid[body] != 0 or np.any(np.asarray(model.body_parentid[1:]) == body):
            raise ValueError("mass_range: the object must be a child of the world without bodies of its own")
        self.body, self.dofs = int(body), np.arange(dof, dof + 6)
        self.mass0, self.inertia0 = float(model.body_mass[body]), np.array(model.body_inertia[body], float)
        self.world0 = float(model.body_subtreemass[0])
        self.iw0, self.dof_iw0 = np.array(model.body_invweight0[body], float), np.array(model.dof_invweight0[self.dofs])
        self.dof_m0 = np.array(model.dof_M0[self.dofs], float)

    def values(self, mass: float) -> dict:
        """name -> (indices, values) of the fields with the object's mass ``mass`` kg."""
        s = mass / self.mass0
        b = self.body
        return dict(body_mass=(b, mass), body_inertia=(b, self.inertia0 * s),
                    body_subtreemass=([b, 0], [mass, self.world0 + mass - self.mass0]),
                    body_invweight0=(b, self.iw0 / s), dof_invweight0=(self.dofs, self.dof_iw0 / s),
                    dof_M0=(self.dofs, self.dof_m0 * s))


def check_range(name: str, value, unit: str):
    """None, or ``value`` as a (lo, hi) pair of floats with 0 < lo <= hi, both finite."""
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be None or (lo, hi) in {unit}, got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"{name} must be None or (lo, hi) {unit} with 0 < lo <= hi, both finite, got {value!r}")
    return lo, hi


class Hold(SoftTask):
    """Keep the object in the hand, in firm soft contact, without penetration."""

    def __init__(self, obj: str, random=None, settle_frames: int = 20, object_jitter: float = 0.002,
                 min_force: float = 1.0, squeeze: float = 1.0, float_frames: int = 0, grasp: str = "hoi",
                 mass_range=None, friction_range=None):
        super().__init__(random=random, settle_frames=settle_frames)
        self.obj = obj
        if grasp not in GRASPS:
            raise ValueError(f"grasp must be one of {list(GRASPS)}, got {grasp!r}")
        self.grasp = grasp
        self.squeeze = check_positive("squeeze", squeeze, "x the keyframe's joint angles")
        if not (isinstance(float_frames, (int, np.integer)) and float_frames >= 0):
            raise ValueError(f"float_frames must be an integer >= 0 (MuJoCo steps), got {float_frames!r}")
        self.float_frames = int(float_frames)
        self.object_jitter = check_nonneg("object_jitter", object_jitter, "m")
        self.min_force = check_positive("min_force", min_force, "N")
        self.mass_range = check_range("mass_range", mass_range, "kg")
        self.friction_range = check_range("friction_range", friction_range, _MU_UNIT)
        self._start = np.zeros(3)

    def bind(self, physics):
        m = physics.model
        j = int(m.body_jntadr[m.name2id(self.obj, "body")])
        self._qadr, self._vadr = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        self._hand_q = np.arange(self._qadr)  # the hand's hinge joints precede the object's free joint
        b = self._body = int(m.name2id(self.obj, "body"))
        self._geoms = np.flatnonzero(m.geom_bodyid == b)
        self._mass = MassFields(m, b, self._vadr) if self.mass_range is not None else None

    def randomise(self, physics):
        """This episode's object mass and friction into the model (see the module docstring)."""
        m = physics.model
        if self.mass_range is not None:
            for name, (idx, value) in self._mass.values(self.random.uniform(*self.mass_range)).items():
                getattr(m, name)[idx] = value
        if self.friction_range is not None:
            m.geom_friction[self._geoms, 0] = self.random.uniform(*self.friction_range)
            physics.soft.refresh_friction()  # (SoftHand reads the coefficients once otherwise)

    def initialize_episode(self, physics):
        m, d = physics.model, physics.data
        self._bind_once(physics)
        mujoco.mj_resetDataKeyframe(m.ptr, d.ptr, 0 if self.grasp == "hoi" else m.name2id("hold", "key"))
        if self.squeeze != 1.0:  # the fingers pressed onto the object: targets past the keyframe's pose
            d.ctrl[:] = np.clip(d.ctrl * self.squeeze, m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
        d.qpos[self._qadr: self._qadr + 3] += self.random.uniform(-self.object_jitter, self.object_jitter, 3)
        self.randomise(physics)
        self.finish_reset(physics)
        if self.float_frames:  # gravity off while the object settles into the grasp
            g = m.opt.gravity.copy()
            m.opt.gravity[:] = 0.0
            try:
                physics.step(self.float_frames)
            finally:
                m.opt.gravity[:] = g
            d.time = 0.0
        self._start = d.qpos[self._qadr: self._qadr + 3].copy()
        super().initialize_episode(physics)

    def _task_observations(self, physics, obs):
        d = physics.data
        obs["joint_pos"] = d.qpos[self._hand_q].copy()
        obs["joint_vel"] = d.qvel[self._hand_q].copy()
        self.free_object_observations(physics, obs)

    def get_reward(self, physics):
        d = physics.data
        offset = float(np.linalg.norm(d.qpos[self._qadr: self._qadr + 3] - self._start))
        force = float(physics.soft.sensor.obj_host[0, 1])
        depth = float(physics.soft._last.get("penetration_max_um", 0.0)) * 1e-3
        return float(hold_reward(offset, force, depth, self.min_force))


def hold_reward(offset, force, depth_mm, min_force: float):
    """``hold * (0.5 + 0.5 * firm) * no_penetration`` (the module docstring) of the object's offsets
    from its start (m), soft-contact forces (N) and deepest penetrations (mm): scalars or (W,) arrays
    alike (the single task and the batched one share it)."""
    hold = rewards.tolerance(np.asarray(offset, float), bounds=(0.0, 0.01), margin=0.05)
    firm = rewards.tolerance(np.asarray(force, float), bounds=(min_force, np.inf), margin=min_force, sigmoid="linear",
                             value_at_margin=0.0)
    return hold * (0.5 + 0.5 * firm) * rewards.tolerance(np.asarray(depth_mm, float), bounds=(0.0, 0.05), margin=1.0)


class BatchHold(BatchTask):
    """:class:`Hold` on W worlds (physhand_dmc.vector): the same episodes, observations and reward."""

    def __init__(self, physics, obj: str, settle_frames: int = 20, object_jitter: float = 0.002, min_force: float = 1.0,
                 squeeze: float = 1.0, float_frames: int = 0, grasp: str = "hoi", mass_range=None, friction_range=None):
        super().__init__(physics, settle_frames)
        probe = Hold(obj, settle_frames=settle_frames, object_jitter=object_jitter, min_force=min_force, squeeze=squeeze,
                     float_frames=float_frames, grasp=grasp, mass_range=mass_range,
                     friction_range=friction_range)  # (the options' checks)
        self.obj, self.grasp, self.squeeze = obj, grasp, probe.squeeze
        self.float_frames, self.object_jitter, self.min_force = probe.float_frames, probe.object_jitter, probe.min_force
        self.mass_range, self.friction_range = probe.mass_range, probe.friction_range
        m = physics.model
        b = self._body = m.body(obj).id
        self._geoms = np.flatnonzero(m.geom_bodyid == b)
        j = int(m.body_jntadr[b])
        self._qadr, self._vadr = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        self._mass = MassFields(m, b, self._vadr) if self.mass_range is not None else None
        # per-world fields allocated now, before the first step captures MuJoCo Warp's step (CUDA graph)
        self._mass_fields = [name for name in MassFields.FIELDS if hasattr(physics.m, name)]
        if self.mass_range is not None:
            physics.batch_model_fields(*self._mass_fields)
        if self.friction_range is not None:
            physics.batch_model_fields("geom_friction")
        self._key = 0 if grasp == "hoi" else m.key("hold").id
        self._start = np.zeros((physics.worlds, 3))

    def initialize_episodes(self, mask):
        p, m = self.physics, self.physics.model
        p.reset_keyframe(self._key, mask)
        if self.squeeze != 1.0:
            ctrl = p.host("ctrl")
            lo, hi = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
            ctrl[mask] = np.clip(np.asarray(m.key(self._key).ctrl) * self.squeeze, lo, hi)
            p.set_ctrl(ctrl)
        qpos = p.host("qpos")
        a = self._qadr
        mass, friction = np.zeros(p.worlds), np.zeros(p.worlds)
        for w in np.flatnonzero(mask):  # (each world's own RNG, drawn as the single task draws)
            qpos[w, a: a + 3] += self.random[w].uniform(-self.object_jitter, self.object_jitter, 3)
            if self.mass_range is not None:
                mass[w] = self.random[w].uniform(*self.mass_range)
            if self.friction_range is not None:
                friction[w] = self.random[w].uniform(*self.friction_range)
        p.set_host("qpos", qpos)
        if self.mass_range is not None:  # (Hold.randomise, per world: the masked worlds' values only)
            fields = {name: p.model_field(name) for name in self._mass_fields}
            for w in np.flatnonzero(mask):
                for name, (idx, value) in self._mass.values(mass[w]).items():
                    if name in fields:
                        fields[name][w, idx] = value
            for name, value in fields.items():
                p.set_model_field(name, value, mask)
        if self.friction_range is not None:
            gf = p.model_field("geom_friction")
            gf[:, self._geoms, 0] = friction[:, None]
            p.set_model_field("geom_friction", gf, mask)
        p.restart_soft(self.settle_frames)
        if self.float_frames:  # gravity off while the object settles into the grasp
            g = p.m.opt.gravity.numpy().copy()
            p.m.opt.gravity.assign(np.zeros_like(g))
            try:
                p.step(self.float_frames)
            finally:
                p.m.opt.gravity.assign(g)
            time = p.host("time")
            time[mask] = 0.0
            p.set_host("time", time)
        self._start[mask] = p.host("qpos")[mask, a: a + 3]

    def task_observations(self, obs):
        p, a, v = self.physics, self._qadr, self._vadr
        qpos, qvel = p.host("qpos"), p.host("qvel")
        obs["joint_pos"] = qpos[:, :a]
        obs["joint_vel"] = qvel[:, :a]
        obs["object_offset"] = qpos[:, a: a + 3] - self._start
        obs["object_quat"] = qpos[:, a + 3: a + 7]
        obs["object_vel"] = qvel[:, v: v + 6]

    def rewards(self):
        p = self.physics
        p.sync()  # (the sensor's pinned host rows: their copies complete)
        offset = np.linalg.norm(p.host("qpos")[:, self._qadr: self._qadr + 3] - self._start, axis=1)
        force = p.sensor.obj_host.reshape(p.worlds, -1, 3)[:, 0, 1].astype(float)
        return hold_reward(offset, force, self.depth_mm(), self.min_force)


def _options(obj: str, gravity: str, config, grasp, squeeze, float_frames):
    """The task's resolved (config, grasp, squeeze, float_frames): two-way by default along the palm,
    the holding grasp, squeeze and float with two-way (the module docstring)."""
    if config is None and gravity == "down":  # along the palm one-way holds nothing: the skin holds
        config = Config(two_way=True)
    two_way = bool(getattr(config, "two_way", False))
    if grasp is None:  # two-way: the holding grasp where the object has one
        grasp = "hold" if two_way and obj in HOLD_GRASPS else "hoi"
    squeeze = (SQUEEZE if two_way and grasp == "hoi" else 1.0) if squeeze is None else squeeze
    float_frames = (FLOAT_FRAMES if two_way else 0) if float_frames is None else float_frames
    return config, grasp, squeeze, float_frames


def _task(obj: str):
    def task(time_limit=_DEFAULT_TIME_LIMIT, random=None, environment_kwargs=None, *, settle_frames=20,
             object_jitter=0.002, min_force=1.0, gravity="palm", config=None, control_timestep=_CONTROL_TIMESTEP,
             squeeze=None, float_frames=None, object_proxies=True, grasp=None, mass_range=None, friction_range=None):
        check_positive("time_limit", time_limit, "s"), check_positive("control_timestep", control_timestep, "s")
        check_range("mass_range", mass_range, "kg"), check_range("friction_range", friction_range, _MU_UNIT)
        config, grasp, squeeze, float_frames = _options(obj, gravity, config, grasp, squeeze, float_frames)
        t = Hold(obj, random=random, settle_frames=settle_frames, object_jitter=object_jitter, min_force=min_force,
                 squeeze=squeeze, float_frames=float_frames, grasp=grasp, mass_range=mass_range,
                 friction_range=friction_range)
        physics = make_physics(obj, gravity, config, object_proxies, grasp)
        return make_environment(physics, t, time_limit, control_timestep, environment_kwargs)

    task.__name__ = task.__qualname__ = obj
    task.__doc__ = f"Hold the {obj} (mjcf/scenes/hoi_{obj}.xml, free) against gravity."
    return task


for _obj in OBJECTS:
    globals()[_obj] = SUITE.add("benchmarking", "hoi")(_task(_obj))


def batch_task(task, num_envs, device=None, *, time_limit=_DEFAULT_TIME_LIMIT, settle_frames=20, object_jitter=0.002,
               min_force=1.0, gravity="palm", config=None, control_timestep=_CONTROL_TIMESTEP, squeeze=None,
               float_frames=None, object_proxies=True, grasp=None, mass_range=None, friction_range=None):
    """The batched task ``task`` (an object; physhand_dmc.vector.load_batch): (BatchHold, time_limit,
    control_timestep), options as the single task's."""
    check_positive("time_limit", time_limit, "s"), check_positive("control_timestep", control_timestep, "s")
    check_range("mass_range", mass_range, "kg"), check_range("friction_range", friction_range, _MU_UNIT)
    config, grasp, squeeze, float_frames = _options(task, gravity, config, grasp, squeeze, float_frames)
    model = build_model(task, gravity, grasp)
    if not object_proxies:
        without_proxies(model, task)
    cfg = batch_config(config, float(model.opt.timestep), device)
    physics = BatchPhysics(model, num_envs, cfg, object_bodies=[task])
    t = BatchHold(physics, task, settle_frames, object_jitter, min_force, squeeze, float_frames, grasp, mass_range,
                  friction_range)
    return t, time_limit, control_timestep
