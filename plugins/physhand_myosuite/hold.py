"""ObjHold held by the skin: the stored grasp (a fixed muscle action) and the holding measure.

    import physhand_myosuite as pm
    from physhand_myosuite import hold
    env = pm.make("myoHandObjHoldFixed-v0", two_way=True)
    row = hold.hold_still(env, hold.grasp_action(env), seconds=2.0)   # offsets, the skin's force, ...

The grasp (``objhold_grasp.json``, made by ``benchmarks/myosuite_hold.py --search``) is one action
vector of MyoSuite's normalised action space ([-1, 1] per muscle; MyoSuite maps it to the activation
1 / (1 + exp(-5 (a - 0.5)))), held constant from the reset: a policy reaches it by outputting it. It
was searched with MuJoCo alone, MyoHand's own contact capsules holding the object (they lie on the
skin's surface: median distance from the skin 0 mm, up to 3-6 mm outside it on the palm side);
:func:`skin_only` takes the object out of the capsules' collisions so that only the skin
(``two_way=True``) can hold it. Measured (docs/tasks.md): the grasp holds the object 2 s on the
capsules (one-way, 19 mm) and on the skin alone (two-way; it settles 37 mm from its start, then
2.3 mm over the last second, the skin's force = m g).
"""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np

GRASP_PATH = Path(__file__).with_name("objhold_grasp.json")
"""The stored ObjHold grasp: ``{"env", "action": {muscle: action}, "activation": {...}, "how": ...}``."""

LIFT = 0.010
"""m: :func:`hold_still` starts the object this much above where ObjHold's reset puts it. The reset
seats it on MyoHand's capsules, which leaves the skin's rest surface ~8 mm inside it (261 rest skin
vertices); the reset's one-way settle pushes the skin out of it, and the first two-way frame gives
that compression back as a kick (3.4 N sideways, 2.5 N up: the object thrown out of every grasp
tried). 10 mm up it drops onto the skin instead (first frame 1.4 N, about m g)."""

HAND_BIT, OBJECT_BIT = 1, 2  # MyoHand's geoms collide on bit 1; skin_only moves the object to bit 2


def load_grasp(path: Path | str = GRASP_PATH) -> dict:
    """The stored grasp record (see :data:`GRASP_PATH`)."""
    return json.loads(Path(path).read_text())


def grasp_action(env, grasp: dict | None = None) -> np.ndarray:
    """The grasp as an action of ``env`` (float32, its action space), looked up by muscle name."""
    grasp = load_grasp() if grasp is None else grasp
    m = env.unwrapped.model
    names = [m.actuator(i).name for i in range(m.nu)]
    missing = sorted(set(grasp["action"]) - set(names)) + sorted(set(names) - set(grasp["action"]))
    if missing:
        raise ValueError(f"the grasp's muscles do not match the env's actuators: {missing}")
    return np.array([grasp["action"][n] for n in names], np.float32)


def activation(action) -> np.ndarray:
    """MyoSuite's normalised action -> muscle activation (its ``sigmoid_muscle_activation``)."""
    return 1.0 / (1.0 + np.exp(-5.0 * (np.asarray(action, np.float64) - 0.5)))


def skin_only(model: mujoco.MjModel, body: str = "object") -> None:
    """Take ``body``'s geoms out of MyoHand's MuJoCo collisions (the capsules on bit 1), keeping its
    collisions with the other scene geoms (floor, table): the skin alone can then hold it. Edits the
    compiled model in place (before wrapping, so the wrapper's object list is the same)."""
    b = model.body(body).id
    hand_roots = {int(model.body_rootid[model.geom_bodyid[g]]) for g in range(model.ngeom)
                  if model.geom_bodyid[g] != b and int(model.body_rootid[model.geom_bodyid[g]]) != 0}
    for g in range(model.ngeom):
        if not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        if model.geom_bodyid[g] == b:
            model.geom_contype[g], model.geom_conaffinity[g] = OBJECT_BIT, OBJECT_BIT
        elif int(model.body_rootid[model.geom_bodyid[g]]) not in hand_roots:
            model.geom_contype[g] = model.geom_conaffinity[g] = HAND_BIT | OBJECT_BIT


