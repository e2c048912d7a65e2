"""Hand-frames per second of batched worlds on the HOI grasps (issue 15), both penetration measures.

Each world holds one HOI scene's generated grasp (docs/hoi.md: the hand at the ``grasp`` keyframe,
the object where the scene puts it): W copies of one scene in one :class:`~physhand_mj.batch.BatchedHands`,
set up as ``physhand rollout LIST --batch W`` sets up a batch (the rest placement, 20 settling frames
without contact, the objects placed), then the bones held at the keyframe (Table 2's setting) while
the contact resolves the grasp's 2.5-3.8 mm initial penetration: ``--frames`` 5 ms frames timed
after 2 warm-up frames (compilation, recording and graph capture excluded), one host sync per
frame (``--modes step,submit``: also pipelined by ``BatchedHands.submit``, the modes alternated
block by block ``--repeats`` times); the MuJoCo step is not part of it (the poses are the
keyframe's). At the end, per world: skin
samples inside the object (order 5) and object points inside the skin, and the two measures the
contact does not share (skin samples on the denser order-9 lattice, the object's check points
inside the skin); the worst world is reported.

    python benchmarks/batch_hoi.py [--device cpu|cuda] [--scenes box,apple] [--worlds 1,16,64] [--frames 10]
                                   [--config '{"feature_winding": false}'] [--profile] [--host-split]
                                   [--modes step,submit] [--repeats 3]
    python benchmarks/batch_hoi.py --plot [JSON [PNG]]   (docs/images/batch_hoi_1024.png from a run's JSON)
    python benchmarks/batch_hoi.py --curves [JSON] (docs/images/batch_hoi_curves.png: hand-frames/s against W)

Writes docs/benchmarks/batch_hoi_<device>.json (or --out) after every row, ``complete`` true at the
end (rows: scene, worlds, ms per frame, hand-frames/s, setup s, the worst world's measures, and the
RuntimeWarnings the row's batch gave, e.g. a full patch pool).
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))


def plot(src: Path, out: Path) -> Path:
    """Bars of hand-frames per second per HOI grasp from one batch_hoi JSON (one world count), the
    10,000 target drawn, each bar labelled with its worst world's four measures (inside counts);
    rows timed both ways (``--modes step,submit``) get a pale bar for ``step`` beside ``submit``'s."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = json.loads(src.read_text())
    # (rows timed by submit, with or without step beside it: pale step bars where a row has them)
    both = all("hand_frames_per_s_submit" in r for r in d["rows"]) and any("hand_frames_per_s_step" in r
                                                                          for r in d["rows"])
    key = "hand_frames_per_s_submit" if both else "hand_frames_per_s"  # (a run's own: its first mode's)
    rows = sorted(d["rows"], key=lambda r: -r[key])
    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    hz = [r[key] for r in rows]
    x = np.arange(len(rows), dtype=float)
    colors = ["tab:green" if h >= 10_000 else "tab:orange" for h in hz]
    if both:
        step = [r.get("hand_frames_per_s_step", 0.0) for r in rows]  # (0: a row timed by submit only)
        ax.bar(x - 0.2, step, 0.4, color=["tab:green" if h >= 10_000 else "tab:orange" for h in step], alpha=0.4,
               label="step (a frame and its report at a time)")
        ax.bar(x + 0.2, hz, 0.4, color=colors, label="submit (pipelined)")
        ax.legend(fontsize=7, loc="upper right")
    else:
        ax.bar(x, hz, color=colors)
    ax.set_xticks(x, [r["scene"] for r in rows])
    for i, r in enumerate(rows):
        inside = [r.get(k) for k in ("penetration_count_max", "order9_count_max", "object_in_skin_count_max",
                                     "check_count_max")]
        ax.text(x[i] + (0.2 if both else 0), hz[i] * 1.01, f"{int(hz[i] + 0.5):,}", ha="center",
                fontsize=7 if both else 8)
        alone = both and "hand_frames_per_s_step" not in r  # (one bar: the label on it)
        ax.text(x[i] + (0.2 if alone else 0.0), 300,
                "inside:\n" + ("/" if both else " / ").join("-" if v is None else str(v) for v in inside),
                ha="center", fontsize=6.5 if not alone else 5.5, color="white")
    ax.axhline(10_000, color="0.3", lw=0.8, ls=":")
    if both:
        ax.text(-0.5, 10_000 * 0.93, "target (H100)", fontsize=7, color="0.3", ha="left", va="top")
    else:
        ax.text(len(rows) - 0.5, 10_000 * 1.02, "target (H100)", fontsize=7, color="0.3", ha="right")
    ax.tick_params(axis="x", labelsize=8, labelrotation=20)
    dev = "H100" if "H100" in d["device"] else d["device"]
    w = rows[0]["worlds"] if rows else 0
    ax.set(ylabel="hand-frames per second (5 ms frames)",
           title=f"HOI grasps, {w} worlds in one batch ({dev}); inside counts: order 5 / order 9 / object / check points")
    ax.title.set_fontsize(8)
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def plot_curves(src: Path, out: Path) -> Path:
    """Hand-frames per second against W, one line per HOI grasp, from one batch_hoi JSON of several
    world counts (issue 15's curves); the 10,000 target drawn; a row with any world inside by any of
    the four measures is marked with a red ring; rows marked ``superseded`` (re-run since) are left out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = json.loads(src.read_text())
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    scenes = list(dict.fromkeys(r["scene"] for r in d["rows"]))
    for scene in scenes:
        rows = sorted((r for r in d["rows"] if r["scene"] == scene and not r.get("superseded")),
                      key=lambda r: r["worlds"])
        w, hz = [r["worlds"] for r in rows], [r["hand_frames_per_s"] for r in rows]
        (line,) = ax.plot(w, hz, "o-", ms=3.5, label=scene)
        for r in rows:
            if any(r.get(k) for k in ("penetration_count_max", "order9_count_max", "object_in_skin_count_max",
                                       "check_count_max")):
                ax.plot(r["worlds"], r["hand_frames_per_s"], "o", ms=10, mfc="none", mec="tab:red")
    ax.axhline(10_000, color="0.3", lw=0.8, ls=":")
    ax.text(1, 10_000 * 1.06, "target (H100): 10,000", fontsize=7, color="0.3")
    ax.set(xscale="log", yscale="log", xlabel="worlds W in one batch", ylabel="hand-frames per second (5 ms frames)")
    ax.set_xticks([1, 16, 64, 256, 1024, 4096], ["1", "16", "64", "256", "1,024", "4,096"])
    dev = "H100" if "H100" in d["device"] else d["device"]
    ax.set_title(f"HOI grasps, multires contact, Config() as shipped ({dev}); red ring: a world inside", fontsize=8)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def host_split(hands, pos, quat, op, oq, frames: int) -> dict:
    """ms per frame of BatchedHands.step's parts, each timed apart: the object and bone poses in, the
    solver's step (its graph, its one sync and its reports), the per-world report (frame_worlds);
    and the solver step's Python functions with the most own time (cProfile, one more frame each)."""
    import cProfile
    import pstats

    parts = dict(poses=0.0, solver_step=0.0, frame_worlds=0.0)
    for _ in range(frames):
        t0 = time.perf_counter()
        hands.set_object_poses(op, oq)
        hands.solver.set_body_poses(hands.state, (pos + hands.offsets[:, None]).reshape(-1, 3), quat.reshape(-1, 4))
        t1 = time.perf_counter()
        hands.solver.step(hands.state)
        t2 = time.perf_counter()
        hands.frame_worlds()
        t3 = time.perf_counter()
        parts["poses"] += t1 - t0
        parts["solver_step"] += t2 - t1
        parts["frame_worlds"] += t3 - t2
    out = {k: round(v / frames * 1e3, 3) for k, v in parts.items()}
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(frames):
        hands.step(pos, quat, op, oq)
    prof.disable()
    st = pstats.Stats(prof)
    top = sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:15]  # (own time)
    out["top_own_ms"] = {f"{Path(k[0]).name}:{k[1]}:{k[2]}": round(v[2] / frames * 1e3, 3) for k, v in top}
    return out


