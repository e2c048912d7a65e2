"""Holding grasps for hand_hold (``plugins/physhand_dmc/suite/hand_hold_grasps.json``): how they are made.

The HOI keyframes of glass1, glass2, the phone, the toothpaste and the bowl touch the object on the
palm's side only (the open thumb lies between the palm and the object, so the generator stopped the
object 50-90 mm over the palm and the fingers reach it with their tips), so nothing holds it against
gravity along the palm. This search makes a second grasp per object, as a policy could (a monotone
closing of the position targets), with MuJoCo and the soft hand (two-way coupling, gravity off):

A. kinematic, on the bones' capsule proxies: the fingers open (flexions 0); the thumb, on a 7^4 grid
   of its four joints, as far from the object as it goes (then nearest the HOI keyframe's); the object
   moved along the palm normal from its HOI place to the lowest place where every proxy but the
   thumb's keeps 1 mm (the skin ~1.5 mm into it: the proxies lie 2.5 mm inside the rest skin);
B. the soft hand, the object held in place: every finger's three flexion targets close together (at
   1.3 x the ``power`` keyframe's angle over 90 frames); a joint stops, its target set to where the
   joint is, once its own link's skin pushes the object with 0.1 N, its proxy comes within 1 mm, a
   link beyond it is 1 mm into the object, or it reaches 1.3 x the power angle (GraspIt's autograsp
   rule); then every finger flexion target ``margin`` (rad) past where the joint stopped;
C. the thumb: a 9^4 grid of its joints, kept where its distal proxy is 1-3 mm into the object, picks
   the pose whose contact's outward normal lies most along the fingers' net push on the object across
   gravity (so it opposes the fingers), less 0.05 x its joint change; its targets ramp there (60
   frames) until its distal skin pushes with ``thumb_force`` N or its proxy is within 1 mm; then
   ``margin`` past where it stopped, away from the start;
D. the grasp (hand qpos, targets, object pose) is saved; the check releases the object 0.3 s without
   gravity, then 2 s with it, and reports the largest offset.

Run: ``python benchmarks/hold_grasps.py glass1 --margin 0.05 --thumb-force 1.0 [--write]`` (CPU,
~1 min an object). ``--write`` stores the grasp in the JSON file, which hand_hold reads.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import mujoco
import numpy as np

import physhand_mj as ph
from physhand_dmc.suite import hand_hold
from physhand_dmc.task import solver_config
from physhand_mj.hand_mjcf import scene_path

FJ = {k: [f"mcp{k}_flexion_r", f"pm{k}_flexion_r", f"md{k}_flexion_r"] for k in (2, 3, 4, 5)}
TJ = ["cmc_flexion_r", "cmc_abduction_r", "mp_flexion_r", "ip_flexion_r"]
THUMB = ("firstmc_r", "proximal_thumb_r", "distal_thumb_r")
CLEAR = 1.0e-3  # m: proxies' clearance (skin ~1.5 mm in)


def search(obj: str, margin: float, thumb_force: float, verbose: bool = True) -> dict:
    say = print if verbose else (lambda *a, **k: None)
    m = hand_hold.build_model(obj, "down")
    d = mujoco.MjData(m)
    power = mujoco.MjModel.from_xml_path(str(scene_path("hand_only"))).key("power").qpos.copy()
    mujoco.mj_resetDataKeyframe(m, d, 0)
    key = d.qpos.copy()
    ob = m.body(obj).id
    jo = m.body_jntadr[ob]
    qa, va = int(m.jnt_qposadr[jo]), int(m.jnt_dofadr[jo])
    nh = qa
    jadr = {m.joint(i).name: int(m.jnt_qposadr[i]) for i in range(m.njnt)}
    jid = {m.joint(i).name: i for i in range(m.njnt)}
    ogeoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == ob]
    prox = [g for g in range(m.ngeom) if m.geom_group[g] == 3 and m.geom_bodyid[g] != ob]
    ft = np.zeros(6)
    dk = mujoco.MjData(m)
    dk.mocap_pos[:], dk.mocap_quat[:] = d.mocap_pos, d.mocap_quat  # the hand's mount, as in the keyframe

    def mind(qh, opos, geoms=prox):
        dk.qpos[:] = key
        dk.qpos[:nh] = qh
        dk.qpos[qa:qa + 3] = opos
        mujoco.mj_kinematics(m, dk)
        return min(mujoco.mj_geomDistance(m, dk, g, o, 0.05, ft) for g in geoms for o in ogeoms)

    def thumb_grid(q, n):
        """(thumb joint values, hand qpos ``q`` with them) over an n^4 grid of the thumb's joint ranges."""
        for q4 in itertools.product(*[np.linspace(*m.jnt_range[jid[j]], n) for j in TJ]):
            qh = q.copy()
            for j, v in zip(TJ, q4):
                qh[jadr[j]] = v
            yield q4, qh

    # A: fingers open, the object onto the palm (thumb left out), the thumb out of its way
    q_open = key[:nh].copy()
    for js in FJ.values():
        for j in js:
            q_open[jadr[j]] = 0.0
    p_key = key[qa:qa + 3].copy()
    nothumb = [g for g in prox if m.body(m.geom_bodyid[g]).name not in THUMB]
    thumbg = [g for g in prox if m.body(m.geom_bodyid[g]).name in THUMB]
    lo, hi = -0.08, 0.0
    for _ in range(16):
        t = 0.5 * (lo + hi)
        lo, hi = (lo, t) if mind(q_open, p_key + [0, t, 0], nothumb) >= CLEAR else (t, hi)
    dy = hi
    thumb_key = np.array([key[jadr[j]] for j in TJ])
    best = None
    for q4, qh in thumb_grid(q_open, 7):
        s = (-min(round(mind(qh, p_key + [0, dy, 0], thumbg), 3), 0.004), float(np.abs(np.array(q4) - thumb_key).sum()))
        if best is None or s < best[0]:
            best = (s, qh)
    qh0 = best[1]
    p_obj = p_key + [0, dy, 0]
    say(f"A: the object {-dy * 1e3:.1f} mm toward the palm; thumb {np.round([qh0[jadr[j]] for j in TJ], 3)}, "
        f"{-best[0][0] * 1e3:.1f} mm clear", flush=True)

    # B: the soft hand, the object held; the fingers close until each link touches, then the margin
    g0 = m.opt.gravity.copy()
    m.opt.gravity[:] = 0
    d.qpos[:nh] = qh0
    d.qpos[qa:qa + 3] = p_obj
    d.qvel[:] = 0
    aj = np.array([m.jnt_qposadr[m.actuator_trnid[a, 0]] for a in range(m.nu)])
    act = {j: int(np.flatnonzero(aj == jadr[j])[0]) for j in jadr if jadr[j] in aj}
    lo_c, hi_c = m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1]
    ctrl = d.qpos[aj].copy()
    d.ctrl[:] = ctrl
    q_obj = d.qpos[qa:qa + 7].copy()
    mujoco.mj_forward(m, d)
    hand = ph.SoftHand(m, d, solver_config(ph.Config(two_way=True), float(m.opt.timestep)), object_bodies=[obj])
    hand.solver.warn_feature_slack = False
    names = list(hand.asset.body_names)
    skin_body = hand.solver.model.skin_body.numpy()[:hand.asset.n_skin]

    def bone_force():
        """Each bone's skin's normal force on the object (N), as SoftHand.contacts() estimates it."""
        c, n = hand.solver.contact, hand.asset.n_skin
        h, s = hand.config.substep_dt, hand.config.substeps
        push, vobj = c.push.numpy()[:n].astype(float), c.vertex_obj.numpy()[:n]
        f = hand.asset.mass[:n] * push / (h * h * s) * ((vobj == 0) & (push > 0))
        return np.bincount(np.maximum(skin_body, 0), weights=f, minlength=len(names))

    def frame(hold=True):
        mujoco.mj_step(m, d)
        hand.step()
        if hold:
            d.qpos[qa:qa + 7] = q_obj
            d.qvel[va:va + 6] = 0

    for _ in range(20):
        frame()
    chain = {k: [names.index(b) for b in (f"{k}proxph_r", f"midph{k}_r", f"distph{k}_r")] for k in FJ}
    bone_geoms = {b: [g for g in prox if m.geom_bodyid[g] == m.body(names[b]).id] for b in range(len(names))}

    def clear(bs):
        return min([mujoco.mj_geomDistance(m, d, g, o, 0.05, ft) for b in bs for g in bone_geoms[b] for o in ogeoms] + [1.0])

    moving = {k: [True, True, True] for k in FJ}
    for f in range(160):
        bf = bone_force()
        for k in FJ:
            for s in range(3):
                j = FJ[k][s]
                i = act[j]
                if (bf[chain[k][s]] >= 0.1 or clear([chain[k][s]]) <= CLEAR or (s < 2 and clear(chain[k][s + 1:]) <= -0.001)
                        or ctrl[i] >= min(hi_c[i], 1.3 * power[jadr[j]])):
                    if moving[k][s]:
                        ctrl[i] = d.qpos[jadr[j]]  # the servo lags its target: stop where the joint is
                    moving[k][s] = False
                if moving[k][s]:
                    ctrl[i] = min(ctrl[i] + 1.3 * power[jadr[j]] / 90, hi_c[i])
        d.ctrl[:] = ctrl
        frame()
        if not any(any(v) for v in moving.values()):
            break
    for js in FJ.values():
        for j in js:
            ctrl[act[j]] = min(d.qpos[jadr[j]] + margin, hi_c[act[j]])
    for _ in range(20):
        d.ctrl[:] = ctrl
        frame()
    bf = bone_force()
    c = hand.contacts()["objects"][obj]
    say(f"B: fingers closed in {f + 1} frames, + {margin} rad: skin forces {[round(float(bf[chain[k]].sum()), 2) for k in FJ]} N, "
        f"net {np.round(c['force'], 2)} N", flush=True)

    # C: the thumb opposite the fingers' net push across gravity (-z)
    push = np.asarray(c["force"]).copy()
    push[2] = 0.0
    fhat = push / max(np.linalg.norm(push), 1e-9)
    tgeoms = [g for g in prox if m.body(m.geom_bodyid[g]).name in ("distal_thumb_r", "proximal_thumb_r")]
    tip = [g for g in tgeoms if m.body(m.geom_bodyid[g]).name == "distal_thumb_r"]
    qcur = d.qpos[:nh].copy()
    th0 = np.array([qcur[jadr[j]] for j in TJ])
    bt = None
    for q4, qh in thumb_grid(qcur, 9):
        if not (-0.003 <= mind(qh, q_obj[:3], tgeoms) <= -0.001) or mind(qh, q_obj[:3], tip) > 0:
            continue
        mujoco.mj_geomDistance(m, dk, tip[0], ogeoms[0], 0.05, ft)
        n = ft[:3] - q_obj[:3]
        n /= np.linalg.norm(n)
        sc = float(n @ fhat) - 0.05 * float(np.abs(np.array(q4) - th0).sum())
        if bt is None or sc > bt[0]:
            bt = (sc, np.array(q4), n)
    if bt is not None and thumb_force > 0:
        at, dist_t = 0.0, names.index("distal_thumb_r")
        for f in range(100):
            if bone_force()[dist_t] >= thumb_force or clear([dist_t]) <= CLEAR:
                break
            at = min(1.0, at + 1 / 60)
            for j, v, v0 in zip(TJ, bt[1], th0):
                ctrl[act[j]] = np.clip(v0 + at * (v - v0), lo_c[act[j]], hi_c[act[j]])
            d.ctrl[:] = ctrl
            frame()
        for j, v, v0 in zip(TJ, bt[1], th0):
            ctrl[act[j]] = d.qpos[jadr[j]] + margin * np.sign(v - v0)
        for _ in range(20):
            d.ctrl[:] = ctrl
            frame()
        say(f"C: thumb toward {np.round(bt[1], 3)} (normal {np.round(bt[2], 2)}), {at:.2f} of the way; "
            f"its skin force {bone_force()[dist_t]:.2f} N", flush=True)
    grasp = dict(qpos=d.qpos[:nh].copy(), ctrl=np.clip(ctrl, lo_c, hi_c), pos=q_obj[:3].copy(), quat=q_obj[3:7].copy())

    # D: the check: released without gravity, then with it
    p_rel = d.qpos[qa:qa + 3].copy()
    for _ in range(60):
        frame(hold=False)
    p0 = d.qpos[qa:qa + 3].copy()
    m.opt.gravity[:] = g0
    worst = 0.0
    for _ in range(400):
        frame(hold=False)
        worst = max(worst, float(np.linalg.norm(d.qpos[qa:qa + 3] - p0)))
    say(f"D: released without gravity it moved {np.linalg.norm(p0 - p_rel) * 1e3:.1f} mm; with gravity, "
        f"largest offset in 2 s {worst * 1e3:.1f} mm", flush=True)
    grasp.update(moved_mm=float(-dy * 1e3), worst_mm=worst * 1e3)
    return grasp


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("objects", nargs="+", choices=hand_hold.OBJECTS)
    p.add_argument("--margin", type=float, default=0.05, help="rad past the touch (fingers and thumb)")
    p.add_argument("--thumb-force", type=float, default=1.0, help="N of the thumb's distal skin that stops its closing")
    p.add_argument("--write", action="store_true", help="store the grasps in hand_hold_grasps.json")
    a = p.parse_args()
    path = Path(hand_hold.__file__).with_name("hand_hold_grasps.json")
    data = json.loads(path.read_text())
    for obj in a.objects:
        t0 = time.perf_counter()
        g = search(obj, a.margin, a.thumb_force)
        print(f"{obj}: {time.perf_counter() - t0:.0f} s")
        if a.write:
            data[obj] = dict(qpos=[round(float(v), 6) for v in g["qpos"]], ctrl=[round(float(v), 6) for v in g["ctrl"]],
                             pos=[round(float(v), 6) for v in g["pos"]], quat=[round(float(v), 6) for v in g["quat"]],
                             made=f"benchmarks/hold_grasps.py --margin {a.margin} --thumb-force {a.thumb_force}: "
                                  f"object {g['moved_mm']:.1f} mm toward the palm")
    if a.write:
        path.write_text("{\n" + ",\n".join(
            f' "{k}": {{\n' + ",\n".join(f'  "{f}": {json.dumps(v)}' for f, v in e.items()) + "\n }" for k, e in data.items())
            + "\n}\n")


if __name__ == "__main__":
    main()
