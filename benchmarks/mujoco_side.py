"""The rigid MuJoCo step of the suite's scenes batched two ways, for the batched environment's MuJoCo side.

Scenes: ``hand_hold`` (``build_model("apple", "down", "hoi")``: the hand's capsule proxies and palm box,
the free apple (a sphere geom; ``--object bowl`` for the one mesh object), the floor 20 cm below) and ``fingertip_press`` (``build_model()``: the proxies and the fixed plate), each
from keyframe 0 with ctrl = the keyframe's ctrl held. One env step is the tasks' control step (0.01 s:
2 MuJoCo steps of 5 ms). The soft hand is not stepped: this is MuJoCo's side alone.

Backends (rows of the table):

- ``serial``: ``mujoco.mj_step`` of one world in a Python loop (the single env's MuJoCo side).
- ``rollout``: MuJoCo's threaded C rollout (``mujoco.rollout.Rollout(nthread=T)``) called once per
  env step as an env would: state in and out as (W, nstate) arrays (mjSTATE_FULLPHYSICS),
  ``nstep`` = the MuJoCo steps per env step, controls ctrl + mocap (the rollout resets mocap to the
  model's body pose unless the control spec carries it).
- ``rollout_long``: the same, one call of all the steps (the rollout's best case: no per-call cost).
- ``mjwarp``: MuJoCo Warp (``mjw.step``), W worlds in one ``Data``; on CUDA the env step (its MuJoCo
  steps) is one captured CUDA graph (``wp.ScopedCapture``, as mujoco_warp's testspeed.py); state on
  the device. ``mjwarp_io`` adds what an env with host arrays pays: ctrl to the device before and
  qpos, qvel back after each env step.

Each backend runs ``--warmup`` env steps untimed (compilation, graph capture, the first call), then
``--steps`` timed; after all of them every world's qpos is compared with serial ``mj_step``:
``rollout_long`` should be exact; ``rollout`` is exact against a serial run that zeroes
``qacc_warmstart`` at each env step (the C rollout zeroes it at every call and does not return it),
and the difference against the plain serial run is printed beside it; MJWarp (float32) is within
``--tol`` or flagged. ``rollout_long`` keeps every step's state: W x steps x 2 x nstate doubles
(0.4 GB at W 4,096 and 100 steps).

MJWarp's contact and constraint capacity (``put_data``'s ``nconmax``, ``njmax``, per world) are by
default the larger of its own guess and twice the most the serial run reached; per-world overflow
flags (``Data.overflow``) after the run are reported, as are the collision pairs MJWarp keeps (the
hand's skin and bone meshes have contype = conaffinity = 0: they should not appear).

    python benchmarks/mujoco_side.py [--device cpu|cuda] [--worlds 1,16,256,1024,4096] [--steps N]
        [--scenes hand_hold,fingertip_press] [--object apple] [--backends serial,rollout,rollout_long,mjwarp,mjwarp_io]
        [--threads T] [--out results.json]

Defaults: on the CPU worlds 1,4,16 and 10 steps (the small check, < 2 min on 2 cores once Warp's
kernels are cached); on CUDA worlds 1,16,256,1024,4096 and 100 steps.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import mujoco
import numpy as np
from mujoco import rollout

from physhand_dmc.suite import fingertip_press, hand_hold

STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
# ctrl and the mocap mount: without the mocap bits the C rollout puts the mount at the model's body pose
CONTROL = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS | mujoco.mjtState.mjSTATE_MOCAP_QUAT
SCENES = {
    "hand_hold": (lambda obj: hand_hold.build_model(obj, "down", "hoi"), hand_hold._CONTROL_TIMESTEP),
    "fingertip_press": (lambda obj: fingertip_press.build_model(), fingertip_press._CONTROL_TIMESTEP),
}
BACKENDS = ("serial", "rollout", "rollout_long", "mjwarp", "mjwarp_io")


def load(name, obj):
    build, control_dt = SCENES[name]
    m = build(obj)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    nsub = int(round(control_dt / m.opt.timestep))
    return m, d, nsub


def serial_reference(m, d0, nsub, nenv, zero_warmstart):
    """qpos after ``nenv`` env steps of ``mj_step`` from ``d0``, and the most contacts / constraint rows seen."""
    d = mujoco.MjData(m)
    state = np.empty(mujoco.mj_stateSize(m, STATE))
    mujoco.mj_getState(m, d0, state, STATE)
    mujoco.mj_setState(m, d, state, STATE)
    d.ctrl[:], d.mocap_pos[:], d.mocap_quat[:] = d0.ctrl, d0.mocap_pos, d0.mocap_quat
    ncon = nefc = 0
    for _ in range(nenv):
        if zero_warmstart:
            d.qacc_warmstart[:] = 0
        for _ in range(nsub):
            mujoco.mj_step(m, d)
            ncon, nefc = max(ncon, d.ncon), max(nefc, d.nefc)
    return d.qpos.copy(), ncon, nefc


def time_serial(m, d0, nsub, warmup, steps):
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    for _ in range(warmup * nsub):
        mujoco.mj_step(m, d)
    t = time.perf_counter()
    for _ in range(steps * nsub):
        mujoco.mj_step(m, d)
    return time.perf_counter() - t, d.qpos[None].copy()


def initial_arrays(m, d0, W, nsub):
    state0 = np.empty(mujoco.mj_stateSize(m, STATE))
    mujoco.mj_getState(m, d0, state0, STATE)
    ctrl0 = np.empty(mujoco.mj_stateSize(m, CONTROL))
    mujoco.mj_getState(m, d0, ctrl0, CONTROL)
    return np.tile(state0, (W, 1)), np.tile(ctrl0, (W, nsub, 1))


def time_rollout(m, d0, nsub, W, threads, warmup, steps):
    """One rollout call per env step, the state carried between calls as an env would."""
    state, control = initial_arrays(m, d0, W, nsub)
    out = np.empty((W, nsub, state.shape[1]))
    models, datas = [m] * W, [mujoco.MjData(m) for _ in range(threads)]
    with rollout.Rollout(nthread=threads) as r:
        def env_step():
            # an env writes its actions into `control` here; the keyframe's ctrl stays
            r.rollout(models, datas, state, control, control_spec=CONTROL, skip_checks=True, nstep=nsub, state=out)
            state[:] = out[:, -1]
        for _ in range(warmup):
            env_step()
        t = time.perf_counter()
        for _ in range(steps):
            env_step()
        elapsed = time.perf_counter() - t
    return elapsed, state[:, 1:1 + m.nq].copy()  # FULLPHYSICS starts with time, then qpos


def time_rollout_long(m, d0, nsub, W, threads, warmup, steps):
    """All warmup + steps env steps in one call (timed whole, reported per env step)."""
    nstep = (warmup + steps) * nsub
    state, _ = initial_arrays(m, d0, W, 1)
    _, control = initial_arrays(m, d0, W, nstep)
    out = np.empty((W, nstep, state.shape[1]))
    models, datas = [m] * W, [mujoco.MjData(m) for _ in range(threads)]
    with rollout.Rollout(nthread=threads) as r:
        r.rollout(models, datas, state, control[:, :1].copy(), control_spec=CONTROL, nstep=1)  # pool warm
        t = time.perf_counter()
        r.rollout(models, datas, state, control, control_spec=CONTROL, skip_checks=True, nstep=nstep, state=out)
        elapsed = time.perf_counter() - t
    return elapsed * steps / (warmup + steps), out[:, -1, 1:1 + m.nq].copy()


class MJWarp:
    """One scene on MuJoCo Warp: the model once, a Data of W worlds per call."""

    def __init__(self, m, d0, device, nconmax, njmax):
        import mujoco_warp as mjw
        import warp as wp

        self.mjw, self.wp, self.mjm, self.d0 = mjw, wp, m, d0
        self.device = wp.get_device(device)
        t = time.perf_counter()
        with wp.ScopedDevice(self.device):
            self.m = mjw.put_model(m)
        self.put_model_s = time.perf_counter() - t
        self.nconmax, self.njmax = nconmax, njmax

    def info(self):
        """Collision pairs MJWarp keeps, and whether any is a hand mesh (skin, bones)."""
        m, mjm = self.m, self.mjm
        host = lambda a: a.numpy() if hasattr(a, "numpy") else np.asarray(a)  # noqa: E731  (CUDA arrays: copy)
        pairs = host(m.nxn_geom_pair_filtered).reshape(-1, 2)
        mesh = {g for g in range(mjm.ngeom) if mjm.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
                and mjm.geom_contype[g] == 0 and mjm.geom_conaffinity[g] == 0}
        types = {}
        for g1, g2 in pairs:
            key = "-".join(sorted((mujoco.mjtGeom(mjm.geom_type[g1]).name[7:].lower(), mujoco.mjtGeom(mjm.geom_type[g2]).name[7:].lower())))
            types[key] = types.get(key, 0) + 1
        return {"npairs_all": len(host(m.nxn_geom_pair).reshape(-1, 2)), "npairs_kept": len(pairs),
                "pair_types": types, "pairs_with_noncolliding_meshes": int(sum(g1 in mesh or g2 in mesh for g1, g2 in pairs)),
                "noncolliding_mesh_geoms": len(mesh), "mesh_vertices_on_device": int(mjm.nmeshvert),
                "is_sparse": bool(m.is_sparse), "broadphase": str(m.opt.broadphase.name),
                "solver_iterations": int(m.opt.iterations), "ls_iterations": int(m.opt.ls_iterations), "put_model_s": self.put_model_s}

    def run(self, nsub, W, warmup, steps, io):
        mjw, wp = self.mjw, self.wp
        with wp.ScopedDevice(self.device):
            d = mjw.put_data(self.mjm, self.d0, nworld=W, nconmax=self.nconmax, njmax=self.njmax)
            ctrl_host = np.tile(self.d0.ctrl.astype(np.float32), (W, 1))
            t = time.perf_counter()
            if self.device.is_cuda:
                with wp.ScopedCapture() as capture:  # records the steps (and compiles), runs nothing
                    for _ in range(nsub):
                        mjw.step(self.m, d)
                graph = capture.graph

                def physics():
                    wp.capture_launch(graph)
            else:
                def physics():
                    for _ in range(nsub):
                        mjw.step(self.m, d)

            def env_step():
                if io:
                    d.ctrl.assign(ctrl_host)
                physics()
                if io:
                    d.qpos.numpy(), d.qvel.numpy()  # the host copies synchronize
                else:
                    wp.synchronize_device()

            for i in range(warmup):
                env_step()
                if i == 0:
                    first_s = time.perf_counter() - t
            t = time.perf_counter()
            for _ in range(steps):
                env_step()
            elapsed = time.perf_counter() - t
            overflow = d.overflow.numpy()
            nacon, nefc = int(d.nacon.numpy()[0]), int(d.nefc.numpy().max())
            qpos = d.qpos.numpy().astype(np.float64)
        flags = {}
        for f in mjw.OverflowType:
            if f.value and not f.value & (f.value - 1):
                n = int(np.count_nonzero(overflow & f.value))
                if n:
                    flags[f.name] = n
        return elapsed, qpos, {"compile_capture_first_s": first_s, "overflow_worlds": flags,
                               "nacon_all_worlds_end": nacon, "nefc_max_world_end": nefc}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--worlds", default=None, help="comma list (default: 1,4,16 on cpu, 1,16,256,1024,4096 on cuda)")
    ap.add_argument("--steps", type=int, default=None, help="timed env steps (default: 10 cpu, 100 cuda)")
    ap.add_argument("--warmup", type=int, default=2, help="untimed env steps first (>= 1)")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--object", default="apple", choices=hand_hold.OBJECTS,
                    help="hand_hold's object (apple: a sphere; bowl: the one mesh, 706 vertices)")
    ap.add_argument("--backends", default=",".join(BACKENDS))
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="C rollout threads (default: all cores)")
    ap.add_argument("--nconmax", type=int, default=None, help="MJWarp contacts per world (default: see docstring)")
    ap.add_argument("--njmax", type=int, default=None, help="MJWarp constraint rows per world (default: see docstring)")
    ap.add_argument("--tol", type=float, default=1e-3, help="MJWarp's max |qpos - serial| allowed (m, rad)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    cuda = a.device.startswith("cuda")
    worlds = [int(w) for w in (a.worlds or ("1,16,256,1024,4096" if cuda else "1,4,16")).split(",")]
    steps = a.steps or (100 if cuda else 10)
    warmup = max(1, a.warmup)
    backends = a.backends.split(",")
    for b in backends:
        if b not in BACKENDS:
            raise SystemExit(f"unknown backend {b!r}; choose from {BACKENDS}")

    meta = {"device": a.device, "host_cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
            "rollout_threads": a.threads, "mujoco": mujoco.__version__, "steps": steps, "warmup": warmup,
            "tol": a.tol}
    if any(b.startswith("mjwarp") for b in backends):
        import mujoco_warp
        import warp as wp

        wp.config.quiet = True
        wp.init()
        meta.update(mujoco_warp=getattr(mujoco_warp, "__version__", "?"), warp=wp.__version__,
                    device_name=wp.get_device(a.device).name)
    print(f"device {a.device} ({meta.get('device_name', meta['host_cpu'])}), {os.cpu_count()} CPU cores, "
          f"rollout threads {a.threads}; MuJoCo {mujoco.__version__}; {warmup} warm-up + {steps} timed env steps")
    meta["hand_hold_object"] = a.object
    results = {"meta": meta, "scenes": {}}
    for name in a.scenes.split(","):
        m, d0, nsub = load(name, a.object)
        nenv = warmup + steps
        ref, ncon, nefc = serial_reference(m, d0, nsub, nenv, zero_warmstart=False)
        ref0, _, _ = serial_reference(m, d0, nsub, nenv, zero_warmstart=True)
        scene = {"nq": m.nq, "nv": m.nv, "nu": m.nu, "ngeom": m.ngeom, "timestep": m.opt.timestep,
                 "mj_steps_per_env_step": nsub, "serial_max_ncon": ncon, "serial_max_nefc": nefc,
                 "warmstart_zeroing_qpos_diff": float(np.abs(ref0 - ref).max()), "rows": []}
        print(f"\n{name}: nq {m.nq} nv {m.nv} nu {m.nu} ngeom {m.ngeom}; env step = {nsub} x {m.opt.timestep * 1e3:g} ms; "
              f"serial run: up to {ncon} contacts, {nefc} constraint rows")
        mjwarp = None
        if any(b.startswith("mjwarp") for b in backends):
            from mujoco_warp._src.io import _default_nconmax, _default_njmax
            nconmax = a.nconmax or max(_default_nconmax(m), 2 * ncon)
            njmax = a.njmax or max(_default_njmax(m), 2 * nefc)
            mjwarp = MJWarp(m, d0, a.device, nconmax, njmax)
            scene["mjwarp"] = dict(mjwarp.info(), nconmax=nconmax, njmax=njmax,
                                   default_nconmax=_default_nconmax(m), default_njmax=_default_njmax(m))
            mi = scene["mjwarp"]
            print(f"  MJWarp: put_model {mi['put_model_s']:.1f} s; nconmax {nconmax} njmax {njmax} per world "
                  f"(its defaults {mi['default_nconmax']}, {mi['default_njmax']}); collision pairs kept "
                  f"{mi['npairs_kept']} of {mi['npairs_all']} {mi['pair_types']}; pairs with the "
                  f"{mi['noncolliding_mesh_geoms']} non-colliding meshes (skin, bones): {mi['pairs_with_noncolliding_meshes']}")
        print(f"  {'backend':<13}{'W':>6}{'ms / env step':>15}{'env-steps/s':>14}{'max|dq| serial':>16}  note")
        for b in backends:
            for W in ([1] if b == "serial" else worlds):
                extra, note = {}, ""
                if b == "serial":
                    el, q = time_serial(m, d0, nsub, warmup, steps)
                elif b == "rollout":
                    el, q = time_rollout(m, d0, nsub, W, a.threads, warmup, steps)
                    extra["max_dq_vs_serial_zeroed_warmstart"] = float(np.abs(q - ref0).max())
                    note = f"vs serial with warmstart zeroed per env step: {extra['max_dq_vs_serial_zeroed_warmstart']:.1e}"
                elif b == "rollout_long":
                    el, q = time_rollout_long(m, d0, nsub, W, a.threads, warmup, steps)
                else:
                    el, q, extra = mjwarp.run(nsub, W, warmup, steps, io=b == "mjwarp_io")
                    note = (f"first call {extra['compile_capture_first_s']:.1f} s; overflow "
                            f"{extra['overflow_worlds'] or 'none'}")
                dq = float(np.abs(q - ref).max())
                if b.startswith("mjwarp") and not dq <= a.tol:
                    note += f"; OVER tol {a.tol:g}"
                ms = 1e3 * el / steps
                row = dict(backend=b, worlds=W, ms_per_env_step=ms, env_steps_per_s=W * steps / el,
                           mj_steps_per_s=W * steps * nsub / el, max_dq_vs_serial=dq, **extra)
                scene["rows"].append(row)
                print(f"  {b:<13}{W:>6}{ms:>15.3f}{row['env_steps_per_s']:>14,.0f}{dq:>16.1e}  {note}", flush=True)
        print(f"  (serial with qacc_warmstart zeroed per env step vs plain serial: {scene['warmstart_zeroing_qpos_diff']:.1e})")
        results["scenes"][name] = scene
    if a.out:
        with open(a.out, "w") as f:
            json.dump(results, f, indent=1)
        print(f"\nwrote {a.out}")


if __name__ == "__main__":
    main()