def measure_split(hands, calls: int = 3) -> dict:
    """``hands.penetration()`` ``calls`` times: its wall ms a call and the GPU ms a call of each kernel,
    memset and copy (Warp's timing, cuda_filter TIMING_ALL), the top 16."""
    from collections import defaultdict

    import warp as wp

    hands.penetration()  # (its reuse memory made, every point asked once)
    wp.synchronize()
    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    t = time.perf_counter()
    for _ in range(calls):
        hands.penetration()
    wp.synchronize()
    wall = (time.perf_counter() - t) / calls * 1e3
    agg = defaultdict(float)
    for r in wp.timing_end():
        agg[r.name] += r.elapsed
    top = sorted(agg.items(), key=lambda kv: -kv[1])[:16]
    return dict(wall_ms=round(wall, 2), gpu_ms={k: round(v / calls, 3) for k, v in top},
                gpu_all_ms=round(sum(agg.values()) / calls, 3))


def _laps(into: dict, tag: str):
    """A function lap(name): the wall time (s) since the last lap (or since made) into ``into[name]``,
    printed to stderr at once, so a run cut by its time limit shows where its time went."""
    last = [time.perf_counter()]

    def lap(name: str) -> None:
        now = time.perf_counter()
        into[name] = round(now - last[0], 2)
        last[0] = now
        print(f"{tag} {name}: {into[name]} s", file=sys.stderr, flush=True)

    return lap


