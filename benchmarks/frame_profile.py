"""Where the demo's frame goes: per-launch GPU time of a SoftHand frame, and the frame with a few
contact settings changed.

The demo (grasp_glass, approach keyframe, default Config): 3 warm-up frames (compilation and
recording excluded), then ``--frames`` frames timed as a whole (MuJoCo step + SoftHand.step, one
device sync at the end). First with CUDA graphs off and Warp's CUDA timing on
(``wp.timing_begin``: every launch, memset and copy timed by the driver; ms per frame and launches
per frame for the top 25), then graphs on with the skin BVH built by LBVH and by SAH
(``physhand_mj.contact.inside.BVH_CONSTRUCTOR``), then (without ``--quick``) with the object's side,
side-aware exits, the tether or the gating switched off. One JSON line per run.

    python benchmarks/frame_profile.py --device cuda [--frames 10] [--warmup 3] [--quick] [--config JSON]

``--config`` sets Config fields for every run, for A/B comparisons, e.g. the BVH feature queries
against the tiled ones: ``--config '{"tiled_features": false}'``.

On the CPU the timing list is empty (Warp's timing covers CUDA work only); the frame times still print.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

import mujoco
import warp as wp

import physhand_mj as ph
import physhand_mj.contact.inside as inside
import physhand_mj.contact.contact as contact_mod
import physhand_mj.launch as solver_mod


def run(device: str, frames: int, graph: bool = True, profile: bool = False, warmup: int = 3, **config) -> dict:
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device=device, **config, execution=ph.Execution(cuda_graph=graph)), settle_frames=2)
    for _ in range(warmup):
        mujoco.mj_step(model, data)
        hand.step()
    wp.synchronize()
    if profile:
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    t = time.perf_counter()
    for _ in range(frames):
        mujoco.mj_step(model, data)
        hand.step()
    wp.synchronize()
    ms = (time.perf_counter() - t) / frames * 1e3
    m = hand.metrics()
    out = dict(config=config, warmup=warmup, list_blocks_per_sm=solver_mod.LIST_BLOCKS_PER_SM,
               tiled_blocks_per_sm=solver_mod.TILED_BLOCKS_PER_SM, wide_blocks_per_sm=solver_mod.WIDE_BLOCKS_PER_SM,
               feature_lanes=contact_mod.FEATURE_LANES, skin_bvh=inside.BVH_CONSTRUCTOR, graph=graph, ms_frame=round(ms, 3),
               **{k: m.get(k) for k in ("ops_run", "contact_ops_run", "features_listed", "triangles_tested")})
    if profile:
        agg = defaultdict(lambda: [0, 0.0])
        for r in wp.timing_end():
            agg[r.name][0] += 1
            agg[r.name][1] += r.elapsed
        top = sorted(agg.items(), key=lambda kv: -kv[1][1])[:25]
        out["top_ms_per_frame"] = [(k[:70], v[0] // frames, round(v[1] / frames, 4)) for k, v in top]
        out["timed_ms_per_frame"] = round(sum(v[1] for v in agg.values()) / frames, 3)
    print(json.dumps(out), flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda", help="Warp device: cuda[:N] or cpu")
    ap.add_argument("--frames", type=int, default=10, help="timed 5 ms frames per run (count)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed frames first (count; the hand closes on the "
                    "glass over the first ~40 frames and holds it after)")
    ap.add_argument("--list-blocks", type=int, default=None, help="blocks per SM of the list-walking CUDA "
                    "launches (physhand_mj.launch.LIST_BLOCKS_PER_SM; 0: uncapped)")
    ap.add_argument("--tiled-blocks", type=int, default=None, help="blocks per SM of the tiled list-walking CUDA "
                    "launches (physhand_mj.launch.TILED_BLOCKS_PER_SM; 0: uncapped)")
    ap.add_argument("--wide-blocks", type=int, default=None, help="blocks per SM of the tiled list-walking CUDA "
                    "launches wider than a warp (the feature kernels; launch.WIDE_BLOCKS_PER_SM; 0: uncapped)")
    ap.add_argument("--feature-lanes", type=int, default=None, help="threads per listed feature in the CUDA "
                    "tiled feature kernels (physhand_mj.contact.contact.FEATURE_LANES; count)")
    ap.add_argument("--quick", action="store_true", help="the profile and the LBVH/SAH pair only")
    ap.add_argument("--config", default="{}", help="JSON object of Config fields set in every run "
                    "(e.g. '{\"tiled_features\": false}')")
    a = ap.parse_args()
    if a.feature_lanes is not None:
        contact_mod.FEATURE_LANES = a.feature_lanes
    if a.wide_blocks is not None:
        solver_mod.WIDE_BLOCKS_PER_SM = a.wide_blocks
    if a.tiled_blocks is not None:
        solver_mod.TILED_BLOCKS_PER_SM = a.tiled_blocks
    if a.list_blocks is not None:
        solver_mod.LIST_BLOCKS_PER_SM = a.list_blocks
    base = json.loads(a.config)
    if not isinstance(base, dict):
        ap.error("--config takes a JSON object of Config fields")
    run(a.device, a.frames, graph=False, profile=True, warmup=a.warmup, **base)
    for bvh in ("lbvh", "sah"):
        inside.BVH_CONSTRUCTOR = bvh
        run(a.device, a.frames, warmup=a.warmup, **base)
    if not a.quick:
        for config in (dict(feature_contact=False), dict(feature_contact=False, side_aware=False),
                       dict(skin_tether=0.0), dict(skip_idle=False)):
            run(a.device, a.frames, warmup=a.warmup, **{**base, **config})


if __name__ == "__main__":
    main()
