"""MuJoCo Warp's side of a batched rollout: W worlds stepped on the GPU and their poses read back.

    python benchmarks/mjwarp_poses.py [--device cuda] [--scenes hoi_apple,hoi_box] [--worlds 256,1024,4096]
                                      [--frames 36] [--out PATH]

Issue 15 asks for the batch's bone poses "per world with MuJoCo's C API in threads, or batched on
the GPU with MuJoCo Warp (pinned to the MuJoCo in use) where its kinematics cover the scene; measure
both and choose". ``benchmarks/mujoco_side.py`` measures the C API (the rollout's serial
``mj_step`` loop and MuJoCo's threaded ``mujoco.rollout`` with pose sensors); this measures MuJoCo
Warp (``mujoco_warp``, not a dependency of the package: ``pip install mujoco-warp``): the scene's
``grasp`` keyframe in all W worlds (``put_data``), one ``mjw.step`` a frame (a captured CUDA graph on
the GPU), per world-frame (us) after two untimed steps (compilation):

- ``step``: the steps alone;
- ``step_read``: each step, then the poses a batch takes copied to the host (``xpos`` / ``xquat`` of
  every body and ``geom_xpos`` / ``geom_xmat`` of every geom, W worlds' at once) and the bones' and
  object geoms' rows picked out (``BatchedHands.submit`` takes host arrays).

``agree_m``: after the 2 + ``--frames`` steps, the largest distance between world 0's bone origins
and those of MuJoCo's own ``mj_step`` from the same keyframe (float32 against float64). The grasp
keyframes hold the hand still, so this checks the kinematics at that state, not a trajectory. Prints one JSON line per scene and W and writes them to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def run(scene: str, worlds: int, frames: int, device: str, asset) -> dict:
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    import physhand_mj as ph
    from physhand_mj.coupling import select_object_geoms
    from physhand_mj.hand_mjcf import skin_geom_id

    model = mujoco.MjModel.from_xml_path(str(ph.scene_path(scene)))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    mujoco.mj_forward(model, data)
    bones = ph.body_ids(model, [str(b) for b in asset.body_names])
    geoms = select_object_geoms(model, bones, skin_geom_id(model, ""))
    ref = mujoco.MjData(model)  # MuJoCo's own trajectory from the same state
    mujoco.mj_resetDataKeyframe(model, ref, model.key("grasp").id)
    with wp.ScopedDevice(device):
        t0 = time.perf_counter()
        m = mjw.put_model(model)
        d = mjw.put_data(model, data, nworld=worlds, nconmax=128, njmax=512)
        setup_s = time.perf_counter() - t0
        for _ in range(2):  # (compilation)
            mjw.step(m, d)
        wp.synchronize()
        graph = None
        if wp.get_device(device).is_cuda:
            with wp.ScopedCapture() as cap:  # (recorded, not run)
                mjw.step(m, d)
            graph = cap.graph
        steps = 2

        def step():
            if graph is not None:
                wp.capture_launch(graph)
            else:
                mjw.step(m, d)

        host = {name: wp.empty(getattr(d, name).shape, dtype=getattr(d, name).dtype, device="cpu",
                               pinned=graph is not None) for name in ("xpos", "xquat", "geom_xpos", "geom_xmat")}

        def read():
            for name, arr in host.items():
                wp.copy(arr, getattr(d, name))
            wp.synchronize()
            return (host["xpos"].numpy()[:, bones], host["xquat"].numpy()[:, bones],
                    host["geom_xpos"].numpy()[:, geoms], host["geom_xmat"].numpy()[:, geoms])

        half = frames // 2
        t = time.perf_counter()
        for _ in range(half):
            step()
        wp.synchronize()
        t_step = (time.perf_counter() - t) / half
        t = time.perf_counter()
        for _ in range(frames - half):
            step()
            out = read()
        t_read = (time.perf_counter() - t) / (frames - half)
        steps += frames
    for _ in range(steps):
        mujoco.mj_step(model, ref)
    agree = float(np.abs(out[0][0] - ref.xpos[bones]).max())
    return dict(scene=scene, worlds=worlds, frames=frames, device=device, graph=graph is not None,
                setup_s=round(setup_s, 2), step_us=round(t_step / worlds * 1e6, 3),
                step_read_us=round(t_read / worlds * 1e6, 3), step_ms=round(t_step * 1e3, 3),
                step_read_ms=round(t_read * 1e3, 3), agree_m=agree, bones=len(bones), geoms=len(geoms),
                hand_frames_per_s_alone=round(worlds / t_read, 1))


def main() -> None:
    import mujoco
    import mujoco_warp
    import warp as wp

    import physhand_mj as ph
    from physhand_mj.bench import device_name

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", help="Warp device: cuda or cpu")
    ap.add_argument("--scenes", default="hoi_apple,hoi_box")
    ap.add_argument("--worlds", default="256,1024,4096", help="comma-separated world counts")
    ap.add_argument("--frames", type=int, default=36, help="5 ms frames timed (count; half without the reads)")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/mjwarp_poses_<device>.json)")
    a = ap.parse_args()
    wp.init()
    asset = ph.load_asset()
    rows = []
    for scene in a.scenes.split(","):
        for w in (int(s) for s in a.worlds.split(",")):
            rows.append(run(scene, w, a.frames, a.device, asset))
            print(json.dumps(rows[-1]), flush=True)
    out = Path(a.out) if a.out else Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / \
        f"mjwarp_poses_{a.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(dict(device=device_name(a.device if a.device != "cuda" else "cuda:0"),
                                   mujoco=mujoco.__version__, mujoco_warp=getattr(mujoco_warp, "__version__", "?"),
                                   warp=wp.config.version,
                                   command="python benchmarks/mjwarp_poses.py " + " ".join(sys.argv[1:]),
                                   rows=rows), indent=1))
    print(json.dumps(dict(out=str(out))))


if __name__ == "__main__":
    main()
