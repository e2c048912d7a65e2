"""Fingerprints of the project's results, to show that a restructuring changed no behaviour.

    python benchmarks/fingerprint.py [--device cpu|cuda] [--parts solver,cone,hard,hoi,batch] --out FP.json
    python benchmarks/fingerprint.py --compare BEFORE.json AFTER.json
    python benchmarks/fingerprint.py --arrays A.npz ...; --compare A.npz B.npz   (the positions, on CUDA)

Each part records the figures a docs page reports and a SHA-256 of the final positions (float32
bytes), so "identical" means bit for bit:
- solver: `physhand bench solver`'s hand, 20 frames from the open pose toward the power grasp, no contact;
- cone: the paper's cone experiment (`physhand bench cone`, multires, 30 steps), its summary;
- hard: the 24 hard cases (six objects x fingertip/palm x pressed/deep start), the default contact,
  14 frames, by all four penetration measures, and the final skin;
- hoi: the seven HOI grasps of Table 2 (`physhand rollout hoi_*`, 36 frames x 10 substeps), by all
  four measures, and the final skin;
- batch: three batched worlds (one pressed by a sphere) against a serial Solver per world: the
  largest position difference per world (0 on the CPU: bit for bit).
Timings are not part of a fingerprint. Uses the public API and the CLI's functions only.
"""

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parents[1]))  # (after PYTHONPATH: an older tree can be fingerprinted)

KINDS = ("cone_tip", "mesh_cone", "knife", "plate", "capsule", "coarse")
HOI = ("apple", "bowl", "box", "glass1", "glass2", "phone", "toothpaste")


SAVED: dict | None = None  # --arrays: the positions behind each digest, to measure a difference on CUDA


def digest(x, key: str | None = None) -> str:
    a = np.ascontiguousarray(np.asarray(x, dtype=np.float32))
    if SAVED is not None and key is not None:
        SAVED[key] = a
    return hashlib.sha256(a.tobytes()).hexdigest()[:16]


def part_solver(device):
    import physhand_mj as ph

    asset, model, data = ph.open_hand_scene("hand_only", "open")
    bones = ph.body_ids(model, asset.body_names)
    config = ph.Config(device=device)
    solver = ph.Solver(ph.make_model(asset, config), config)
    state = solver.make_state(*ph.mount_pose(model, data))
    q0, q1 = model.key("open").qpos, model.key("power").qpos
    for frame in range(20):
        solver.set_body_poses(state, *ph.bone_poses_at(model, data, q0 + (frame + 1) / 50 * (q1 - q0), bones))
        solver.step(state)
    x = state.x.numpy()
    return dict(x=digest(x, "solver"), x_sum=float(np.sum(x, dtype=np.float64)))


def part_cone(device):
    from physhand_mj.cli import main as _  # noqa: F401  (the CLI's module path)
    try:
        from physhand_mj.bench import bench_cone
    except ImportError:
        from physhand_mj.bench import bench_cone
    summary, log = bench_cone("multires", device=device, steps=30)
    keep = ("penetration_count_final", "penetration_count_max", "penetration_count_mean", "penetration_avg_um_final",
            "penetration_max_um_final", "penetration_max_um_all", "finite")
    return {k: summary[k] for k in keep} | {"log": digest([[r["penetration_count"], r["penetration_max_um"]]
                                                            for r in log])}


def part_hard(device):
    import physhand_mj as ph
    try:
        from physhand_mj.bench.cases import press_case, run_case
    except ImportError:
        from physhand_mj.cases import press_case, run_case
    from tqdm import tqdm

    asset, out = ph.load_asset(), {}
    todo = [(k, s, st) for k in KINDS for s in ("fingertip", "palm") for st in (0.002, -0.004)]
    for kind, site, start in tqdm(todo, desc="hard cases", file=sys.stderr):
        r = run_case(press_case(kind, site=site, depth=0.004, start=start), ph.Config(device=device), frames=14,
                     asset=asset)
        out[f"{kind}/{site}/{start * 1e3:+.0f}mm"] = dict(
            {k: float(r[k][-1]) for k in ("skin_count", "skin_max_um", "dense_count", "dense_max_um", "obj_count",
                                          "obj_max_um", "check_count", "check_max_um")},
            finite=bool(r["finite"]), skin=digest(r["skin"], f"hard/{kind}/{site}/{start * 1e3:+.0f}mm"))
    return out


