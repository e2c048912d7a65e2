"""Where ``feature_patches`` (physhand_mj/contact/winding.py) spends its time: the kernel as shipped
against kernels doing one of its parts each, on the same inputs (an HOI grasp's batch after its warm-up
frames): the patch's two BVH box walks, the closest-point search in ``frame_winding``, the fast
winding number, and the patch's solid-angle sum. Median of ``--repeats`` launches, synchronised,
compilation excluded.
    python benchmarks/feature_patch_split.py [--device cuda] [--scene box] [--worlds 1024] [--repeats 20]
Prints a table and writes docs/benchmarks/feature_patch_split_<device>.json (or --out).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from physhand_mj.contact.inside import object_point, winding_number
from physhand_mj.contact.winding import feature_patches, frame_winding, patch_angle, patch_radius, within

ROOT = Path(__file__).resolve().parents[1]


@wp.kernel
def walk_count(skin: wp.uint64, faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), feat: wp.array(dtype=int),
               feat_count: wp.array(dtype=int), pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int),
               pose: wp.array(dtype=wp.transform), radius: float, feat_dist: wp.array(dtype=float),
               slack: wp.array(dtype=float), geoms_per_world: int, out: wp.array(dtype=int)):
    """One box walk with the ``within`` test (the patch's count)."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    i = feat[k]
    p = object_point(i, pts, pts_geom, pose)
    r = patch_radius(radius, feat_dist[k], slack[pts_geom[i] // geoms_per_world])
    n = int(0)
    t = int(0)
    q = wp.mesh_query_aabb(skin, p - wp.vec3(r), p + wp.vec3(r))
    while wp.mesh_query_aabb_next(q, t):
        if within(p, t, faces, x, r):
            n += 1
    out[k] = n


@wp.kernel
def closest_only(skin_w: wp.uint64, feat: wp.array(dtype=int), feat_count: wp.array(dtype=int),
                 pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform),
                 margin: float, out: wp.array(dtype=int)):
    """``frame_winding``'s closest-point search alone."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    p = object_point(feat[k], pts, pts_geom, pose)
    out[k] = wp.where(wp.mesh_query_point_no_sign(skin_w, p, margin).result, 1, 0)


@wp.kernel
def winding_only(skin_w: wp.uint64, feat: wp.array(dtype=int), feat_count: wp.array(dtype=int),
                 pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform),
                 accuracy: float, out: wp.array(dtype=float)):
    """The fast winding number alone (``accuracy``: Warp's beta; the shipped queries use 2)."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    p = object_point(feat[k], pts, pts_geom, pose)
    out[k] = winding_number(skin_w, p, accuracy)


@wp.kernel
def frame_winding_only(skin_w: wp.uint64, feat: wp.array(dtype=int), feat_count: wp.array(dtype=int),
                       pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform),
                       margin: float, feat_dist: wp.array(dtype=float), out: wp.array(dtype=float)):
    """``frame_winding`` as shipped (the listed feature's distance; a coarse winding number, asked again
    where far from an integer)."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    p = object_point(feat[k], pts, pts_geom, pose)
    out[k] = frame_winding(skin_w, p, feat_dist[k], margin)


@wp.kernel
def angle_only(faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), feat: wp.array(dtype=int),
               feat_count: wp.array(dtype=int), pts: wp.array(dtype=wp.vec3), pts_geom: wp.array(dtype=int),
               pose: wp.array(dtype=wp.transform), pool: wp.array(dtype=int), patch_start: wp.array(dtype=int),
               patch_len: wp.array(dtype=int), out: wp.array(dtype=float)):
    """The patch's solid-angle sum alone (over the pool the shipped kernel filled)."""
    k = wp.tid()
    if k >= feat_count[0]:
        return
    n = patch_len[k]
    if n < 0:
        return
    p = object_point(feat[k], pts, pts_geom, pose)
    out[k] = patch_angle(p, faces, x, pool, patch_start[k], n)


def main() -> None:
    import physhand_mj as ph
    from physhand_mj.batch_rollout import replicated_batch
    from physhand_mj.bench import device_name
    from physhand_mj.contact.contact import PATCH_SLOT

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--scene", default="box", help="HOI scene (hoi_<name>)")
    p.add_argument("--worlds", type=int, default=1, help="worlds in the batch")
    p.add_argument("--repeats", type=int, default=20, help="timed launches per kernel (median)")
    p.add_argument("--config", default="{}", help="Config fields as JSON")
    p.add_argument("--out", default=None, help="JSON path")
    a = p.parse_args()
    wp.init()
    dev = device_name(a.device if a.device != "cuda" else "cuda:0")
    asset = ph.load_asset()
    hands, args = replicated_batch(asset, ph.scene_path(f"hoi_{a.scene}"), "grasp", a.worlds, device=a.device,
                                   **json.loads(a.config))
    for _ in range(3):
        hands.step(*args)
    c, state = hands.solver.contact, hands.state
    if c is None or c.feat is None or not c.config.feature_winding:
        raise SystemExit("no feature points with the local winding number (Config.tuning.feature_winding): nothing to split")
    pts, m, cfg = c.points, c.model, c.config
    vol, volw = c.volume(state, winding=False), c.volume(state, winding=True)
    qpose = c._qp
    x = c._query_x(state)
    d = m.device
    n = pts.n_features
    listed = int(c.feat_count.numpy()[0])
    if not listed:
        raise SystemExit("no feature points listed after the warm-up frames: nothing to split")
    tmp_i = wp.zeros(n, dtype=int, device=d)
    tmp_f = wp.zeros(n, dtype=float, device=d)
    fm = cfg.contact_frame_margin
    common = [c.feat, c.feat_count, pts.pts, pts.geom, qpose]

    def shipped():
        c.patch_used.zero_()
        wp.launch(feature_patches, n, inputs=[vol.mesh.id, volw.mesh.id, m.skin_faces, x, c.feat, c.feat_count,
                                              pts.pts, pts.geom, qpose, fm, fm, c.feat_dist, c.slack,
                                              c.geoms_per_world, PATCH_SLOT],
                  outputs=[c.patch_used, c.patch_pool, c.feat_slot, c.patch_start, c.patch_len, c.far_angle], device=d)

    parts = {
        "feature_patches (shipped)": shipped,
        "one box walk + within": lambda: wp.launch(walk_count, n, inputs=[vol.mesh.id, m.skin_faces, x, *common, fm,
                                                                         c.feat_dist, c.slack, c.geoms_per_world],
                                                   outputs=[tmp_i], device=d),
        "frame_winding": lambda: wp.launch(frame_winding_only, n,
                                                               inputs=[volw.mesh.id, *common, fm, c.feat_dist],
                                                               outputs=[tmp_f],
                                                               device=d),
        "closest-point search (not run since)": lambda: wp.launch(closest_only, n, inputs=[volw.mesh.id, *common, fm],
                                                  outputs=[tmp_i], device=d),
        "fast winding number": lambda: wp.launch(winding_only, n, inputs=[volw.mesh.id, *common, 2.0],
                                                 outputs=[tmp_f], device=d),
        "fast winding number, beta 1": lambda: wp.launch(winding_only, n, inputs=[volw.mesh.id, *common, 1.0],
                                                         outputs=[tmp_f], device=d),
        "refit, BVH only": vol.mesh.refit,
        "refit, BVH + winding data": volw.mesh.refit,
        "patch solid angles": lambda: wp.launch(angle_only, n, inputs=[m.skin_faces, x, *common, c.patch_pool,
                                                                       c.patch_start, c.patch_len],
                                                outputs=[tmp_f], device=d),
    }
    rows = []
    for name, fn in parts.items():
        fn()
        wp.synchronize_device(d)
        ts = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            fn()
            wp.synchronize_device(d)
            ts.append(time.perf_counter() - t0)
        rows.append(dict(part=name, ms=round(1e3 * float(np.median(ts)), 3)))
        print(f"{name:38s} {rows[-1]['ms']:9.3f} ms")
    lens = c.patch_len.numpy()[:listed]
    wn = {}
    for beta in (2.0, 1.0):  # how far the winding number at the listed points is from an integer
        wp.launch(winding_only, n, inputs=[volw.mesh.id, *common, beta], outputs=[tmp_f], device=d)
        wn[beta] = tmp_f.numpy()[:listed].astype(np.float64)
    frac = {b: float(np.abs(v - np.round(v)).max()) if listed else 0.0 for b, v in wn.items()}
    info = dict(device=dev, scene=a.scene, worlds=a.worlds, listed=listed, patch_len_mean=float(lens[lens >= 0].mean()),
                patch_len_max=int(lens.max()), overflow=int((lens < 0).sum()),
                winding_off_integer_max=frac[2.0], winding_beta1_off_integer_max=frac[1.0],
                winding_beta1_rounding_differs=int((np.round(wn[1.0]) != np.round(wn[2.0])).sum()),
                command="python benchmarks/feature_patch_split.py " + " ".join(sys.argv[1:]), rows=rows)
    print({k: v for k, v in info.items() if k != "rows"})
    out = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"feature_patch_split_{a.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(info, indent=1))


if __name__ == "__main__":
    main()
