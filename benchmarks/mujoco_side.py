"""The MuJoCo side of a batched rollout: what W worlds' bone and object poses cost per frame.

    python benchmarks/mujoco_side.py [--scenes hoi_apple,hoi_box,grasp_glass] [--worlds 64,256,1024] [--frames 36]

A batched rollout (``physhand rollout LIST --batch W``, physhand_mj/batch_rollout.py) steps each
world's MjModel / MjData with ``mujoco.mj_step`` one after another and reads its bone poses
(``xpos``, ``xquat``) and object geom poses. Issue 15 asks whether that per-world C API or a batched
alternative should feed the batch. Measured per world-frame (us), after one untimed frame:

- ``serial``: the rollout's loop, ``mj_step`` then the pose reads (fancy-indexed copies);
- ``rollout``: MuJoCo's own multi-threaded ``mujoco.rollout.rollout`` (C++ thread pool, one MjData
  per thread, no GIL) over all ``--frames`` steps of the W worlds at once from the keyframe with its
  constant ctrl (the soft hand never acts back on MuJoCo, so a rollout's MuJoCo trajectory can be
  computed ahead), then per world-frame ``mj_setState`` + ``mj_kinematics`` for the poses;
- ``sensors``: the same threaded rollout of the scene with a ``framepos`` and a ``framequat`` sensor
  per bone body (its frame: ``xbody``) and object geom added (``mujoco.MjSpec``), so the poses come back as its sensor data
  from the C++ threads, with no per-world Python at all (a step's sensor row holds the poses of the
  state the step started from: MuJoCo evaluates sensors before it integrates).

and, for scale, the hand-frames per second each would allow on its own (1e6 / us). Prints one JSON
line per scene and W and writes them to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mujoco  # noqa: E402
import mujoco.rollout  # noqa: E402

import physhand_mj as ph  # noqa: E402
from physhand_mj.coupling import select_object_geoms  # noqa: E402
from physhand_mj.hand_mjcf import skin_geom_id  # noqa: E402

KEYS = {"grasp_glass": "approach"}  # the keyframe per scene (HOI scenes: grasp)


def mocap_at_key(model, key: int) -> None:
    """Move the model's mocap bodies to keyframe ``key``'s mocap poses: ``mujoco.rollout`` resets
    each world's data (mocap included) and takes only the physics state from ``initial_state``."""
    for b in np.flatnonzero(model.body_mocapid >= 0):
        i = model.body_mocapid[b]
        model.body_pos[b] = model.key_mpos[key].reshape(-1, 3)[i]
        model.body_quat[b] = model.key_mquat[key].reshape(-1, 4)[i]


