"""The ``physhand`` console script.

Each command that reports figures prints one JSON line on stdout; progress goes to stderr; bad input
exits non-zero with one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _demo(args) -> dict:
    """The default scene: the soft hand closes on a glass under position control (grasp_glass)."""
    import mujoco
    from tqdm import tqdm

    import physhand_mj as ph
    from physhand_mj import figures
    from physhand_mj.coupling import SoftHand
    from physhand_mj.render import write_png

    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if args.video:
        try:
            import imageio.v2 as imageio
        except ImportError as e:
            raise ImportError("--video needs the video extra: pip install -e '.[video]'") from e
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    renderer = _working_renderer(model, data, 960, 720)  # before any simulation (or kernel compilation)
    writer = None
    try:
        if args.video:
            writer = imageio.get_writer(out / "demo.mp4", fps=50, codec="libx264", quality=7, macro_block_size=8)
        t0 = time.perf_counter()
        # the scene closes the hand in ~0.2 s, its fingertips up to ~7 mm a 5 ms frame: the object feature
        # lists are sized for the frame margin (Config.tuning.feature_slack = contact_frame_margin), as a
        # scene that moves this fast should be (the warning says so otherwise; docs/contact.md)
        config = ph.Config(device=args.device)
        config.tuning.feature_slack = config.contact_frame_margin
        hand = SoftHand(model, data, config)
        setup_s = time.perf_counter() - t0
        camera = figures.contact_camera(hand.skin_vertices)
        vmax = None  # colour scale of the pressure heat map: each frame's 95th percentile
        for f in tqdm(range(args.frames), desc="demo", unit="frame", file=sys.stderr, disable=args.frames < 20):
            mujoco.mj_step(model, data)
            hand.step()
            if writer is not None and f % 2 == 1:
                writer.append_data(figures.render_contact_frame(renderer, model, data, hand, camera, vmax))
        png = write_png(figures.render_contact_frame(renderer, model, data, hand, camera, vmax), out / "demo.png")
    finally:
        renderer.close()
        if writer is not None:
            writer.close()
    m = hand.metrics()
    # per touched object also how near the bones are (negative: a bone that deep inside, where no skin can
    # be both outside the object and on its bone: the flesh between is squeezed flat; docs/quickstart.md)
    objects = {k: dict(contact_vertices=len(v["vertices"]), area_cm2=round(v["area_m2"] * 1e4, 2),
                       force_n=round(v["force_n"], 3), bone_clearance_mm=round(v["bone_clearance_mm"], 3),
                       bones_inside=v["bones_inside"])
               for k, v in hand.contacts()["objects"].items() if len(v["vertices"])}
    # the reference for inverted_tets: the same bone pose without the objects (settled from rest over
    # 20 frames, no contact; ~0.4 s on a CPU). The curled fingers' joint creases invert some tets by
    # themselves (docs/limitations.md); the rest are pressed inverted by the objects and recover when
    # they let go.
    free = SoftHand(model, data, ph.Config(device=args.device), object_geoms=[], writeback=False)
    free.step()
    return dict(command="demo", picture=str(png), video=str(out / "demo.mp4") if writer is not None else None,
                scene="grasp_glass", keyframe="approach", frames=args.frames,
                penetration_count=m["penetration_count"], penetration_max_um=round(m["penetration_max_um"], 3),
                penetration_avg_um=round(m["penetration_avg_um"], 3), ms_per_frame=round(m["ms_per_frame"], 2),
                finite=m["finite"], inverted_tets=m["inverted"],
                inverted_tets_without_contact=free.metrics()["inverted"], objects=objects,
                device=str(hand.solver.device), setup_s=round(setup_s, 2))


def _working_renderer(model, data, width: int, height: int):
    """``make_renderer``, and one frame rendered: some GL backends fail only when they first draw.
    RenderUnavailable in one line (the backend's own warnings, e.g. GLFW's "DISPLAY is missing",
    folded into it) where they cannot draw."""
    import os
    import warnings

    from physhand_mj.render import RenderUnavailable, make_renderer

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            renderer = make_renderer(model, width, height)
            try:
                renderer.update_scene(data)
                renderer.render()
            except Exception as e:
                renderer.close()
                raise RenderUnavailable(f"MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset')} cannot draw "
                                        f"offscreen: {e}") from e
        except RenderUnavailable as e:
            said = "; ".join(dict.fromkeys(" ".join(str(w.message).split()) for w in caught))
            raise RenderUnavailable(f"{e}; the backend warned: {said}" if said else str(e)) from None
    for w in caught:  # (a backend that works: its warnings as they were)
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return renderer


def _build_from_files(args) -> dict:
    """A user's skin + bone meshes (files named after MuJoCo bodies) posed by a MuJoCo model."""
    import mujoco
    import trimesh

    from physhand_mj.asset import save_asset
    from physhand_mj.build import build_from_meshes

    if args.bones is None or args.model is None:
        raise ValueError("--skin needs --bones DIR (one mesh per body, named BODY.stl/.obj/.ply) and --model XML")
    model = mujoco.MjModel.from_xml_path(str(args.model))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    bones, pose = {}, {}
    for f in sorted(Path(args.bones).iterdir()):
        if f.suffix.lower() not in (".stl", ".obj", ".ply"):
            continue
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f.stem)
        if bid < 0:
            raise ValueError(f"bone mesh {f.name} names no body of {args.model}")
        bones[f.stem] = trimesh.load(f, force="mesh")
        pose[f.stem] = (data.xpos[bid].copy(), data.xquat[bid].copy())
    if not bones:
        raise ValueError(f"no bone meshes (.stl/.obj/.ply) in {args.bones}")
    skin = trimesh.load(args.skin, force="mesh")
    asset = build_from_meshes(skin, bones, pose, skeleton_vertices=args.skeleton_vertices,
                              meta=dict(name=Path(args.skin).stem, source=str(args.skin)))
    save_asset(asset, args.out)
    return dict(command="build-hand", asset=str(args.out), **asset.summary())