def main() -> None:
    if "--curves" in sys.argv[1:]:  # python benchmarks/batch_hoi.py --curves [JSON]
        args = [a for a in sys.argv[1:] if a != "--curves"]
        src = Path(args[0]) if args else ROOT / "docs" / "benchmarks" / "batch_hoi_cuda_default.json"
        print(plot_curves(src, ROOT / "docs" / "images" / "batch_hoi_curves.png").relative_to(ROOT))
        return
    if "--plot" in sys.argv[1:]:  # python benchmarks/batch_hoi.py --plot [JSON]
        args = [a for a in sys.argv[1:] if a != "--plot"]
        src = Path(args[0]) if args else ROOT / "docs" / "benchmarks" / "batch_hoi_cuda_1024.json"
        png = Path(args[1]).resolve() if len(args) > 1 else ROOT / "docs" / "images" / "batch_hoi_1024.png"
        print(plot(src, png).relative_to(ROOT))
        return
    import warp as wp

    import physhand_mj as ph
    from physhand_mj.batch import BatchedHands
    from physhand_mj.batch_rollout import _Run
    from physhand_mj.bench import device_name
    from physhand_mj.coupling import rest_placement
    from batch_throughput import mode_rows  # (benchmarks/ is on sys.path)

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--scenes", default="box,apple", help="HOI scenes (hoi_<name>), comma-separated")
    p.add_argument("--worlds", default="1,2,4", help="comma-separated world counts")
    p.add_argument("--frames", type=int, default=10, help="timed 5 ms frames per world count")
    p.add_argument("--config", default="{}", help="Config options as JSON (any group's keys flat: Config.from_dict)")
    p.add_argument("--profile", action="store_true", help="CUDA: the per-kernel GPU time of each frame (top 24)")
    p.add_argument("--modes", default="step",
                   help="how frames are run, comma-separated, alternated block by block: step "
                        "(BatchedHands.step) and/or submit (BatchedHands.submit, pipelined)")
    p.add_argument("--repeats", type=int, default=1, help="timed blocks of --frames frames per mode")
    p.add_argument("--host-split", action="store_true",
                   help="time the frame's parts apart (poses in, solver step, per-world report) and profile the "
                        "solver step's host side (top functions by own time)")
    p.add_argument("--lineinfo", action="store_true",
                   help="build the decision-point kernels with line info (Nsight Compute's source view; "
                        "aot_cache.decision_modules_with_lineinfo)")
    p.add_argument("--skip-margin", type=float, default=None,
                   help="physhand_mj.contact.metrics.SKIP_MARGIN (m) for the run: the skin measure's corner bound (0: off)")
    p.add_argument("--profile-measure", action="store_true",
                   help="CUDA: the GPU time of BatchedHands.penetration() (both measures, as a rollout's log takes "
                        "them every frame) kernel by kernel, and its wall time, over 3 calls")
    p.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/batch_hoi_<device>.json)")
    a = p.parse_args()
    extra = json.loads(a.config)
    if a.lineinfo:
        from aot_cache import decision_modules_with_lineinfo

        decision_modules_with_lineinfo()
    if a.skip_margin is not None:
        from physhand_mj.contact import metrics

        metrics.SKIP_MARGIN = a.skip_margin
    wp.init()
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    out_path = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"batch_hoi_{a.device.split(':')[0]}.json"

    def save(rows, complete: bool):  # after every row: a run cut by a time limit keeps the rows it made
        out_path.parent.mkdir(parents=True, exist_ok=True)
        out_path.write_text(json.dumps(dict(device=dev, frames=a.frames, config=extra, complete=complete,
                                            command="python benchmarks/batch_hoi.py "
                                            + " ".join(sys.argv[1:]),
                                            rows=rows), indent=1))

    asset = ph.load_asset()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in a.scenes.split(","):
            run = _Run(0, ph.scene_path(f"hoi_{scene}"), "grasp", Path(tmp), asset)
            import mujoco

            mujoco.mj_kinematics(run.model, run.data)
            bone_pos, bone_quat = run.bone_poses()
            obj_pos, obj_quat = run.object_poses()
            place = rest_placement(asset, bone_pos[0], bone_quat[0])
            for w in [int(s) for s in a.worlds.split(",")]:
                # the rollout's Config (rollout_config) without its per-substep metrics (a log's, not timed here)
                cfg = ph.Config.from_dict(dict(frame_dt=float(run.model.opt.timestep), substeps=10, device=a.device, **extra))
                with warnings.catch_warnings(record=True) as said:  # the row keeps what its batch warned about
                    warnings.simplefilter("always")
                    t0 = time.perf_counter()
                    hands = BatchedHands(asset, w, cfg, np.tile(place[0], (w, 1)), np.tile(place[1], (w, 1)),
                                         objects=run.specs, spacing=1.0)
                    setup_s = time.perf_counter() - t0
                    phase_s = {}  # wall time of the row's untimed parts (a run cut by a time limit says where)
                    lap = _laps(phase_s, f"[{scene} W={w}]")
                    pos, quat = np.tile(bone_pos, (w, 1, 1)), np.tile(bone_quat, (w, 1, 1))
                    hands.settle(pos, quat)
                    lap("settle")
                    op, oq = np.tile(obj_pos, (w, 1, 1)), np.tile(obj_quat, (w, 1, 1))
                    hands.set_object_poses(op, oq)
                    for _ in range(2):
                        hands.step(pos, quat, op, oq)
                    lap("warmup (compile, record, capture)")
                    timing, out = mode_rows(hands, lambda k: [(pos, quat, op, oq)] * a.frames, w,
                                            a.modes.split(","), a.repeats)
                    ms = timing["ms_per_frame"]
                    lap("timed frames")
                    pen = hands.penetration()
                    lap("order 5 and object points")
                    print(f"[{scene} W={w}] {w / ms * 1e3:.1f} hand-frames/s; worst world inside: order 5 "
                          f"{max(r['penetration_count'] for r in pen)}, object points "
                          f"{max(r['object_in_skin_count'] for r in pen)}", file=sys.stderr, flush=True)
                    row = dict(scene=scene, worlds=w, **timing, setup_s=round(setup_s, 2),
                               features_listed=out.get("features_listed"),
                               triangles_tested=out.get("triangles_tested"),
                               penetration_count_max=max(r["penetration_count"] for r in pen),
                               penetration_max_um=round(max(r["penetration_max_um"] for r in pen), 2),
                               object_in_skin_count_max=max(r["object_in_skin_count"] for r in pen),
                               object_in_skin_max_um=round(max(r["object_in_skin_max_um"] for r in pen), 2),
                               finite=bool(np.isfinite(hands.state.x.numpy()).all()))
                    if hands.solver.contact is not None:  # measures the contact does not use: the order-9 lattice,
                        # and the denser object check points inside the closed skin (worst world)
                        contact, failed = hands.solver.contact, None
                        try:
                            dense = contact.measure_worlds(hands.state, order=9, check=True)
                            row.update(check_count_max=int(dense[:, 3].max()),
                                       check_max_um=round(float(dense[:, 5].max()) * 1e6, 2))
                        except RuntimeError as e:  # a measure that does not fit the GPU even in pieces
                            failed = str(e)[:200]
                        if failed:  # (outside the handler: its traceback would keep the failed arrays alive)
                            print(f"[{scene} W={w}] no check points: {failed[:120]}", file=sys.stderr, flush=True)
                            row["check_skipped"] = failed
                            contact.measures.forget()  # (re-made on use: every point asked again once)
                            gc.collect()
                            dense = contact.measure_worlds(hands.state, order=9, objects_side=False)
                        row.update(order9_count_max=int(dense[:, 0].max()), order9_max_um=round(float(dense[:, 2].max()) * 1e6, 2))
                        lap("order 9 and check points")
                    row["phases_s"] = phase_s
                    if a.host_split:  # the frame's host parts, timed apart (the solver's step syncs once)
                        row["host_split_ms"] = host_split(hands, pos, quat, op, oq, a.frames)
                    if a.profile_measure and hands.solver.device.is_cuda:
                        row["measure_split"] = measure_split(hands)
                    if a.profile and hands.solver.device.is_cuda:
                        from batch_throughput import kernel_split

                        n_launch = {}
                        row["kernels_ms_per_frame"] = kernel_split(hands, lambda f: (pos, quat), (op, oq), a.frames,
                                                                   n_launch)
                        row["kernel_launches_per_frame"] = n_launch
                for m in said:
                    warnings.warn_explicit(m.message, m.category, m.filename, m.lineno)  # still on stderr
                # what the run warned about (a full patch pool: points not pushed) goes with its row
                row["warnings"] = sorted({str(m.message)[:300] for m in said if issubclass(m.category, RuntimeWarning)})
                rows.append(row)
                print(json.dumps(row), flush=True)
                save(rows, complete=False)
                # the batch's arrays go before the next one's (W = 4096: ~7 GB each; a local `contact` had kept
                # the last batch's contact buffers alive: two grasps at W = 4,096 in one run ran out of memory)
                hands.close()
                contact = None
                del hands, out, pen
                gc.collect()
    save(rows, complete=True)
    print(json.dumps(dict(device=dev, out=str(out_path))))


if __name__ == "__main__":
    main()
