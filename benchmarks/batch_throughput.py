"""Hand-frames per second of batched worlds (physhand_mj/batch.py), without or with contact.

W copies of the embedded hand in one solver, open pose, each world's index finger bending at its own
rate; ``--frames`` 5 ms frames timed after ``--warmup`` frames (2: compilation, recording and graph
capture excluded; the skin still settles from its rest shape under gravity for ~100-200 frames, which
with self-collision asks for more queries than a settled hand's), one host sync per frame; ``--modes step,submit``: also pipelined
(``BatchedHands.submit``: the next frame's poses checked while the GPU runs this one), the modes
alternated block by block ``--repeats`` times. ``--objects``: each world holds a sphere (r = 2 cm)
pressing the back of its hand 2 mm (the worlds then lie 1 m apart; the contact is world-indexed).
Memory per world: the bytes of the replicated model's and state's device arrays divided by W.

    python benchmarks/batch_throughput.py [--device cpu|cuda] [--worlds 1,2,4,8] [--frames 5] [--objects]
                                          [--config '{"jacobi_gather": true}'] [--tag NAME]
                                          [--modes step,submit] [--repeats 3] [--profile] [--host-profile]
    python benchmarks/batch_throughput.py --plot     # docs/images/batch_throughput.png from the JSONs

Writes docs/benchmarks/batch_throughput_<device>[_objects][_<tag>].json; each row also gives the
batch's setup time (``BatchedHands(...)``: one world's model tiled W times, the upload, the solver; s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]


def _nbytes(obj) -> int:
    import dataclasses

    import warp as wp

    total = 0
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, wp.array):
            total += v.capacity
        elif isinstance(v, (list, tuple)):  # e.g. Model.gather_off: one array per Jacobi group
            total += sum(a.capacity for a in v if isinstance(a, wp.array))
    return total


def plot(out: Path) -> Path:
    """Hand-frames per second against worlds, every batch_throughput_*.json in docs/benchmarks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10.0, 4.6))
    ax.set_prop_cycle(color=plt.cm.tab20.colors)  # (more curves than tab10 has colours)
    for f in sorted((ROOT / "docs" / "benchmarks").glob("batch_throughput_*.json")):
        if f.stem.endswith("_origin"):  # an older run kept for the record (docs/scale.md), not plotted
            continue
        d = json.loads(f.read_text())
        if "contact" not in d or len(d["rows"]) < 2:  # (a collation, or one W: a point, not a curve)
            continue
        w = [r["worlds"] for r in d["rows"]]
        hz = [r["hand_frames_per_s"] for r in d["rows"]]
        dev = "H100" if "H100" in d["device"] else ("CPU" if d["device"].startswith("cpu") else d["device"])
        variant = ", ".join(f"{k}={v}" for k, v in (d.get("config") or {}).items())
        tag = f.stem.removeprefix("batch_throughput_").split("_", 1)[1:]  # the file's --tag (after cuda/cpu)
        tag = tag[0].removeprefix("objects").strip("_") if tag else ""
        variant = ", ".join(v for v in (variant, tag) if v)
        label = f"{dev}, {'a sphere pressing each hand' if d['contact'] else 'no contact'}"
        ax.plot(w, hz, "o-" if d["contact"] else "s--", label=label + (f" ({variant})" if variant else ""))
        if all("hand_frames_per_s_submit" in r for r in d["rows"]):  # (--modes step,submit: the pipelined curve too)
            ax.plot(w, [r["hand_frames_per_s_submit"] for r in d["rows"]], "^-", lw=2,
                    label=label + f" ({', '.join(v for v in (variant, 'submit') if v)})")
    ax.axhline(10_000, color="0.5", lw=0.8, ls=":")
    ax.axhline(50_000, color="0.5", lw=0.8, ls=":")
    ax.text(1, 10_000 * 1.08, "target with contact (H100)", fontsize=7, color="0.4")
    ax.text(1, 50_000 * 1.08, "target without contact (H100)", fontsize=7, color="0.4")
    ax.set(xscale="log", yscale="log", xlabel="worlds W (hands in one solver step)",
           ylabel="hand-frames per second (5 ms frames)", title="BatchedHands throughput")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    return out


def hand_only_setup():
    """The embedded asset and the hand_only scene these benchmarks bend: (asset, model, data, the
    asset's bone ids in the model, the mount pose)."""
    import physhand_mj as ph
    from physhand_mj.hand_mjcf import body_ids, mount_pose, open_hand_scene

    asset = ph.load_asset()
    _, model, data = open_hand_scene("hand_only", "open")
    return asset, model, data, body_ids(model, asset.body_names), mount_pose(model, data)


