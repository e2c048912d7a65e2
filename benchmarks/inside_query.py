"""The object-side measure's inside test, before and after its closest-point search moved behind the
winding number (contact/inside.py ``inside_depth``; winding.py ``frame_winding``): ms per launch over
an HOI grasp's object points against its settled skin, both ways, with the answers compared.

    python benchmarks/inside_query.py [--device cpu|cuda] [--scene apple] [--worlds 1] [--repeat 5]

"Before" is Warp's ``mesh_query_point_sign_winding_number`` per point (a closest-point search, then
the winding number), "after" ``inside_depth`` (the winding number, and the search only inside); the
feature patches' w_0 likewise (two sign queries at -1/2 and 1/2 against one search and one winding
number). Writes docs/benchmarks/inside_query_<device>.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parents[1]

from physhand_mj.contact.inside import INSIDE_RANGE, inside_depth  # noqa: E402
from physhand_mj.contact.winding import frame_winding  # noqa: E402


@wp.kernel
def _before(skin: wp.uint64, p: wp.array(dtype=wp.vec3), box: wp.array(dtype=wp.vec3), per: int,
            depth: wp.array(dtype=float)):
    i = wp.tid()
    lo, hi = box[2 * (i // per)], box[2 * (i // per) + 1]
    q = p[i]
    d = float(0.0)
    if not (q[0] < lo[0] or q[1] < lo[1] or q[2] < lo[2] or q[0] > hi[0] or q[1] > hi[1] or q[2] > hi[2]):
        r = wp.mesh_query_point_sign_winding_number(skin, q, INSIDE_RANGE)
        if r.result and r.sign < 0.0:
            d = wp.length(q - wp.mesh_eval_position(skin, r.face, r.u, r.v))
    depth[i] = d


@wp.kernel
def _after(skin: wp.uint64, p: wp.array(dtype=wp.vec3), box: wp.array(dtype=wp.vec3), per: int,
           depth: wp.array(dtype=float)):
    i = wp.tid()
    depth[i] = inside_depth(skin, p[i], box[2 * (i // per)], box[2 * (i // per) + 1])


@wp.kernel
def _w0_before(skin: wp.uint64, p: wp.array(dtype=wp.vec3), margin: float, out: wp.array(dtype=float)):
    i = wp.tid()
    w0 = float(-1.0)
    r = wp.mesh_query_point_sign_winding_number(skin, p[i], margin, 2.0, -0.5)
    if not r.result:
        w0 = 0.0
    elif r.sign < 0.0:
        w0 = 0.0
        r = wp.mesh_query_point_sign_winding_number(skin, p[i], margin, 2.0, 0.5)
        if r.sign < 0.0:
            w0 = 1.0
    out[i] = w0


@wp.kernel
def _w0_after(skin: wp.uint64, p: wp.array(dtype=wp.vec3), margin: float, out: wp.array(dtype=float)):
    i = wp.tid()
    d = float(1.0e6)  # (frame_winding takes the distance a listed feature's own search found)
    c = wp.mesh_query_point_no_sign(skin, p[i], margin)
    if c.result:
        d = wp.length(p[i] - wp.mesh_eval_position(skin, c.face, c.u, c.v))
    out[i] = frame_winding(skin, p[i], d, margin)


def main() -> None:
    import mujoco

    import physhand_mj as ph
    from physhand_mj.batch import BatchedHands
    from physhand_mj.batch_rollout import _Run
    from physhand_mj.bench import device_name
    from physhand_mj.coupling import rest_placement

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    p.add_argument("--scene", default="apple", help="HOI scene (hoi_<name>)")
    p.add_argument("--worlds", type=int, default=1, help="batched worlds (their points in one launch)")
    p.add_argument("--frames", type=int, default=5, help="5 ms frames of the held grasp before measuring")
    p.add_argument("--repeat", type=int, default=5, help="timed launches of each kernel")
    a = p.parse_args()
    wp.init()
    d = wp.get_device(a.device)
    asset = ph.load_asset()
    with tempfile.TemporaryDirectory() as tmp:
        run = _Run(0, ph.scene_path(f"hoi_{a.scene}"), "grasp", Path(tmp), asset)
    mujoco.mj_kinematics(run.model, run.data)
    bp, bq = run.bone_poses()
    opos, oq = run.object_poses()
    place = rest_placement(asset, bp[0], bq[0])
    w = a.worlds
    cfg = ph.Config(frame_dt=float(run.model.opt.timestep), device=a.device)
    hands = BatchedHands(asset, w, cfg, np.tile(place[0], (w, 1)), np.tile(place[1], (w, 1)), objects=run.specs,
                         spacing=1.0)
    pos, quat = np.tile(bp, (w, 1, 1)), np.tile(bq, (w, 1, 1))
    hands.settle(pos, quat)
    op, oqq = np.tile(opos, (w, 1, 1)), np.tile(oq, (w, 1, 1))
    for _ in range(a.frames):
        hands.step(pos, quat, op, oqq)
    c = hands.solver.contact
    c.measure_worlds(hands.state)  # refits the winding-number skin and its per-world boxes
    vol = c.volume(hands.state)
    pts = c.points
    # the object points in the query's space (the skin mesh holds each world shifted apart)
    pose = c._query_pose(lambda k, dim, inputs, outputs, **kw: wp.launch(k, dim, inputs=inputs, outputs=outputs,
                                                                        device=d))
    world = wp.zeros(len(pts), dtype=wp.vec3, device=d)

    @wp.kernel
    def place_points(pts: wp.array(dtype=wp.vec3), geom: wp.array(dtype=int), pose: wp.array(dtype=wp.transform),
                     out: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        out[i] = wp.transform_point(pose[geom[i]], pts[i])

    wp.launch(place_points, len(pts), [pts.pts, pts.geom, pose], [world], device=d)
    per = max(len(pts) // w, 1)
    rows = {}
    outs = {}
    for name, kernel, args in (("inside: sign query (before)", _before, [vol.mesh.id, world, vol.box, per]),
                               ("inside: inside_depth (after)", _after, [vol.mesh.id, world, vol.box, per]),
                               ("w_0: two sign queries (before)", _w0_before, [vol.mesh.id, world, cfg.contact_frame_margin]),
                               ("w_0: frame_winding (after)", _w0_after, [vol.mesh.id, world, cfg.contact_frame_margin])):
        out = wp.zeros(len(pts), dtype=float, device=d)
        wp.launch(kernel, len(pts), args, [out], device=d)  # compile, warm
        wp.synchronize_device(d)
        t = time.perf_counter()
        for _ in range(a.repeat):
            wp.launch(kernel, len(pts), args, [out], device=d)
        wp.synchronize_device(d)
        rows[name] = round((time.perf_counter() - t) / a.repeat * 1e3, 3)
        outs[name] = out.numpy()
    names = list(outs)
    res = dict(device=device_name(a.device if a.device != "cuda" else "cuda:0"), scene=a.scene, worlds=w,
               points=len(pts), ms_per_launch=rows,
               inside_equal=bool(np.array_equal(outs[names[0]], outs[names[1]])),
               w0_equal=bool(np.array_equal(outs[names[2]], outs[names[3]])),
               points_inside=int((outs[names[1]] > 0).sum()),
               w0_counts={str(v): int((outs[names[3]] == v).sum()) for v in (-1.0, 0.0, 1.0)},
               command="python benchmarks/inside_query.py " + " ".join(sys.argv[1:]))
    print(json.dumps(res, indent=1))
    (ROOT / "docs" / "benchmarks" / f"inside_query_{a.device.split(':')[0]}.json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
