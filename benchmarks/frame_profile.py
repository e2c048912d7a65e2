"""Per-kernel GPU time of the demo's SoftHand frame (grasp_glass, approach keyframe), graphs off so
every launch is timed by Warp's CUDA timing (wp.timing_begin). Prints the top kernels and the
frame's ms for a few contact configurations. Run: python benchmarks/frame_profile.py --device cuda"""
import argparse, json, time
from collections import defaultdict
import mujoco, numpy as np, warp as wp
import physhand_mj as ph

def run(device, frames, graph=True, profile=False, **over):
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device=device, cuda_graph=graph, **over), settle_frames=2)
    for _ in range(3):
        mujoco.mj_step(model, data); hand.step()
    wp.synchronize()
    if profile:
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    t = time.perf_counter()
    for _ in range(frames):
        mujoco.mj_step(model, data); hand.step()
    wp.synchronize()
    ms = (time.perf_counter() - t) / frames * 1e3
    out = dict(config=over, graph=graph, ms_frame=round(ms, 3), **{k: hand.metrics().get(k) for k in ("ops_run", "contact_ops_run", "features_listed", "triangles_tested")})
    if profile:
        res = wp.timing_end()
        agg = defaultdict(lambda: [0, 0.0])
        for r in res:
            agg[r.name][0] += 1; agg[r.name][1] += r.elapsed
        top = sorted(agg.items(), key=lambda kv: -kv[1][1])[:25]
        out["top_ms_per_frame"] = [(k[:70], v[0] // frames, round(v[1] / frames, 4)) for k, v in top]
        out["sum_ms_per_frame"] = round(sum(v[1] for v in agg.values()) / frames, 3)
    print(json.dumps(out), flush=True)

ap = argparse.ArgumentParser(); ap.add_argument("--device", default="cuda"); ap.add_argument("--frames", type=int, default=10)
ap.add_argument("--quick", action="store_true", help="the profile and the LBVH/SAH pair only")
a = ap.parse_args()
import physhand_mj.contact.inside as inside
run(a.device, a.frames, graph=False, profile=True)
for bvh in ("lbvh", "sah"):  # the skin BVH's builder (inside.BVH_CONSTRUCTOR)
    inside.BVH_CONSTRUCTOR = bvh
    print(json.dumps(dict(skin_bvh=bvh)), flush=True)
    run(a.device, a.frames)
if not a.quick:
    for over in (dict(feature_contact=False), dict(feature_contact=False, side_aware=False), dict(skin_tether=0.0),
                 dict(skip_idle=False)):
        run(a.device, a.frames, **over)