def part_hoi(device):
    import trimesh
    from tqdm import tqdm

    from physhand_mj.rollout import rollout

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in tqdm(HOI, desc="HOI grasps", file=sys.stderr):
            import physhand_mj as ph
            s = rollout(ph.scene_path(f"hoi_{name}"), steps=36, substeps=10, device=device, out=tmp, progress=False)
            skin = trimesh.load(s["skin"], process=False).vertices
            out[name] = {k: s[k] for k in ("penetration_count", "penetration_max_um", "penetration_avg_um",
                                           "object_in_skin_count", "object_in_skin_max_um", "initial_penetration_count",
                                           "initial_object_in_skin_count", "finite")} | {"skin": digest(skin, f"hoi/{name}")}
    return out


def part_batch(device):
    import physhand_mj as ph
    from physhand_mj.contact import Objects
    from physhand_mj.types import GeomType

    asset, model, data = ph.open_hand_scene("hand_only", "open")
    ids, mount = ph.body_ids(model, asset.body_names), ph.mount_pose(model, data)
    poses = ph.bone_poses_at(model, data, model.key("open").qpos, ids)
    cfg = ph.Config(device=device)
    spec = dict(gtype=GeomType.SPHERE, size=(0.02, 0, 0), name="ball")
    W = 3
    batch = ph.BatchedHands(asset, W, cfg, *mount, objects=[spec])
    skin = batch.skin(0)
    top = skin[np.argmax(skin[:, 2])].astype(float)
    where = [top + [0.0, 0.1, 0.05]] * W
    where[1] = top + [0.0, 0.0, 0.018]
    ident = np.array([[1.0, 0.0, 0.0, 0.0]] * W)
    serial = []
    for w in range(W):
        o = Objects(device, 1)
        o.add(GeomType.SPHERE, (0.02, 0, 0), where[w], name="ball")
        s = ph.Solver(ph.make_model(asset, cfg), cfg, objects=o)
        serial.append((s, s.make_state(*mount)))
    for _ in range(4):
        batch.step(np.stack([poses[0]] * W), np.stack([poses[1]] * W), np.stack(where)[:, None], ident[:, None])
        for s, st in serial:
            s.set_body_poses(st, *poses)
            s.step(st)
    return {f"world{w}": dict(batch=digest(batch.positions(w), f"batch/{w}"), serial=digest(serial[w][1].x.numpy(), f"serial/{w}"),
                              max_diff_um=float(np.abs(batch.positions(w) - serial[w][1].x.numpy()).max() * 1e6))
            for w in range(W)}


def compare(a_path, b_path) -> int:
    a, b = json.loads(Path(a_path).read_text()), json.loads(Path(b_path).read_text())
    diffs = []

    def walk(x, y, path):
        if isinstance(x, dict) and isinstance(y, dict):
            for k in sorted(set(x) | set(y)):
                walk(x.get(k), y.get(k), f"{path}/{k}")
        elif x != y:
            diffs.append(f"{path}: {x!r} -> {y!r}")

    for part in sorted(set(a["parts"]) & set(b["parts"])):
        walk(a["parts"][part], b["parts"][part], part)
    print(f"{len(diffs)} differences in parts {sorted(set(a['parts']) & set(b['parts']))}")
    for d in diffs:
        print("  " + d)
    return 1 if diffs else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--parts", default="solver,cone,batch,hard,hoi")
    ap.add_argument("--out", default=None)
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--arrays", default=None, help="also save the positions behind the digests (.npz); with "
                    "--compare A.npz B.npz: the largest position difference per entry (um)")
    a = ap.parse_args()
    if a.compare and a.compare[0].endswith(".npz"):
        x, y = np.load(a.compare[0]), np.load(a.compare[1])
        worst = {k: float(np.abs(x[k].astype(float) - y[k]).max() * 1e6) for k in sorted(set(x) & set(y))}
        print(json.dumps(dict(max_diff_um=worst, largest=max(worst.values(), default=0.0)), indent=1))
        return
    if a.compare:
        sys.exit(compare(*a.compare))
    global SAVED
    SAVED = {} if a.arrays else None
    parts = {}
    for p in a.parts.split(","):
        print(f"fingerprint: {p}", file=sys.stderr)
        parts[p] = globals()[f"part_{p}"](a.device)
    res = dict(device=a.device, parts=parts)
    text = json.dumps(res, indent=1)
    if a.out:
        Path(a.out).write_text(text)
    if a.arrays:
        np.savez_compressed(a.arrays, **SAVED)
    print(text)


if __name__ == "__main__":
    main()