def run(scene: str, worlds: int, frames: int, threads: int, asset) -> dict:
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path(scene)))
    key = model.key(KEYS.get(scene, "grasp")).id
    bones = ph.body_ids(model, [str(b) for b in asset.body_names])
    geoms = select_object_geoms(model, bones, skin_geom_id(model, ""))
    datas = [mujoco.MjData(model) for _ in range(worlds)]
    for d in datas:
        mujoco.mj_resetDataKeyframe(model, d, key)

    def poses(d):
        return d.xpos[bones].copy(), d.xquat[bones].copy(), d.geom_xpos[geoms].copy(), d.geom_xmat[geoms].copy()

    for d in datas:  # one untimed frame
        mujoco.mj_step(model, d)
        poses(d)
    t_step = t_read = 0.0
    for _ in range(frames):
        t = time.perf_counter()
        for d in datas:
            mujoco.mj_step(model, d)
        t_step += time.perf_counter() - t
        t = time.perf_counter()
        for d in datas:
            poses(d)
        t_read += time.perf_counter() - t
    n = worlds * frames
    serial_step, serial_read = 1e6 * t_step / n, 1e6 * t_read / n

    # MuJoCo's threaded rollout of the whole trajectory, then the poses from its states
    mocap_at_key(model, key)
    d0 = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d0, key)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, d0, state0, spec)
    init = np.tile(state0, (worlds, 1))
    ctrl = np.tile(d0.ctrl, (worlds, frames, 1))
    tdata = [mujoco.MjData(model) for _ in range(threads)]
    for td in tdata:  # (the mocap hand mount is not part of the physics state: the keyframe's)
        mujoco.mj_resetDataKeyframe(model, td, key)
    mujoco.rollout.rollout(model, tdata, init[:1], ctrl[:1, :1])  # warm the pool
    t = time.perf_counter()
    states, _ = mujoco.rollout.rollout(model, tdata, init, ctrl)
    t_roll = time.perf_counter() - t
    t = time.perf_counter()
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, key)
    for w in range(worlds):
        for f in range(frames):
            mujoco.mj_setState(model, d, states[w, f], spec)
            mujoco.mj_kinematics(model, d)
            poses(d)
    t_kin = time.perf_counter() - t
    # the two paths agree: the last frame's bone positions of world 0
    mujoco.mj_setState(model, d, states[0, -1], spec)
    mujoco.mj_kinematics(model, d)
    gap = float(np.abs(d.xpos[bones] - datas[0].xpos[bones]).max())
    roll_step, roll_kin = 1e6 * t_roll / n, 1e6 * t_kin / n

    # the poses as sensor data of the threaded rollout
    sp = mujoco.MjSpec.from_file(str(ph.scene_path(scene)))
    for b in bones:
        for kind in (mujoco.mjtSensor.mjSENS_FRAMEPOS, mujoco.mjtSensor.mjSENS_FRAMEQUAT):
            sp.add_sensor(type=kind, objtype=mujoco.mjtObj.mjOBJ_XBODY, objname=model.body(b).name)
    for g in geoms:
        for kind in (mujoco.mjtSensor.mjSENS_FRAMEPOS, mujoco.mjtSensor.mjSENS_FRAMEQUAT):
            sp.add_sensor(type=kind, objtype=mujoco.mjtObj.mjOBJ_GEOM, objname=model.geom(g).name)
    sm = sp.compile()
    mocap_at_key(sm, key)
    sdata = [mujoco.MjData(sm) for _ in range(threads)]
    for td in sdata:
        mujoco.mj_resetDataKeyframe(sm, td, key)
    mujoco.rollout.rollout(sm, sdata, init[:1], ctrl[:1, :1])
    t = time.perf_counter()
    _, sens = mujoco.rollout.rollout(sm, sdata, init, ctrl)
    t_sens = time.perf_counter() - t
    base = sm.nsensordata - 7 * (len(bones) + len(geoms))  # the scene's own sensors come first
    last = sens[0, -1, base: base + 7 * len(bones)].reshape(-1, 7)
    # (MuJoCo computes sensors before it integrates: step f's row holds the poses of the state step
    # f - 1 ended in, the threaded rollout's second-to-last state)
    mujoco.mj_setState(model, d, states[0, -2], spec)
    mujoco.mj_kinematics(model, d)
    gap_s = float(np.abs(last[:, :3] - d.xpos[bones]).max())
    sens_us = 1e6 * t_sens / n
    return dict(scene=scene, worlds=worlds, frames=frames, threads=threads,
                serial_step_us=round(serial_step, 2), serial_read_us=round(serial_read, 2),
                serial_us=round(serial_step + serial_read, 2),
                rollout_step_us=round(roll_step, 2), rollout_kinematics_us=round(roll_kin, 2),
                rollout_us=round(roll_step + roll_kin, 2),
                serial_hand_frames_per_s=round(1e6 / (serial_step + serial_read)),
                rollout_hand_frames_per_s=round(1e6 / (roll_step + roll_kin)),
                sensors_us=round(sens_us, 2), sensors_hand_frames_per_s=round(1e6 / sens_us),
                paths_agree_m=gap, sensors_agree_m=gap_s)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="hoi_apple,hoi_box,grasp_glass")
    ap.add_argument("--worlds", default="64,256,1024", help="comma-separated world counts")
    ap.add_argument("--frames", type=int, default=36, help="5 ms frames per rollout (count)")
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="mujoco.rollout threads (count)")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/mujoco_side_<host>.json)")
    a = ap.parse_args()
    from physhand_mj.bench import device_name

    asset = ph.load_asset()
    host = device_name("cpu")
    rows = []
    for scene in a.scenes.split(","):
        for w in (int(x) for x in a.worlds.split(",")):
            r = dict(run(scene, w, a.frames, a.threads, asset), host=host)
            print(json.dumps(r), flush=True)
            rows.append(r)
    out = Path(a.out) if a.out else Path(__file__).resolve().parents[1] / "docs/benchmarks/mujoco_side_cpu.json"
    out.write_text(json.dumps(dict(host=host, rows=rows), indent=1))


if __name__ == "__main__":
    main()
