"""MyoSuite's ObjHold held by the skin: the grasp search and the one-way / two-way table (docs/tasks.md).

The grasp (``plugins/physhand_myosuite/objhold_grasp.json``) is one constant action of the env's
normalised action space (39 muscles), as a policy would output it from the reset (hand open, palm
up, the object in the palm). ``--search`` finds it with MuJoCo alone (MyoHand's contact capsules,
which lie on the skin's surface, standing in for the skin; ~2 ms per env step, so thousands of
rollouts fit in minutes): a small evolution strategy (diagonal Gaussian, 24 samples, the best 6
recombined) minimising the object's largest offset from its start over ``--seconds`` s, plus 6 mm
per finger short of four touching it at the end and 4 mm if the thumb does not, the worst of four
starts (as the env resets it, lifted 3 mm, pushed two ways: ``KICKS``; without them the best grasp flung the
object out under two-way, whose skin pushes differently from the capsules), plus 0.1 m per radian
the palm turns beyond 0.2 rad from up (``TILT_*``: a grasp that rolled the palm 0.85 rad held the
object on the capsules but the skin alone let it slide off after 0.45 s). ``--write`` stores
the best with ``--search``'s settings in the JSON file.

The table (default) holds the grasp for ``--seconds`` s of sim time in the wrapper, per mode:
``one`` one-way (the capsules hold, the skin only deforms), ``two`` two-way (capsules and skin),
``skin`` two-way with the object out of the capsules' collisions (``hold.skin_only``: the skin
alone holds it), ``one-skin`` one-way without the capsules (nothing holds it). Per run: the
object's largest and final offset from its start, its drift over the last half, the force the skin
applied (mean over the last 0.5 s: vector, friction part, contact vertices), MuJoCo's contact force
on it, m g, both penetration measures at the end and MyoSuite's ``solved``.

Run: ``python benchmarks/myosuite_hold.py [--modes one,two,skin,one-skin] [--seconds 2]`` (CPU:
a two-way run is 1,000 soft frames, ~2-3 min on 2 shared cores);
``python benchmarks/myosuite_hold.py --search --generations 60 --seed 1 [--write | --out PATH]``
(``--restart``: from the stored grasp; ``--shrink M``: the hand's capsules M m thinner in the search,
nearer the skin's smoother surface); ``--grasp PATH`` runs the table with another grasp record.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

ENV = "myoHandObjHoldFixed-v0"
KICKS = ((0, 0, 0.003, 0, 0, 0), (0, 0, 0, 0.05, -0.05, 0.1))
"""Object perturbations (m, m/s) the grasp must also hold through: lifted 3 mm; pushed up and sideways
(two-way, the compressed palm skin pushes the object up ~2.4 N and towards the fingers' side ~3.4 N in
the first frame, 10 mm in 60 ms: MuJoCo's capsules had let it sit into the skin's rest surface)."""
TILT_FREE, TILT_COST = 0.15, 0.1  # rad, m/rad: the palm turning more than 0.15 rad from up costs 10 mm/0.1 rad
MOVE_FREE, MOVE_COST = 0.02, 0.5  # m, m/m: the palm moving more than 20 mm costs half of it
FINGERS = {"thumb": ("firstmc", "proximal_thumb", "distal_thumb"),
           **{f"f{k}": (f"proxph{k}", f"midph{k}", f"distph{k}") for k in (2, 3, 4, 5)}}


def search(generations: int, seed: int, seconds: float, start=None, sigma: float = 0.5, lift: float = 0.0,
           shrink: float = 0.0, verbose=True) -> dict:
    """The evolution strategy of the module docstring, MuJoCo alone; returns the grasp record."""
    import gymnasium
    import mujoco
    import myosuite  # noqa: F401  (registers the envs)
    from physhand_myosuite import hold

    env = gymnasium.make(ENV)
    u = env.unwrapped
    m, d = u.model, u.data
    names = [m.actuator(i).name for i in range(m.nu)]
    ob = m.body("object").id
    palm = m.body("thirdmc").id
    for g in range(m.ngeom):  # shrink: the hand's capsules thinner (m), nearer the skin's smoother surface
        if shrink and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE and m.body_rootid[m.geom_bodyid[g]] != 0:
            m.geom_size[g, 0] -= shrink
    fid = {f: {m.body(b).id for b in bs} for f, bs in FINGERS.items()}
    steps = int(round(seconds / u.dt))

    def touching():
        bs = {int(m.geom_bodyid[c.geom1] + m.geom_bodyid[c.geom2] - ob) for c in d.contact[:d.ncon]
              if ob in (m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2])}
        return {f for f, ids in fid.items() if ids & bs}

    qa, va = int(m.jnt_qposadr[m.body_jntadr[ob]]), int(m.jnt_dofadr[m.body_jntadr[ob]])

    def rollout(a, kick):
        env.reset(seed=0)
        d.qpos[qa + 2] += lift
        mujoco.mj_forward(m, d)
        p0 = d.xpos[ob].copy()
        d.qpos[qa: qa + 3] += kick[:3]
        d.qvel[va: va + 3] += kick[3:]
        n0 = d.xmat[palm].reshape(3, 3)[:, 2].copy()
        x0 = d.xpos[palm].copy()
        worst = tilt = move = 0.0
        for k in range(steps):
            env.step(a)
            worst = max(worst, float(np.linalg.norm(d.xpos[ob] - p0)))
            tilt = max(tilt, float(np.arccos(np.clip(d.xmat[palm].reshape(3, 3)[:, 2] @ n0, -1, 1))))
            move = max(move, float(np.linalg.norm(d.xpos[palm] - x0)))
            if worst > 0.05:  # dropped: ranked by how long it stayed
                return 0.05 + 0.01 * (steps - k), set()
        t = touching()
        return (worst + 0.006 * max(0, 4 - len(t)) + (0.0 if "thumb" in t else 0.004)
                + TILT_COST * max(0.0, tilt - TILT_FREE) + MOVE_COST * max(0.0, move - MOVE_FREE)), t

    def cost(a):  # the worst of the start and of KICKS (the skin's first push differs from the capsules')
        r = [rollout(a, np.zeros(6))]
        for kick in KICKS:
            if r[-1][0] >= 0.05:
                break
            r.append(rollout(a, np.asarray(kick)))
        return max(ri[0] for ri in r), r[0][1]

    rng = np.random.default_rng(seed)
    n = m.nu
    if start is None:  # the flexors and the wrist's extensors half on, the rest nearly off
        mean = np.full(n, -0.5)
        for nm in ("FDS2", "FDS3", "FDS4", "FDS5", "FDP2", "FDP3", "FDP4", "FDP5", "FPL", "OP", "ECRL", "ECRB"):
            mean[names.index(nm)] = 0.0
    else:
        mean = np.array([start[nm] for nm in names], float)
    sig = np.full(n, sigma)
    lam, mu = 24, 6
    w = np.log(mu + 0.5) - np.log(np.arange(1, mu + 1))
    w /= w.sum()
    best = (np.inf, None, set())
    t0 = time.perf_counter()
    for gen in range(generations):
        x = np.clip(mean + sig * rng.standard_normal((lam, n)), -1, 1)
        r = [cost(xi.astype(np.float32)) for xi in x]
        f = np.array([ri[0] for ri in r])
        o = np.argsort(f)
        if f[o[0]] < best[0]:
            best = (float(f[o[0]]), x[o[0]].copy(), r[o[0]][1])
        new = w @ x[o[:mu]]
        sig = np.clip(0.8 * sig + 0.2 * np.sqrt(w @ ((x[o[:mu]] - mean) ** 2)), 0.05, 1.0)
        mean = new
        if verbose and gen % 5 == 0:
            print(f"gen {gen}: best cost {best[0] * 1e3:.1f} mm, touching {sorted(best[2])} "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
    a = best[1].astype(np.float32)
    act = hold.activation(a)
    return dict(env=ENV, action={nm: round(float(a[i]), 4) for i, nm in enumerate(names)},
                activation={nm: round(float(act[i]), 4) for i, nm in enumerate(names)},
                how=f"benchmarks/myosuite_hold.py --search --generations {generations} --seed {seed} "
                    f"--seconds {seconds}" + (" (restarted from the stored grasp, sigma "
                                              f"{sigma})" if start is not None else ""),
                lift_m=lift, mujoco_cost_mm=round(best[0] * 1e3, 2), touching=sorted(best[2]))


def run(mode: str, seconds: float, grasp=None) -> dict:
    import gymnasium
    import myosuite  # noqa: F401
    import physhand_myosuite as pm
    from physhand_myosuite import hold

    base = gymnasium.make(ENV)
    if mode in ("skin", "one-skin"):
        hold.skin_only(base.unwrapped.model)
    env = pm.SoftSkin(base, two_way=mode in ("two", "skin"))
    t0 = time.perf_counter()
    row = hold.hold_still(env, hold.grasp_action(env, grasp), seconds)
    row["s"] = time.perf_counter() - t0
    env.close()
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--modes", default="one,two,skin,one-skin")
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--search", action="store_true", help="search the grasp with MuJoCo alone")
    p.add_argument("--generations", type=int, default=60)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--restart", action="store_true", help="--search from the stored grasp (sigma 0.2)")
    p.add_argument("--write", action="store_true", help="store the searched grasp in the JSON file")
    p.add_argument("--out", help="with --search: write the grasp record here instead")
    p.add_argument("--grasp", help="the table with this grasp record (JSON) instead of the stored one")
    p.add_argument("--shrink", type=float, default=0.0, help="with --search: the hand's capsules this much thinner (m)")
    a = p.parse_args()
    from physhand_myosuite import hold

    if a.search:
        start = hold.load_grasp()["action"] if a.restart else None
        g = search(a.generations, a.seed, a.seconds, start=start, sigma=0.2 if a.restart else 0.5, lift=hold.LIFT,
                   shrink=a.shrink)
        print(json.dumps({k: g[k] for k in ("how", "mujoco_cost_mm", "touching")}))
        if a.write or a.out:
            out = a.out or hold.GRASP_PATH
            Path(out).write_text(json.dumps(g, indent=1) + "\n")
            print(f"wrote {out}")
        return
    print("| mode | worst offset mm | end mm | drift last half mm | within 2 cm | skin force N (x, y, z) | "
          "friction N | contact vertices | MuJoCo contact force N (z) | m g N | skin in object (n, max um) | "
          "object in skin (n, max um) | solved | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for mode in a.modes.split(","):
        r = run(mode, a.seconds, hold.load_grasp(a.grasp) if a.grasp else None)
        f, fr = r["force_n"], r["friction_n"]
        print(f"| {mode} | {r['worst_mm']:.1f} | {r['end_mm']:.1f} | {r['hold_mm']:.1f} | "
              f"{'yes' if r['worst_mm'] < 20 else 'no'} | ({f[0]:.2f}, {f[1]:.2f}, {f[2]:.2f}) | "
              f"{np.linalg.norm(fr):.2f} | {r['points']:.0f} | {r['capsule_n'][2]:.2f} | {r['weight_n']:.2f} | "
              f"{r['skin_in'][0]}, {r['skin_in'][1]:.0f} | {r['obj_in'][0]}, {r['obj_in'][1]:.0f} | "
              f"{r['solved']} | {r['s']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
