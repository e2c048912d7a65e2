"""What a frame costs when only the effects the scene calls for run (physhand_mj/solver/activity.py).

Solver frames (set_body_poses + step, one host sync) of the embedded hand, open pose, palm down:
  none        the solver without objects (the full solver frame: the reference)
  far         a sphere 1 m away (no object near): skip_idle on (after) and off (before)
  touch       a 2 cm sphere pressing 2 mm into the back of the hand (analytic contact)
  asleep      the still hand with the sphere far, after it fell asleep (Config.sleep_speed; the
              other cases run with sleeping off, so they measure the awake frame)
  glass       the demo (grasp_glass, SoftHand.step during the approach/closing): contact vs NONE
Configurations run interleaved, ``--repeats`` rounds of ``--frames`` frames each; per configuration
the median over all frames is reported (the CPU host is shared: ratios within one run are what to
compare). ``--profile`` (CPU) also times every recorded op of the touch frame by kernel.
Compilation excluded (two warm-up frames per configuration). Writes
docs/benchmarks/activity_frame_<device>.json. Run: python benchmarks/activity_frame.py [--device cuda]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _solver_case(device, objects_at, skip_idle=True, radius=0.02, sleep=False):
    import physhand_mj as ph
    from physhand_mj.contact import Objects
    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene
    from physhand_mj.solver import Solver, make_model
    from physhand_mj.types import Config, Execution, GeomType

    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    poses = bone_poses_at(model, data, model.key("open").qpos, body_ids(model, asset.body_names))
    cfg = Config(device=device, **({} if sleep else {"sleep_speed": 0.0}), execution=Execution(skip_idle=skip_idle))
    objects = None
    if objects_at is not None:
        objects = Objects(device, 1)
        objects.add(GeomType.SPHERE, [radius, 0.0, 0.0], pos=(1.0, 1.0, 1.0), name="ball")
    solver = Solver(make_model(asset, cfg), cfg, objects=objects)
    state = solver.make_state(*mount_pose(model, data))
    if objects_at == "touch":
        skin = state.x.numpy()[: asset.n_skin]
        top = skin[np.argmax(skin[:, 2])].astype(float)
        objects.set_pose(0, top + [0.0, 0.0, radius - 0.002], (1.0, 0.0, 0.0, 0.0))

    def frame():
        solver.set_body_poses(state, *poses)
        return solver.step(state)

    if sleep:  # settle until asleep (Config.sleep_speed)
        for _ in range(600):
            if frame()["asleep"]:
                break
        else:
            raise RuntimeError("the still hand did not fall asleep in 600 frames")
    return frame, solver, state


def _glass_case(device, contact):
    import mujoco

    import physhand_mj as ph
    from physhand_mj.types import Strategy

    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device=device, contact=Strategy[contact]))

    def frame():  # the solver's share of SoftHand.step (sync and write-back excluded)
        mujoco.mj_step(model, data)
        hand.step()
        return hand._last

    return frame, hand.solver, hand.state, hand


def profile(frame, solver, state, frames=5) -> dict:
    """CPU: ms per frame of every recorded op, grouped by kernel name (memsets/refits as 'other')."""
    from physhand_mj.solver.activity import _Gate

    acc = defaultdict(float)
    ops = solver._ops[(id(state), id(solver.contact))]

    def wrap(lst):
        for i, op in enumerate(lst):
            if isinstance(op, _Gate):
                wrap(op.sub)
                continue
            cmd = getattr(op, "cmd", None) or getattr(op, "__self__", None)
            name = getattr(getattr(cmd, "kernel", None), "key", "other (memsets, refits)")

            def timed(op=op, name=name):
                t = time.perf_counter()
                op()
                acc[name] += time.perf_counter() - t

            lst[i] = timed

    wrap(ops)
    for _ in range(frames):
        frame()
    return {k: round(v / frames * 1e3, 3) for k, v in sorted(acc.items(), key=lambda kv: -kv[1])}


def main():
    from physhand_mj.bench import device_name

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--no-glass", action="store_true", help="skip the demo scene (SoftHand)")
    p.add_argument("--profile", action="store_true", help="CPU: per-kernel split of the touch frame")
    args = p.parse_args()
    import warp as wp

    wp.init()
    cases = {
        "none (no objects)": _solver_case(args.device, None),
        "far, skip_idle off (before)": _solver_case(args.device, "far", skip_idle=False),
        "far, skip_idle on (after)": _solver_case(args.device, "far"),
        "touch (sphere, 2 mm)": _solver_case(args.device, "touch"),
        "still hand asleep, object far": _solver_case(args.device, "far", sleep=True),
    }
    if not args.no_glass:
        cases["glass demo, contact NONE"] = _glass_case(args.device, "NONE")
        cases["glass demo, multires"] = _glass_case(args.device, "MULTIRES")
    for c in cases.values():  # warm-up: compile, capture
        for _ in range(2):
            c[0]()
    times = defaultdict(list)
    last = {}
    for _ in range(args.repeats):
        for name, c in cases.items():
            for _ in range(args.frames):
                t = time.perf_counter()
                last[name] = c[0]()
                times[name].append(time.perf_counter() - t)
    rows = []
    ref = float(np.median(times["none (no objects)"]))
    for name, c in cases.items():
        ms = float(np.median(times[name]))
        out = last[name]
        rows.append(dict(case=name, ms_median=round(ms * 1e3, 3), x_solver_frame=round(ms / ref, 3),
                         **{k: out.get(k) for k in ("objects_near", "triangles_frame", "triangles_tested",
                                                    "features_listed", "ops_run", "contact_ops_run")}))
        print(json.dumps(rows[-1]), flush=True)
    if not args.no_glass:
        g0, g1 = (float(np.median(times[k])) for k in ("glass demo, contact NONE", "glass demo, multires"))
        print(json.dumps(dict(glass_contact_over_none=round(g1 / g0, 3))))
    t0, t1 = float(np.median(times["none (no objects)"])), float(np.median(times["touch (sphere, 2 mm)"]))
    print(json.dumps(dict(touch_over_none=round(t1 / t0, 3))))
    prof = None
    if args.profile and not wp.get_device(args.device).is_cuda:
        prof = {k: profile(*cases[k][:3]) for k in ("touch (sphere, 2 mm)", "none (no objects)")}
        print(json.dumps(prof))
    dev = device_name(args.device if args.device != "cuda" else "cuda:0")
    (ROOT / "docs" / "benchmarks" / f"activity_frame_{args.device.split(':')[0]}.json").write_text(
        json.dumps(dict(device=dev, frames=args.frames, repeats=args.repeats, rows=rows, profile=prof), indent=1))


if __name__ == "__main__":
    main()
