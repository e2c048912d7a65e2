"""The Jacobi gather of a batch (``integrate.apply_jacobi`` on the gather path, solver/gather.py) in
other layouts, one launch at a time: which reads the slots fastest.

Each movable vertex sums the correction slots its constraints wrote (~7-15 per group, 12 bytes each,
scattered over the family's corner-major slot blocks). Variants, all on the tiled model of a batch
of ``--worlds`` hands (solver.worlds.tile_model_arrays), the slots filled with random corrections:

- ``thread``: a thread per vertex walking its CSR row (``apply_jacobi`` with one lane: the kernel
  as it was);
- ``lanes<L>``: ``apply_jacobi`` with L neighbouring lanes per vertex, lane l summing entries l,
  l + L, ... of the row, then a shuffle reduction (more loads in flight, the row's slot ids read
  together; the solver's scheme since 2026-11-25: gather.GATHER_LANES);
- ``morton``: a thread per vertex, vertices taken in Morton order of their rest positions (a
  warp's rows then name neighbouring constraints); ``morton_lanes<L>`` both;

    python benchmarks/gather_layouts.py [--device cuda] [--worlds 256] [--launches 50]

Prints (and writes docs/benchmarks/gather_layouts_<device>.json) ms per launch for the edge and tet
groups, and each variant's largest difference from the one-thread sum. For CUDA: the CPU has no
shuffles (its solver runs one lane), so there the lane variants apply only lane 0's share.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import warp as wp

from physhand_mj.solver.gather import gathered_lanes

ROOT = Path(__file__).resolve().parents[1]


@wp.kernel
def gather_perm(lanes: int, perm: wp.array(dtype=int), vertex_count: wp.array2d(dtype=float), group: int,
                relaxation: float, x: wp.array(dtype=wp.vec3), off: wp.array(dtype=int),
                slot_ids: wp.array(dtype=int), slots: wp.array(dtype=wp.vec3)):
    """integrate.apply_jacobi's gather with the vertices taken in the order ``perm``."""
    t = wp.tid()
    i = perm[t // lanes]
    d = gathered_lanes(off, slot_ids, slots, i, t % lanes, lanes)
    n = vertex_count[group, i]
    if t % lanes == 0 and n > 0.0:
        x[i] = x[i] + d * (relaxation / n)


def main() -> None:
    import physhand_mj as ph
    from physhand_mj.solver.worlds import tile_model_arrays
    from physhand_mj.bench import device_name
    from physhand_mj.solver import integrate
    from physhand_mj.solver.model import model_arrays, morton_code

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cuda")
    p.add_argument("--worlds", type=int, default=256)
    p.add_argument("--launches", type=int, default=50)
    a = p.parse_args()
    wp.init()
    d = a.device
    cfg = ph.Config(device=d, execution=ph.Execution(jacobi_gather=True))
    one = model_arrays(ph.load_asset(), cfg, batch=True)
    m = tile_model_arrays(one, a.worlds)
    n = m["n_vertices"]
    rng = np.random.default_rng(0)
    counts = wp.array(np.asarray(m["vertex_count"], np.float32), dtype=float, device=d)
    x0 = rng.normal(size=(n, 3)).astype(np.float32)
    perm = wp.array(np.lexsort((morton_code(np.asarray(m["rest_x"], float)), np.asarray(m["vertex_world"]))).astype(np.int32),
                    dtype=int, device=d)
    empty = wp.zeros(0, dtype=wp.vec3, device=d)
    rows = []
    for group, name in ((0, "edge"), (1, "tet")):
        off = wp.array(m["gather_off"][group], dtype=int, device=d)
        ids = wp.array(m["gather_slot"][group], dtype=int, device=d)
        n_slots = int(m["gather_slot"][group].max()) + 1
        slots = wp.array(rng.normal(size=(n_slots, 3)).astype(np.float32) * 1e-3, dtype=wp.vec3, device=d)
        def shipped(x, lanes):  # integrate.apply_jacobi (lanes 1: the kernel as it was)
            wp.launch(integrate.apply_jacobi, n * lanes, inputs=[counts, group, 1.0, x, empty, off, ids, slots, lanes],
                      device=d)

        def morton(x, lanes):
            wp.launch(gather_perm, n * lanes, inputs=[lanes, perm, counts, group, 1.0, x, off, ids, slots], device=d)

        variants = {"thread": lambda x: shipped(x, 1), "morton": lambda x: morton(x, 1)}
        for lanes in (2, 4, 8):
            variants[f"lanes{lanes}"] = lambda x, lanes=lanes: shipped(x, lanes)
            variants[f"morton_lanes{lanes}"] = lambda x, lanes=lanes: morton(x, lanes)
        ref = None
        for key, run in variants.items():
            x = wp.array(x0, dtype=wp.vec3, device=d)
            run(x)
            wp.synchronize_device(d)
            got = x.numpy() - x0
            if ref is None:
                ref = got
            for _ in range(3):
                run(x)
            wp.synchronize_device(d)
            t = time.perf_counter()
            for _ in range(a.launches):
                run(x)
            wp.synchronize_device(d)
            ms = (time.perf_counter() - t) * 1e3 / a.launches
            row = dict(group=name, variant=key, ms_per_launch=round(ms, 4),
                       max_diff=float(np.abs(got - ref).max()), reads=int(len(m["gather_slot"][group])))
            print(json.dumps(row), flush=True)
            rows.append(row)
    out = ROOT / "docs" / "benchmarks" / f"gather_layouts_{'cuda' if 'cuda' in d else 'cpu'}.json"
    out.write_text(json.dumps(dict(device=device_name(d), worlds=a.worlds, rows=rows), indent=1) + "\n")
    print(json.dumps(dict(device=device_name(d), out=str(out.relative_to(ROOT)))))


if __name__ == "__main__":
    main()