def _build_hand(args) -> dict:
    import logging

    from physhand_mj.build import build_myohand

    logging.basicConfig(level=logging.WARNING)
    if args.skin is not None:
        return _build_from_files(args)
    asset = build_myohand(args.out, None if args.no_mjcf else args.mjcf,
                          skin_vertices=args.skin_vertices, skeleton_vertices=args.skeleton_vertices)
    return dict(command="build-hand", asset=str(args.out), mjcf=None if args.no_mjcf else str(args.mjcf),
                build_seconds=asset.meta.get("build_seconds"), hand_length_mm=round(asset.meta["hand_length_mm"], 1),
                **asset.summary())


def _bench_solver(args) -> dict:
    from physhand_mj.bench import bench_solver
    from physhand_mj.types import Scheme

    return bench_solver(device=args.device, frames=args.steps, resolution=args.resolution, asset_path=args.asset,
                        substeps=args.substeps, iterations=args.iterations, scheme=Scheme[args.scheme.upper()])


def _bench_cone(args) -> dict:
    from physhand_mj.bench import bench_cone
    from physhand_mj.types import Placement

    kw = {} if args.passes is None else dict(contact_passes=args.passes)
    if args.samples is not None:
        kw["multires_samples"] = args.samples
    if args.rounds is not None:
        kw["multires_rounds"] = args.rounds
    if args.placement is not None:
        kw["contact_placement"] = Placement[args.placement.upper()]
    summary, log = bench_cone(args.contact, args.device, args.steps, **kw)
    if args.log is not None:
        import csv

        args.log.parent.mkdir(parents=True, exist_ok=True)
        with open(args.log, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(log[0]))
            w.writeheader()
            w.writerows(log)
        summary["log"] = str(args.log)
    return summary


def _bench_accuracy(args) -> dict:
    from physhand_mj.bench import bench_accuracy

    workloads = args.workloads.split(",") if args.workloads else None
    return bench_accuracy(device=args.device, out=args.out, quick=args.quick, frames=args.frames,
                          repeats=args.repeats, workloads=workloads,
                          progress=lambda line: print(f"physhand bench accuracy: {line}", file=sys.stderr, flush=True))


def _view(args) -> dict:
    """MuJoCo's passive viewer on SCENE.xml with the soft skin updated live."""
    import os

    import mujoco

    import physhand_mj as ph

    path = _scene_arg(args.scene)
    if not path.is_file():
        raise FileNotFoundError(f"scene file not found: {path}{_bundled_hint()}")
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY") and sys.platform.startswith("linux"):
        raise ValueError("no display (DISPLAY is unset): the viewer needs a desktop session; "
                         "use `physhand demo` or SoftHand with mujoco.Renderer for pictures")
    import mujoco.viewer

    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    if args.keyframe is not None:
        kid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, args.keyframe)
        if kid < 0:
            raise ValueError(f"{path.name} has no keyframe '{args.keyframe}'")
        mujoco.mj_resetDataKeyframe(model, data, kid)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data)
    frames = 0
    with mujoco.viewer.launch_passive(model, data) as viewer:
        while viewer.is_running():
            mujoco.mj_step(model, data)
            hand.step()
            viewer.update_mesh(hand.skin_mesh_id)
            viewer.sync()
            frames += 1
    return dict(command="view", scene=str(path), frames=frames, **{k: hand.metrics()[k] for k in (
        "penetration_count", "penetration_max_um", "ms_per_frame")})