def bending_poses(model, data, ids, worlds: int):
    """``poses(f)``: the bone poses (positions, quaternions) of frame ``f`` for ``worlds`` worlds of the
    hand_only scene, open, world k bending its index finger at rate 1 + k % 7 (7 distinct poses a
    frame; MuJoCo's kinematics on the host)."""
    from physhand_mj.hand_mjcf import bone_poses_at

    q0 = model.key("open").qpos.copy()
    adr = model.jnt_qposadr[model.joint("mcp2_flexion_r").id]

    def poses(f):
        ps = []
        for r in range(min(worlds, 7)):
            q = q0.copy()
            q[adr] += 0.3 * np.sin(0.05 * f * (1 + r))
            ps.append(bone_poses_at(model, data, q, ids))
        pick = np.arange(worlds) % 7
        return np.stack([x[0] for x in ps])[pick], np.stack([x[1] for x in ps])[pick]

    return poses


def kernel_split(hands, poses, ball, frames: int, counts: dict | None = None, start: int = 100) -> dict:
    """GPU ms per frame of every kernel (memsets and copies as they come), graphs off: ``frames``
    frames after one to record the ungraphed frame (``poses(start)``, then on), timed by the driver (``wp.timing_begin``);
    ``counts`` (a dict) gets the top kernels' launches per frame."""
    from collections import defaultdict

    import warp as wp

    solver = hands.solver
    saved = solver.config
    solver.config = dataclasses.replace(saved, cuda_graph=False)
    solver._graphs.clear()
    try:
        hands.step(*poses(start), *ball)
        wp.synchronize()
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        for f in range(frames):
            hands.step(*poses(start + 1 + f), *ball)
        wp.synchronize()
        agg = defaultdict(float)
        num = defaultdict(int)
        for r in wp.timing_end():
            agg[r.name] += r.elapsed
            num[r.name] += 1
    finally:
        solver.config = saved
        solver._graphs.clear()
    top = sorted(agg.items(), key=lambda kv: -kv[1])[:24]
    if counts is not None:
        counts.update({k: round(num[k] / frames, 2) for k, _ in top})
    return {k: round(v / frames, 3) for k, v in top} | {"all": round(sum(agg.values()) / frames, 3)}


def timed_frames(hands, frames: list, mode: str = "step"):
    """ms per frame of ``frames`` (``BatchedHands.step``'s argument tuples, one a frame) and the last
    frame's report: ``mode`` "step", a frame and its report at a time, or "submit", pipelined
    (``BatchedHands.submit`` each, then ``wait``: the last frame's end is inside the time)."""
    t = time.perf_counter()
    if mode == "step":
        for args in frames:
            out = hands.step(*args)
    elif mode == "submit":
        for args in frames:
            hands.submit(*args)
        out = hands.wait()
    else:
        raise ValueError(f"mode must be 'step' or 'submit', got {mode!r}")
    return (time.perf_counter() - t) / len(frames) * 1e3, out


def host_profile(hands, frames: list, top: int = 16) -> list[dict]:
    """The host's time in ``frames`` pipelined frames (``timed_frames`` "submit") by function
    (cProfile): per frame each function's own time and its time with its callees (ms), the ``top``
    by own time. The wait for the GPU shows as Warp's synchronize; the rest is host work, on the
    critical path where it comes between a frame's end and the next frame's launch."""
    import cProfile
    import pstats

    pr = cProfile.Profile()
    pr.enable()
    timed_frames(hands, frames, "submit")
    pr.disable()
    rows = [(f"{Path(f).name}:{line}({name})", tt, ct)
            for (f, line, name), (_, _, tt, ct, _) in pstats.Stats(pr).stats.items()]
    rows.sort(key=lambda r: -r[1])
    n = len(frames)
    return [dict(where=w, own_ms=round(t / n * 1e3, 3), with_callees_ms=round(c / n * 1e3, 3)) for w, t, c in rows[:top]]


def mode_rows(hands, frames_of, worlds: int, modes: list, repeats: int):
    """Each mode timed ``repeats`` times, the modes alternated block by block and their order
    reversed every other round (A B, B A, ...: a grasp's first frames after the warm-up still
    resolve its initial penetration and cost more, which no one mode should take alone;
    ``frames_of(k)``: the k-th block's frames); per mode its ms per frame (every block) and
    hand-frames/s (the median's), the first mode's also as the row's ``ms_per_frame`` /
    ``hand_frames_per_s``; and the last report."""
    ms = {m: [] for m in modes}
    k = 0
    for r in range(repeats):
        for m in (modes if r % 2 == 0 else modes[::-1]):
            t, out = timed_frames(hands, frames_of(k), m)
            ms[m].append(round(t, 3))
            k += 1
    row = {}
    for m in modes:
        med = float(np.median(ms[m]))
        row[f"ms_per_frame_{m}"] = ms[m]
        row[f"hand_frames_per_s_{m}"] = round(worlds / med * 1e3, 1)
    first = float(np.median(ms[modes[0]]))
    row.update(ms_per_frame=round(first, 3), hand_frames_per_s=round(worlds / first * 1e3, 1))
    return row, out


