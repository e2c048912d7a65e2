"""What the mesh distance grid (contact/objects.mesh_grid, Config.execution.mesh_grid) saves, and that it
changes nothing: the HOI bowl (a 1,408-face mesh) grasped by SoftHand with each grid spacing, and
the grid's answers against the exact BVH query at points around the bowl.

    python benchmarks/mesh_grid.py [--device cpu|cuda] [--frames 12] [--spacings 0,0.001,0.002]
                                   [--config '{"multires_registers": 128}']
                                   [--out docs/benchmarks/mesh_grid_<device>.json]

Per spacing (m; 0 = no grid, every query walks the BVH): SoftHand setup time (s, includes building
the grid), the median ms of ``SoftHand.step`` over frames 3..N (device synchronised; the first
frames compile and record), both penetration measures at the end (order-9 skin samples, check
points), and the largest skin difference from the run without a grid (um; 0 = bit for bit). Then,
on 200k points (half within 2 mm of the bowl's surface, half anywhere on its grid): the share the
grid answers, the largest gap between its lower bound and the exact distance (um), whether every
point below sdf_mesh.GRID_BAND equals the exact query, and us per query each way. One JSON document.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import mujoco
import numpy as np
import warp as wp

import physhand_mj as ph
from physhand_mj.bench import device_name
from physhand_mj.contact import Objects
from physhand_mj.contact.objects import GRID_PAD
from physhand_mj.contact.sdf import geom_sdf
from physhand_mj.contact.sdf_mesh import GRID_BAND
from physhand_mj.types import GeomType

ROOT = Path(__file__).resolve().parents[1]


@wp.kernel
def _phi(size: wp.vec3, ids: wp.vec2ul, p: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = geom_sdf(int(GeomType.MESH), p[i], size, ids)


def run_scene(device: str, spacing: float, frames: int, extra: dict | None = None) -> dict:
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("hoi_bowl")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("grasp").id)
    mujoco.mj_forward(model, data)
    t0 = time.perf_counter()
    hand = ph.SoftHand(model, data, ph.Config(device=device, **(extra or {}), execution=ph.Execution(mesh_grid=spacing)))
    setup = time.perf_counter() - t0
    ms = []
    for _ in range(frames):
        mujoco.mj_step(model, data)
        wp.synchronize_device(device)
        t = time.perf_counter()
        hand.step()
        wp.synchronize_device(device)
        ms.append((time.perf_counter() - t) * 1e3)
    m = hand.penetration(order=9, check=True)
    return dict(spacing_m=spacing, setup_s=round(setup, 3), ms_per_frame=round(float(np.median(ms[2:])), 3),
                order9_count=m["penetration_count"], order9_max_um=round(m["penetration_max_um"], 3),
                check_count=m["object_in_skin_count"], check_max_um=round(m["object_in_skin_max_um"], 3),
                skin=hand.skin_vertices.copy())


def query_accuracy(device: str, spacing: float, n: int = 200_000) -> dict:
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("hoi_bowl")))
    mid = int(model.geom_dataid[model.geom("bowl").id])  # the bowl geom's mesh
    va, vn = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
    fa, fn = model.mesh_faceadr[mid], model.mesh_facenum[mid]
    v, f = model.mesh_vert[va: va + vn].astype(float), model.mesh_face[fa: fa + fn]
    objs = Objects(device, 1)
    objs.add(GeomType.MESH, None, vertices=v, faces=f, name="bowl", mesh_range=0.5, mesh_grid_spacing=spacing)
    rng = np.random.default_rng(0)
    tri = v[f]
    pick = rng.integers(0, len(f), n // 2)
    bc = rng.dirichlet([1, 1, 1], n // 2)
    near = (tri[pick] * bc[:, :, None]).sum(1) + rng.normal(0.0, 2e-3, (n // 2, 3))
    lo, hi = v.min(0) - GRID_PAD, v.max(0) + GRID_PAD
    p = np.concatenate([near, rng.uniform(lo, hi, (n - n // 2, 3))]).astype(np.float32)
    pw = wp.array(p, dtype=wp.vec3, device=device)
    size = wp.vec3(*objs._host["size"][0])
    ids = objs._host["mesh"][0]
    out = {}
    for name, grid in (("exact", 0), ("grid", int(ids[1]))):
        phi = wp.zeros(n, dtype=float, device=device)
        args = [size, wp.vec2ul(int(ids[0]), grid), pw]
        wp.launch(_phi, n, inputs=args, outputs=[phi], device=device)  # compile, warm
        wp.synchronize_device(device)
        best = np.inf
        for _ in range(5):
            t = time.perf_counter()
            wp.launch(_phi, n, inputs=args, outputs=[phi], device=device)
            wp.synchronize_device(device)
            best = min(best, time.perf_counter() - t)
        out[name] = (phi.numpy().astype(float), best / n * 1e6)
    exact, grid = out["exact"][0], out["grid"][0]
    close = exact < GRID_BAND
    answered = grid != exact
    return dict(spacing_m=spacing, points=n, answered_by_grid=round(float(answered.mean()), 4),
                below_band_identical=bool(np.array_equal(grid[close], exact[close])),
                never_above_exact=bool(np.all(grid <= exact + 1e-7)),
                max_gap_um=round(float((exact - grid).max() * 1e6), 1),
                us_per_query_exact=round(out["exact"][1], 4), us_per_query_grid=round(out["grid"][1], 4))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--frames", type=int, default=12, help="5 ms frames per run (the first 2 are not timed)")
    ap.add_argument("--spacings", default="0,0.001,0.002", help="grid spacings to compare (m, comma-separated)")
    ap.add_argument("--config", default="{}", help="other Config fields as JSON, for every run")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/mesh_grid_<device>.json)")
    a = ap.parse_args()
    extra = json.loads(a.config)
    spacings = [float(s) for s in a.spacings.split(",")]
    rows, ref = [], None
    for s in spacings:
        r = run_scene(a.device, s, a.frames, extra)
        skin = r.pop("skin")
        ref = skin if ref is None else ref
        r["max_skin_diff_um"] = round(float(np.abs(skin - ref).max() * 1e6), 4)
        rows.append(r)
        print(json.dumps(r), flush=True)
    queries = [query_accuracy(a.device, s) for s in spacings if s > 0]
    for q in queries:
        print(json.dumps(q), flush=True)
    doc = dict(device=device_name(a.device), frames=a.frames, config=extra, scene="hoi_bowl/grasp", rows=rows, queries=queries)
    out = Path(a.out) if a.out else ROOT / "docs" / "benchmarks" / f"mesh_grid_{a.device.split(':')[0]}.json"
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