def _scene_arg(arg: str) -> Path:
    """A scene argument as a path: a path that exists wins; else a bundled scene's name (``hoi_apple``
    or ``hoi_apple.xml``, as ``physhand_mj.scene_path`` knows it); else the path as given."""
    from physhand_mj.hand_mjcf import SCENES_DIR

    path = Path(arg)
    if path.exists() or path.parent != Path(".") or path.suffix.lower() not in ("", ".xml"):
        return path
    bundled = SCENES_DIR / f"{path.stem}.xml"
    return bundled if bundled.is_file() else path


def _bundled_hint() -> str:
    """The not-found message's tail: the bundled scene names, which the scene argument also takes."""
    from physhand_mj.hand_mjcf import SCENES_DIR

    return f" (nor a bundled scene: {', '.join(sorted(p.stem for p in SCENES_DIR.glob('*.xml')))})"


def _check_device(args) -> None:
    """A command's ``--device``, checked before it loads anything: one line naming what is there."""
    device = getattr(args, "device", None)
    if device is None or getattr(args, "ray", None) is not None:  # (Warp's default; Ray: the cluster's devices)
        return
    import warp as wp

    wp.init()
    if str(device).startswith("cuda") and not wp.is_cuda_available():
        raise ValueError(f"--device {device}: no CUDA device is visible to Warp on this machine")
    try:
        wp.get_device(device)
    except (RuntimeError, ValueError) as e:
        raise ValueError(f"--device {device}: {e}; Warp's devices here: "
                         f"{', '.join(str(d) for d in wp.get_devices())}") from None


def _rollout(args):
    from physhand_mj.rollout import batch_targets, check_measure_every, rollout, rollout_batch

    kw = dict(steps=args.steps, substeps=args.substeps, contact=args.contact, device=args.device,
              measure_every=args.measure_every)
    config = {}
    if args.two_way:  # Config.two_way (the rollout's frame is the scene's time step, as it needs)
        config["two_way"] = True
    if args.self_collision:  # Config.self_collision (and the hand model's self proxies, through SoftHand)
        config["self_collision"] = True
    if config:
        kw["config"] = config
    src = _scene_arg(args.scene)
    if not src.exists():
        raise FileNotFoundError(f"scene file not found: {src}{_bundled_hint()}")
    check_measure_every(args.measure_every)
    if args.workers is not None and args.ray is None:
        raise ValueError("--workers needs --ray (the serial batch runs one rollout at a time)")
    if args.batch is not None and args.batch < 1:
        raise ValueError(f"--batch must be at least 1 (worlds per batch), got {args.batch}")
    single = src.suffix.lower() == ".xml" or not (src.is_dir() or src.is_file())
    if single and args.ray is None and args.batch is None:
        return rollout(src, args.keyframe, out=args.out, **kw)
    targets = [(src, args.keyframe)] if single else batch_targets(src, args.keyframe)

    def emit(row):
        print(json.dumps(row), flush=True)

    if args.ray is not None:  # one Ray task per rollout, or per batch of W (physhand_mj/distributed.py)
        from physhand_mj.distributed import rollout_ray

        rows = rollout_ray(targets, args.out, address=None if args.ray == "local" else args.ray,
                           num_workers=args.workers, emit=emit, batch=args.batch, **kw)
    elif args.batch is not None:  # W worlds per solver step (physhand_mj/batch_rollout.py)
        from physhand_mj.batch_rollout import rollout_batched

        rows = rollout_batched(targets, args.out, worlds=args.batch, emit=emit, **kw)
    else:
        rows = rollout_batch(targets, args.out, emit=emit, **kw)
    print(f"physhand rollout: {len(rows)} runs, table {args.out / 'summary.csv'}", file=sys.stderr)
    if any(r.get("interrupted") for r in rows):
        return 130
    return 1 if any("error" in r for r in rows) else None