def main() -> None:
    if "--plot" in sys.argv[1:]:
        print(plot(ROOT / "docs" / "images" / "batch_throughput.png").relative_to(ROOT))
        return
    import warp as wp

    from physhand_mj.batch import BatchedHands
    from physhand_mj.bench import device_name
    from physhand_mj.types import Config

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--worlds", default="1,2,4,8", help="comma-separated world counts")
    p.add_argument("--frames", type=int, default=5, help="timed 5 ms frames per world count")
    p.add_argument("--objects", action="store_true",
                   help="each world holds a sphere (radius 2 cm) pressing the back of its hand 2 mm")
    p.add_argument("--config", default="{}", help="Config, Tuning or Execution fields as JSON (flat), e.g. '{\"self_collision\": true, \"self_margin\": 1.5e-3}'")
    p.add_argument("--tag", default="", help="suffix of the JSON's name (a variant's results beside the default's)")
    p.add_argument("--profile", action="store_true",
                   help="CUDA: also the per-kernel GPU time of each W's frame (graphs off, wp.timing_begin), top 24")
    p.add_argument("--host-profile", action="store_true",
                   help="also the host's time by function in --frames pipelined frames (cProfile), top 16")
    p.add_argument("--modes", default="step",
                   help="how frames are run, comma-separated, alternated block by block: step "
                        "(BatchedHands.step) and/or submit (BatchedHands.submit, pipelined)")
    p.add_argument("--warmup", type=int, default=2,
                   help="frames run before the timing (at least 2: compilation, recording, graph capture)")
    p.add_argument("--repeats", type=int, default=1, help="timed blocks of --frames frames per mode")
    p.add_argument("--fused-block", type=int, default=0,
                   help="with Config.execution.fused_substep: threads per world's block (solver/fused.py BLOCK_DIM)")
    a = p.parse_args()
    extra = json.loads(a.config)
    if a.fused_block:
        from physhand_mj.solver import fused

        fused.BLOCK_DIM = a.fused_block
    wp.init()
    asset, model, data, ids, mount = hand_only_setup()
    rows = []
    from physhand_mj.types import GeomType

    for w in [int(s) for s in a.worlds.split(",")]:
        objects = [dict(gtype=GeomType.SPHERE, size=(0.02, 0.0, 0.0), name="ball")] if a.objects else ()
        t_setup = time.perf_counter()
        hands = BatchedHands(asset, w, Config.from_dict({"device": a.device, "sleep_speed": 0.0, **extra}), *mount, objects=objects)
        setup_s = time.perf_counter() - t_setup
        ball = ()
        if a.objects:  # 2 mm into the back of the hand (its highest skin point, open pose)
            skin = hands.skin(0)
            top = skin[np.argmax(skin[:, 2])].astype(float)
            ball = (np.tile(top + [0.0, 0.0, 0.02 - 0.002], (w, 1))[:, None], np.tile([1.0, 0.0, 0.0, 0.0], (w, 1))[:, None])

        poses = bending_poses(model, data, ids, w)

        warm = max(2, a.warmup)
        for f in tqdm(range(warm), desc=f"W={w} warm-up", unit="frame", disable=warm <= 2):
            out = hands.step(*poses(f), *ball)
        modes = a.modes.split(",")
        # (bone poses from MuJoCo, made before the timing)
        inputs = [poses(f) + tuple(ball) for f in range(warm, warm + a.frames * a.repeats * len(modes))]
        timing, out = mode_rows(hands, lambda k: inputs[k * a.frames:(k + 1) * a.frames], w, modes, a.repeats)
        mem = (_nbytes(hands.solver.model) + _nbytes(hands.state)) / w
        rows.append(dict(worlds=w, **timing, mb_per_world=round(mem / 2**20, 2),
                         vertices=hands.solver.model.n_vertices, setup_s=round(setup_s, 2)))
        if a.host_profile:  # where the host's time goes in pipelined frames, function by function
            rows[-1]["host_ms_per_frame"] = host_profile(hands, [poses(warm + 200 + f) + tuple(ball) for f in range(a.frames)])
        if a.profile and hands.solver.device.is_cuda:  # where the frame's GPU time goes, kernel by kernel
            # (from frame 100, or where the timing ended if later: a settled hand stays settled)
            rows[-1]["kernels_ms_per_frame"] = kernel_split(hands, poses, ball, a.frames, start=max(100, warm + len(inputs)))
        if a.objects:  # the contact did work in every world, and nothing stayed inside
            pen = hands.penetration()
            rows[-1].update(triangles_tested=out.get("triangles_tested"),
                            penetration_count_max=max(p["penetration_count"] for p in pen),
                            object_in_skin_count_max=max(p["object_in_skin_count"] for p in pen))
        print(json.dumps(rows[-1]), flush=True)
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    tag = a.device.split(":")[0] + ("_objects" if a.objects else "") + (f"_{a.tag}" if a.tag else "")
    out = ROOT / "docs" / "benchmarks" / f"batch_throughput_{tag}.json"
    out.write_text(json.dumps(dict(device=dev, frames=a.frames, warmup=max(2, a.warmup), contact=bool(a.objects), config=extra,
                                   fused_block=a.fused_block or None,
                                   command="python benchmarks/batch_throughput.py " + " ".join(sys.argv[1:]),
                                   rows=rows), indent=1))
    print(json.dumps(dict(device=dev, out=str(out.relative_to(ROOT)))))


if __name__ == "__main__":
    main()
