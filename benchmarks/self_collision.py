"""Skin self-penetration per ``hand_only`` keyframe, with and without Config.self_collision (issue 53).

    python benchmarks/self_collision.py [--scene hand_only] [--keys open,pinch,power] [--frames 36] [--last N] [--modes off,on] [--tet-keep K]
        [--friction MU] [--edges] [--margin MM] [--every N] [--no-self-proxies] [--slip] [--stretch-only] [--flesh-stretch-only] [--device cuda] [--fused auto|on|off] [--self-launches] [--out F.json]
        [--picture F.png]
    python benchmarks/self_collision.py --worlds 3,1024 [--keys open,pinch,power] [--frames 20] [--modes off,on]
        [--stretch-only] [--device cuda] [--fused auto|on|off] [--self-launches]

Each keyframe is rolled out as ``physhand rollout`` does (SoftHand on the hand_only scene, MuJoCo
stepping the keyframe's targets, ``frames`` frames x 10 substeps), then measured by the independent
measure (physhand_mj/contact/self_measures.py): skin vertices whose 0.2 mm and 1 mm outward offsets
lie inside the closed skin, those with no point outside it 0.2 mm around them in any direction
(``buried_200um``: no normal involved), skin edges through another skin triangle (and those poking
through it farther than 0.2 / 1 mm, the deepest), and inverted tets (and where: across a joint, on its
stretched back or in its closing crease, per pair of bones) (``--last N``: also the mean over the last N frames of
the 0.2 mm count and the edges through triangles). Frame times are the median of the frames after the
first (which compiles), wall and the calling thread's CPU time (Warp's CPU kernels run on it: the
figure other processes on a shared host disturb least); modes run one after the other in the same
process. ``--tet-keep``: Tuning.self_tet_keep for the "on" runs; ``--friction``: Tuning.self_friction
for them (Coulomb coefficient); ``--edges``: Tuning.self_edges for them (edge-edge pairs, in both
the keyframe and the ``--worlds`` runs); ``--stretch-only``: Config.skin_compression False in every run (both
modes: the skin's material, not part of the option); ``--flesh-stretch-only``: Config.flesh_compression
False likewise; ``--every``: Tuning.self_every for the "on" runs (frames one list serves); ``--no-self-proxies``: Tuning.self_proxies False for them (with the
option SoftHand turns on the hand model's self proxies, so MuJoCo stops the parts' bones where their
rest skins meet: reported ``self_proxies``, their contacts in the last step, and the joints' largest
change from the keyframe, ``pose_change_rad``); ``--slip``: also the skin's slip at touching pairs over the last 10
frames (each listed vertex within 1 mm of its nearest listed triangle: its motion less the motion of
the triangle's point under it, along the triangle; median and 90th percentile, um a frame). ``--fused``: Config.execution.fused_substep
(auto: None, the default: the fused substep on the CPU, the five-launch substep for one hand on CUDA;
on: True, also on CUDA, one block on one SM; off: False); ``--self-launches``: the self-contact passes as
self_contact.py's launches after the fused kernel (fused.SELF_IN_KERNEL False) instead of inside it. Reported with the option on: the
last frame's vertices queried (``self_queried``), self-collision launches run (``self_ops_run``),
listed vertices and pairs, corrections. Every run: the skin's move over the last frame (vertices
moving more than 0.5 mm, the largest; a held fist: ``--keys power --modes on --frames 120``).

``--worlds W[,W2...]``: batched throughput instead (BatchedHands, no objects): world w holds keyframe
``keys[w % len(keys)]`` (its bones settled there over 20 frames, BatchedHands.settle, then held; the
hand never sleeps: Config.sleep_speed 0), 2 warm-up frames, then ``frames`` frames timed one
``step`` (one host sync) each: ms a frame and hand-frames/s, per mode; with the option on the last
frame's queried vertices, launches run and pairs (every world's), and per keyframe its first world's
pairs and the independent measure (those worlds' skins, on the host). ``--fused`` / ``--self-launches``
as above (a CUDA batch of W >= 0.3 x the SMs takes the fused substep by default: fused_choice.cuda_auto).
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))


def inverted_where(x: np.ndarray, asset) -> dict:
    """Where the inverted tets are: ``inverted_across_joint`` counts those whose corners follow two
    bones (each flesh or skin vertex follows the skeleton vertex it is attached to, Eq. 4-5), of them
    ``inverted_across_stretched`` those whose corner pairs across the two bones lie farther apart than
    at rest (the mean ratio above 1: the back of a bent joint, where nothing touches; below 1: the
    crease that closes), and ``inverted_by_joint`` the counts per pair of bones."""
    from physhand_mj.contact.self_measures import inverted_mask

    x0, tets = np.asarray(asset.positions, float), np.asarray(asset.tets)
    vb = np.asarray(asset.vertex_body)
    body = vb.copy()
    att = np.asarray(asset.attach)
    body[att[:, 0]] = vb[att[:, 1]]
    inv = np.where(inverted_mask(x, tets, x0))[0]
    names = np.asarray(asset.body_names)
    across, stretched, by = 0, 0, {}
    for t in tets[inv]:
        bs = sorted(set(body[t].tolist()) - {-1})
        if len(bs) < 2:
            continue
        across += 1
        r = [np.linalg.norm(x[t[i]] - x[t[j]]) / np.linalg.norm(x0[t[i]] - x0[t[j]])
             for i in range(4) for j in range(i + 1, 4) if body[t[i]] != body[t[j]]]
        stretched += int(np.mean(r) > 1.0)
        k = "/".join(str(names[b]) for b in bs)
        by[k] = by.get(k, 0) + 1
    return dict(inverted_across_joint=across, inverted_across_stretched=stretched,
                inverted_by_joint=dict(sorted(by.items(), key=lambda kv: -kv[1])))


def slip_at_pairs(hand, x: np.ndarray, prev: np.ndarray) -> np.ndarray:
    """The slip (m) over one frame of each listed vertex within 1 mm of its nearest listed triangle
    (the solver's list; the motion from positions ``prev`` -> ``x``): its move less the move of the
    triangle's point under it (the projection's barycentrics now), along the triangle."""
    import trimesh

    sc = hand.solver.selfc
    n = int(sc.counts.numpy()[0])
    v = sc.vlist.numpy()[:n]
    t = sc.nearest.numpy()[v]
    v, t = v[t >= 0], t[t >= 0]
    f = np.asarray(hand.asset.skin_faces)[t]
    A, B, C = (x[f[:, k]] for k in range(3))
    nrm = np.cross(B - A, C - A)
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    gap = ((x[v] - A) * nrm).sum(1)
    bc = trimesh.triangles.points_to_barycentric(np.stack([A, B, C], 1), x[v] - gap[:, None] * nrm)
    q = (bc[:, :, None] * np.stack([A, B, C], 1)).sum(1)
    qp = (bc[:, :, None] * prev[f]).sum(1)
    rel = (x[v] - prev[v]) - (q - qp)
    rel -= (rel * nrm).sum(1)[:, None] * nrm
    return np.linalg.norm(rel[np.abs(gap) < 1e-3], axis=1)


def run(key: str, frames: int, self_collision: bool, device=None, scene: str = "hand_only", extra=None,
        picture: bool = False, slip: bool = False, last: int = 1) -> dict:
    import mujoco

    import physhand_mj as ph
    from physhand_mj.contact.self_measures import self_penetration
    from physhand_mj.rollout import load_rollout_scene

    last_n = int(last)
    model, data, key = load_rollout_scene(ph.scene_path(scene), key)
    opts = dict(frame_dt=float(model.opt.timestep), substeps=10, device=device, **(extra or {}))
    if self_collision:
        opts["self_collision"] = True
    cfg = ph.Config.from_dict(opts)
    hand = ph.SoftHand(model, data, cfg, settle_contact=False)
    q0 = data.qpos.copy()
    times, cpu, res = [], [], {}
    ns, last = hand.asset.n_skin, None
    slips, before = [], None
    lasts = []  # (--last: the measure's counts over the last frames)
    for f in range(frames):
        mujoco.mj_step(model, data)
        t, c = time.perf_counter(), time.thread_time()
        res = hand.step()
        times.append(time.perf_counter() - t)
        cpu.append(time.thread_time() - c)
        if f == frames - 2:
            last = hand.state.x.numpy()[:ns].astype(float)
        if last_n > 1 and f >= frames - last_n:  # (outside the timed call)
            m = self_penetration(hand.state.x.numpy()[:ns].astype(float), np.asarray(hand.asset.skin_faces), offsets=(2e-4,))
            lasts.append((m["inside_200um"], m["crossing_edges"]))
        if slip and f >= frames - 11:  # (outside the timed call)
            now = hand.state.x.numpy()[:ns].astype(float)
            if before is not None:
                slips.append(slip_at_pairs(hand, now, before))
            before = now
    x = hand.solver.state_positions(hand.state) if hasattr(hand.solver, "state_positions") else hand.state.x.numpy()
    a = hand.asset
    out = dict(scene=scene, key=key, self_collision=self_collision, frames=frames,
               ms_frame=float(np.median(times[1:]) * 1e3) if frames > 1 else None,
               cpu_ms_frame=float(np.median(cpu[1:]) * 1e3) if frames > 1 else None,
               finite=bool(np.all(np.isfinite(x))), guard_inverted=int(res.get("inverted", -1)))
    if last is not None:  # the skin's move over the last frame (a held pose at rest: ~0)
        mv = np.linalg.norm(np.asarray(x, float)[:ns] - last, axis=1)
        out.update(skin_moved_over_05mm=int((mv > 5e-4).sum()), skin_move_max_mm=round(float(mv.max()) * 1e3, 3))
    out.update(self_penetration(x, np.asarray(a.skin_faces), np.asarray(a.tets), hand.solver.model.rest_x.numpy(), buried=2e-4))
    out.update(inverted_where(x, a))
    if lasts:
        lasts = np.array(lasts)
        out.update(last_frames=len(lasts), inside_200um_mean_last=round(float(lasts[:, 0].mean()), 1),
                   crossing_edges_mean_last=round(float(lasts[:, 1].mean()), 1))
    if slips:
        s = np.concatenate(slips) * 1e6
        out.update(slip_pairs=int(len(s)), slip_median_um=round(float(np.median(s)), 1),
                   slip_p90_um=round(float(np.percentile(s, 90)), 1))
    out["self_friction"] = float(cfg.tuning.self_friction) if self_collision else None
    out["self_edges"] = bool(cfg.tuning.self_edges)
    # the self proxies SoftHand turned on (MuJoCo keeping the parts' bones apart), their contacts in the
    # last step, and how far MuJoCo's joints ended from the keyframe (rad)
    on = set(hand.self_proxies.tolist())
    out["self_proxies"] = len(on)
    out["self_proxy_contacts"] = sum(1 for c in data.contact[:data.ncon] if c.geom1 in on and c.geom2 in on)
    out["pose_change_rad"] = round(float(np.abs(data.qpos - q0).max()), 4)
    out["skin_compression"] = bool(cfg.skin_compression)
    out["flesh_compression"] = bool(cfg.flesh_compression)
    out["fused_substep"] = bool(hand.solver.fused_substep)
    out["self_in_kernel"] = bool(getattr(hand.solver, "_self_fused", False))
    for k in ("self_queried", "self_ops_run", "self_vertices", "self_pairs", "self_corrections", "ops_run",
              "self_edge_pairs", "self_edge_pairs_over"):
        if k in res:
            out[k] = res[k]
    if picture:  # the skin with its vertices whose 0.2 mm offset lies inside the hand marked
        out["pixels"] = picture_of(model, data, hand, np.asarray(x, float)[:ns])
    return out


def picture_of(model, data, hand, skin: np.ndarray, width: int = 640, height: int = 520) -> np.ndarray:
    """The hand seen from the palm's side, the skin vertices whose 0.2 mm outward offset lies inside
    the closed skin (the independent measure) in magenta."""
    from physhand_mj.contact.self_measures import offsets_inside
    from physhand_mj.figures import render_marked_skin
    from physhand_mj.render import look_at_camera, make_renderer

    inside = offsets_inside(skin, np.asarray(hand.asset.skin_faces), 2e-4)  # (SoftHand.step wrote the skin mesh)
    renderer = make_renderer(model, width, height)
    g = hand.skin_geom
    alpha = float(model.geom_rgba[g, 3])
    model.geom_rgba[g, 3] = 0.55  # translucent: the marks lie between the fingers and the palm
    try:
        cam = look_at_camera(skin.mean(axis=0), 0.24, -90.0, -30.0)  # the thumb's side, a little above
        return render_marked_skin(renderer, model, data, hand, cam, skin[inside], radius=0.0014).copy()
    finally:
        model.geom_rgba[g, 3] = alpha
        renderer.close()


def run_worlds(worlds: int, keys: list, frames: int, self_collision: bool, device=None, fused=None,
               friction=None, skin_compression: bool = True, edges: bool = False) -> dict:
    """``--worlds``: one batch of ``worlds`` worlds holding ``keys`` in turn, timed (module docstring);
    ``fused``: Config.execution.fused_substep (None: the default); ``friction``: Tuning.self_friction;
    ``skin_compression``: Config.skin_compression; ``edges``: Tuning.self_edges."""
    import physhand_mj as ph
    from physhand_mj.batch import BatchedHands
    from physhand_mj.contact.self_measures import self_penetration
    from physhand_mj.hand_mjcf import body_ids, bone_poses_at, mount_pose, open_hand_scene

    asset, model, data = open_hand_scene("hand_only", "open")
    ids = body_ids(model, asset.body_names)
    held = [bone_poses_at(model, data, model.key(k).qpos.copy(), ids) for k in keys]
    pick = np.arange(worlds) % len(keys)
    pos, quat = np.stack([p for p, _ in held])[pick], np.stack([q for _, q in held])[pick]
    opts = dict(frame_dt=float(model.opt.timestep), substeps=10, device=device, sleep_speed=0.0,
                self_collision=self_collision, skin_compression=skin_compression)
    if fused is not None:
        opts["fused_substep"] = fused
    if friction is not None:
        opts["self_friction"] = friction
    if edges:
        opts["self_edges"] = True
    cfg = ph.Config.from_dict(opts)
    t = time.perf_counter()
    hands = BatchedHands(asset, worlds, cfg, *mount_pose(model, data))
    hands.settle(pos, quat)
    setup_s = time.perf_counter() - t
    for _ in range(2):  # (compilation, recording, the graph's capture)
        hands.step(pos, quat)
    times = []
    for _ in range(frames):
        t = time.perf_counter()
        res = hands.step(pos, quat)
        times.append(time.perf_counter() - t)
    ms = float(np.median(times) * 1e3)
    out = dict(worlds=worlds, keys=keys, self_collision=self_collision, frames=frames, ms_frame=round(ms, 3),
               hand_frames_per_s=round(worlds / ms * 1e3, 1), setup_s=round(setup_s, 2),
               nonfinite=int(res["nonfinite"]), inverted=int(res["inverted"]),
               self_friction=float(cfg.tuning.self_friction) if self_collision else None,
               skin_compression=bool(cfg.skin_compression), fused_substep=bool(hands.solver.fused_substep), self_in_kernel=bool(getattr(hands.solver, "_self_fused", False)))
    for k in ("self_queried", "self_ops_run", "self_vertices", "self_pairs", "self_corrections", "ops_run",
              "self_edge_pairs", "self_edge_pairs_over"):
        if k in res:
            out[k] = res[k]
    faces = np.asarray(asset.skin_faces)
    for w in range(min(worlds, len(keys))):  # each keyframe's first world: its pairs and the measure
        row = {k: v for k, v in res["worlds"][w].items() if k.startswith("self_")}
        row.update(self_penetration(hands.skin(w), faces, buried=2e-4))
        out[keys[w]] = row
    hands.close()
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--keys", default="open,pinch,power")
    ap.add_argument("--scene", default="hand_only", help="a shipped scene (hoi_box, ...) whose keyframes --keys names")
    ap.add_argument("--frames", type=int, default=36)
    ap.add_argument("--last", type=int, default=1, help="also the measure's mean over the last N frames (skin edges "
                    "through triangles, offsets inside at 0.2 mm: a closing fist's counts move by ~10 a frame)")
    ap.add_argument("--modes", default="off,on")
    ap.add_argument("--device", default=None)
    ap.add_argument("--tet-keep", type=float, default=None)
    ap.add_argument("--edges", action="store_true", help="Tuning.self_edges for the 'on' runs (edge-edge pairs too)")
    ap.add_argument("--friction", type=float, default=None, help="Tuning.self_friction for the 'on' runs (coefficient)")
    ap.add_argument("--slip", action="store_true", help="also the slip at touching pairs (um a frame)")
    ap.add_argument("--stretch-only", action="store_true", help="Config.skin_compression False in every run "
                    "(the skin's edges resist stretch only)")
    ap.add_argument("--flesh-stretch-only", action="store_true", help="Config.flesh_compression False in every run "
                    "(the flesh's tet edges resist stretch only)")
    ap.add_argument("--margin", type=float, default=None, help="Config.tuning.self_margin for the 'on' runs (mm)")
    ap.add_argument("--every", type=int, default=None, help="Tuning.self_every for the 'on' runs (frames one list serves)")
    ap.add_argument("--no-self-proxies", action="store_true", help="Config.tuning.self_proxies False for the 'on' "
                    "runs (MuJoCo's fingers as without the option)")
    ap.add_argument("--fused", default="auto", choices=["auto", "on", "off"])
    ap.add_argument("--self-launches", action="store_true")
    ap.add_argument("--out", default=None)
    ap.add_argument("--worlds", default=None, help="comma-separated world counts: batched throughput instead")
    ap.add_argument("--picture", default=None, help="PNG: each keyframe's skin per mode side by side (rows: keys), "
                    "the vertices the measure finds inside marked")
    a = ap.parse_args()
    if a.self_launches:
        from physhand_mj.solver import fused

        fused.SELF_IN_KERNEL = False
    fz = {"auto": None, "on": True, "off": False}[a.fused]
    rows, tiles = [], []
    if a.worlds:
        for w in [int(v) for v in a.worlds.split(",")]:
            for mode in a.modes.split(","):
                r = run_worlds(w, a.keys.split(","), a.frames, mode == "on", a.device, fused=fz,
                               friction=a.friction if mode == "on" else None, skin_compression=not a.stretch_only,
                               edges=a.edges and mode == "on")
                print(json.dumps(r), flush=True)
                rows.append(r)
        if a.out:
            Path(a.out).write_text(json.dumps(rows, indent=1))
        return
    for key in a.keys.split(","):
        for mode in a.modes.split(","):
            extra = {"self_tet_keep": a.tet_keep} if a.tet_keep is not None and mode == "on" else {}
            if a.friction is not None and mode == "on":
                extra["self_friction"] = a.friction
            if a.margin is not None and mode == "on":
                extra["self_margin"] = a.margin * 1e-3
            if a.every is not None and mode == "on":
                extra["self_every"] = a.every
            if a.no_self_proxies and mode == "on":
                extra["self_proxies"] = False
            if a.edges and mode == "on":
                extra["self_edges"] = True
            if fz is not None:
                extra["fused_substep"] = fz
            if a.stretch_only:
                extra["skin_compression"] = False
            if a.flesh_stretch_only:
                extra["flesh_compression"] = False
            r = run(key, a.frames, mode == "on", a.device, scene=a.scene, extra=extra, picture=bool(a.picture),
                    slip=a.slip and mode == "on", last=a.last)
            pixels = r.pop("pixels", None)
            if pixels is not None:
                tiles.append(pixels)
            print(json.dumps(r), flush=True)
            rows.append(r)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))
    if a.picture:
        from physhand_mj.render import write_png

        m = len(a.modes.split(","))
        write_png(np.concatenate([np.concatenate(tiles[i: i + m], axis=1) for i in range(0, len(tiles), m)], axis=0),
                  a.picture)


if __name__ == "__main__":
    main()