def main(argv: list[str] | None = None) -> int:
    from physhand_mj.asset import DEFAULT_ASSET
    from physhand_mj.hand_mjcf import HAND_XML

    from physhand_mj import __version__

    parser = argparse.ArgumentParser(prog="physhand", description="PhysHand soft hand for MuJoCo")
    parser.add_argument("--version", action="version", version=f"physhand_mj {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="the soft hand closes on a glass; writes DIR/demo.png (and demo.mp4)")
    p.add_argument("--out", default="demo_out", help="output directory (default: demo_out)")
    p.add_argument("--video", action="store_true", help="also write DIR/demo.mp4 (needs the video extra)")
    p.add_argument("--frames", type=int, default=80, help="5 ms frames to simulate (count, default 80)")
    p.add_argument("--device", default=None, help="Warp device (default: Warp's, CUDA if present)")
    p.set_defaults(run=_demo)
    p = sub.add_parser("build-hand", help="regenerate the embedded MyoHand asset (needs the build extra)")
    p.add_argument("--out", type=Path, default=DEFAULT_ASSET, help="asset .npz path (default: the embedded one)")
    p.add_argument("--mjcf", type=Path, default=HAND_XML, help="hand MJCF path (default: mjcf/hand/myohand.xml)")
    p.add_argument("--no-mjcf", action="store_true", help="write the asset only")
    p.add_argument("--skin-vertices", type=int, default=5000, help="skin vertex target (count, default 5000)")
    p.add_argument("--skeleton-vertices", type=int, default=3300, help="bone vertex budget (count, default 3300)")
    p.add_argument("--skin", type=Path, help="other input: closed skin mesh file (metres, world frame of --model)")
    p.add_argument("--bones", type=Path, help="other input: folder of bone meshes named BODY.stl/.obj/.ply")
    p.add_argument("--model", type=Path, help="other input: MJCF whose bodies (at qpos0) carry the bones")
    p.set_defaults(run=_build_hand)
    p = sub.add_parser("view", help="MuJoCo's passive viewer with the soft skin updated live")
    p.add_argument("scene", help="scene MJCF that includes the hand (e.g. mjcf/scenes/grasp_glass.xml), or a "
                                 "bundled scene's name (grasp_glass)")
    p.add_argument("--keyframe", default=None, help="keyframe to start from (name)")
    p.set_defaults(run=_view)
    p = sub.add_parser("rollout", help="offline rollout of a scene keyframe with a per-substep penetration log")
    p.add_argument("scene", help="scene MJCF that includes the hand (or a bundled scene's name: hoi_apple), or a "
                                 "folder of scenes, or a list file (lines: SCENE.xml [KEYFRAME]) for a batch")
    p.add_argument("--keyframe", default=None, help="keyframe to start from (name; default: the scene's first; "
                                                    "a folder batch: all)")
    p.add_argument("--steps", type=int, default=36, help="5 ms frames to run (count, default 36)")
    p.add_argument("--substeps", type=int, default=10, help="substeps per 5 ms frame (count, default 10; fewer than 3 run as 3: "
                                                           "Config.max_substep, 2 ms)")
    p.add_argument("--contact", choices=["vertex", "opt", "multires"], default="multires",
                   help="decision-point strategy (default multires)")
    p.add_argument("--device", default=None, help="Warp device: cpu or cuda[:N] (default: Warp's, CUDA if present)")
    p.add_argument("--out", type=Path, default=Path("rollout_out"), help="output directory (default rollout_out)")
    p.add_argument("--measure-every", type=int, default=1, metavar="K",
                   help="the object-side measure (object points inside the skin, the log's object_in_skin cells) "
                        "every K-th frame (count, default 1: every frame; 0: the last frame only); the last frame "
                        "is always measured, so a run that ends has the same summary")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="run the batch's rollouts as Ray tasks: alone, on a local Ray; or on the cluster at ADDRESS "
                        "(auto, ray://HOST:10001); needs the ray extra (docs/scale.md)")
    p.add_argument("--workers", type=int, default=None,
                   help="with --ray: rollouts (with --batch: batches) at once (count; default: one per GPU, else one "
                        "per CPU)")
    p.add_argument("--batch", type=int, default=None, metavar="W",
                   help="run the list W worlds at a time in one solver step (count of worlds per batch); runs whose "
                        "scenes hold the same objects share a batch; with --ray: one Ray task per batch "
                        "(docs/scale.md)")
    p.add_argument("--self-collision", action="store_true",
                   help="skin self-collision (Config.self_collision, experimental): fingers, thumb and palm kept "
                        "out of each other's skin, MuJoCo keeping the parts' bones a flesh apart; the JSON line "
                        "then adds the skin's self-penetration by the independent measure (docs/self_collision.md)")
    p.add_argument("--two-way", action="store_true",
                   help="two-way coupling (Config.two_way, experimental): the skin's contact pushes and holds the "
                        "objects, with friction; DIR/forces.csv logs each object's force, torque and friction "
                        "per frame (with --batch: each frame's wrenches reach MuJoCo before its next step, so "
                        "MuJoCo's steps no longer overlap the solver's frames)")
    p.set_defaults(run=_rollout)
    bench = sub.add_parser("bench", help="timings (one JSON line)").add_subparsers(dest="bench", required=True)
    p = bench.add_parser("solver", help="XPBD frame time on the embedded hand, no contact")
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N] (default cpu)")
    p.add_argument("--steps", type=int, default=100, help="timed frames of 5 ms (count, default 100)")
    p.add_argument("--resolution", type=int, default=None,
                   help="skin vertex count (default: the embedded 5000; others are built once and cached)")
    p.add_argument("--asset", type=Path, default=None, help="time this asset .npz instead")
    p.add_argument("--substeps", type=int, default=10, help="substeps per 5 ms frame (count, default 10; fewer than 3 run as 3: "
                                                           "Config.max_substep, 2 ms)")
    p.add_argument("--iterations", type=int, default=1, help="constraint passes per substep (count, default 1)")
    p.add_argument("--scheme", choices=["jacobi", "colored"], default="jacobi", help="parallel scheme (default jacobi)")
    p.set_defaults(run=_bench_solver)
    p = bench.add_parser("cone", help="the paper's cone experiment: a 2,400-vertex sheet falls on a cone")
    p.add_argument("--contact", choices=["vertex", "opt", "multires"], default="multires",
                   help="decision-point strategy (default multires)")
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N] (default cpu)")
    p.add_argument("--steps", type=int, default=30, help="5 ms steps of 10 substeps (count, default 30)")
    p.add_argument("--passes", type=int, default=None, help="contact passes per substep (count, default 8)")
    p.add_argument("--placement", choices=["before", "after", "both"], default=None,
                   help="where the correction runs in a substep (default after)")
    p.add_argument("--samples", type=int, default=None, help="multires samples per round (count, default 21)")
    p.add_argument("--rounds", type=int, default=None, help="multires rounds (count, default 2; the paper: 16 x 2)")
    p.add_argument("--log", type=Path, default=None, help="write the per-substep log as CSV here")
    p.set_defaults(run=_bench_cone)
    p = bench.add_parser("accuracy", help="accuracy against time: contact settings swept over HOI grasps and hard "
                                          "cases; CSV, JSON and a Pareto plot in DIR")
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N] (default cpu)")
    p.add_argument("--out", type=Path, default=Path("accuracy_out"), help="output directory (default accuracy_out)")
    p.add_argument("--quick", action="store_true", help="a smoke run: 2 settings, 3 workloads, 2 frames")
    p.add_argument("--frames", type=int, default=None, help="5 ms frames per run (count, default 20; --quick 2)")
    p.add_argument("--repeats", type=int, default=None,
                   help="timing passes in alternating order; the fastest median counts (count, default 2; --quick 1)")
    p.add_argument("--workloads", default=None,
                   help="comma-separated hoi:SCENE, case:KIND@SITE, heldout:SEED:I (case I of the held-out "
                        "generator) and cone:paper (the paper's sheet on a cone; default: box, apple, glass2, "
                        "knife@fingertip, cone_tip@palm, plate@fingertip, cone:paper, heldout:0:0, heldout:0:51, "
                        "heldout:0:24, heldout:0:4)")
    p.set_defaults(run=_bench_accuracy)
    args = parser.parse_args(argv)

    from physhand_mj.asset import AssetError
    from physhand_mj.render import RenderUnavailable
    from physhand_mj.solver import SolverError

    try:
        _check_device(args)
        result = args.run(args)
    except (AssetError, RenderUnavailable, FileNotFoundError, ValueError, ImportError, SolverError) as e:
        print(f"physhand {args.command}: error: {e}".replace("\n", " "), file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"physhand {args.command}: interrupted", file=sys.stderr)
        return 130
    if result is None:  # the command printed its own lines (batch rollouts)
        return 0
    if isinstance(result, int):
        return result
    print(json.dumps(result))
    return 130 if isinstance(result, dict) and result.get("interrupted") else 0


if __name__ == "__main__":
    sys.exit(main())