def lift_object(env, lift: float = LIFT, body: str = "object") -> None:
    """Right after ``env.reset``: move the free ``body`` ``lift`` m up and settle the skin on the pose
    again (``SoftHand.reset``), so that it starts out of the skin's rest surface (see :data:`LIFT`)."""
    m, d = env.unwrapped.model, env.unwrapped.data
    j = m.body_jntadr[m.body(body).id]
    d.qpos[m.jnt_qposadr[j] + 2] += lift
    mujoco.mj_forward(m, d)
    env.hand.reset(env.settle_frames)


def capsule_force(model: mujoco.MjModel, data: mujoco.MjData, body: int) -> np.ndarray:
    """Total force (3,) N, world frame, that MuJoCo's contacts of other bodies put on ``body`` now
    (the hand's capsules, the floor): the part of the hold that is not the skin's."""
    f = np.zeros(3)
    c6 = np.zeros(6)
    for i in range(data.ncon):
        c = data.contact[i]
        b1, b2 = model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]
        if body not in (b1, b2) or b1 == b2:
            continue
        mujoco.mj_contactForce(model, data, i, c6)
        fw = c.frame.reshape(3, 3).T @ c6[:3]  # contact frame -> world: the force on geom2's body
        f += fw if b2 == body else -fw
    return f


def hold_still(env, action, seconds: float = 2.0, body: str = "object", average_s: float = 0.5,
               lift: float = LIFT) -> dict:
    """Reset ``env`` (a :class:`~physhand_myosuite.SoftSkin`), lift the object ``lift`` m (:data:`LIFT`)
    and settle the skin again, hold ``action`` for ``seconds`` s and measure: ``worst_mm`` / ``end_mm`` (the body's largest / final offset from its place at the
    reset), ``hold_mm`` (its largest offset from where it was after the first second: the drift
    once the hand has closed); over the last ``average_s`` s (the last soft frame of each env step):
    ``force_n`` / ``friction_n`` (3,) the mean force the skin applied to it and its friction part
    (two-way only, else zeros), ``points`` (mean skin vertices in contact with it), ``capsule_n`` (3,)
    the mean force of MuJoCo's contacts (capsules, floor); ``weight_n`` (m g), at the end both
    penetration measures (``skin_in`` count, max um; ``obj_in`` count, max um) and MyoSuite's
    ``solved`` / goal distance."""
    m, d = env.unwrapped.model, env.unwrapped.data
    b = m.body(body).id
    env.reset(seed=0)
    if lift:
        lift_object(env, lift, body)
    p0 = d.xpos[b].copy()
    steps = int(round(seconds / env.dt))
    avg = max(1, int(round(average_s / env.dt)))
    mid = None
    worst = hold = 0.0
    force, friction, caps, points = [], [], [], []
    info = {}
    for k in range(steps):
        _, _, _, _, info = env.step(action)
        p = d.xpos[b]
        worst = max(worst, float(np.linalg.norm(p - p0)))
        if k + 1 == steps // 2:
            mid = p.copy()
        if mid is not None:
            hold = max(hold, float(np.linalg.norm(p - mid)))
        if k >= steps - avg:
            o = info["physhand"]["objects"].get(body, {})
            a = o.get("applied", {})
            force.append(a.get("force", np.zeros(3)))
            friction.append(a.get("friction", np.zeros(3)))
            points.append(o.get("vertices", 0))
            caps.append(capsule_force(m, d, b))
    mt = env.hand.metrics()
    rwd = env.unwrapped.get_reward_dict(env.unwrapped.get_obs_dict(env.unwrapped._accessor)) \
        if hasattr(env.unwrapped, "get_reward_dict") else {}
    return dict(worst_mm=worst * 1e3, end_mm=float(np.linalg.norm(d.xpos[b] - p0)) * 1e3, hold_mm=hold * 1e3,
                force_n=np.mean(force, 0), friction_n=np.mean(friction, 0), points=float(np.mean(points)),
                capsule_n=np.mean(caps, 0), weight_n=float(m.body_subtreemass[b] * -m.opt.gravity[2]),
                skin_in=(int(mt["penetration_count"]), float(mt["penetration_max_um"])),
                obj_in=(int(mt["object_in_skin_count"]), float(mt["object_in_skin_max_um"])),
                solved=bool(rwd.get("solved", False)), goal_mm=-float(rwd.get("goal_dist", np.nan)) * 1e3,
                finite=bool(info.get("physhand", {}).get("finite", True)))
