"""What one CUDA graph node costs on this GPU: the floor under a frame of many small launches.

Captures graphs of N nodes of one kind and times their replay (median of repeats, compile and
capture excluded), as microseconds per node:
- ``empty``: a kernel of one thread that does nothing;
- ``list_idle``: a list-walking kernel of 20,960 threads whose list is empty (every thread reads the
  count and returns), with and without the launch cap (physhand_mj.launch.LIST_BLOCKS_PER_SM);
- ``tiled_idle``: a block of 32 threads per entry of an empty 20,960-entry list;
- ``list_work``: the same kernel walking a 300-entry list (an atomic add per entry);
- ``cond_off`` / ``cond_on``: a conditional node (``wp.capture_if``) around one empty kernel, with its
  flag 0 / 1.

    python benchmarks/graph_node_cost.py [--device cuda] [--nodes 200]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import warp as wp


@wp.kernel
def empty(a: wp.array(dtype=int)):
    pass


@wp.kernel
def list_walk(count: wp.array(dtype=int), out: wp.array(dtype=int)):
    k = wp.tid()
    if k >= count[0]:
        return
    wp.atomic_add(out, 0, 1)


@wp.kernel
def tiled_walk(count: wp.array(dtype=int), out: wp.array(dtype=int)):
    k, lane = wp.tid()
    if k >= count[0]:
        return
    s = wp.tile_sum(wp.tile(lane))[0]
    if lane == 0:
        wp.atomic_add(out, 0, s)


def time_graph(device, record, nodes: int, repeats: int = 20) -> float:
    """us per node of a graph of ``nodes`` ops made by ``record()`` (median over repeats)."""
    record()  # compile
    wp.synchronize_device(device)
    with wp.ScopedCapture(device=device) as cap:
        for _ in range(nodes):
            record()
    g = cap.graph
    wp.capture_launch(g)
    wp.synchronize_device(device)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        wp.capture_launch(g)
        wp.synchronize_device(device)
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)) / nodes * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--nodes", type=int, default=200, help="nodes per graph (count)")
    a = ap.parse_args()
    d = wp.get_device(a.device)
    if not d.is_cuda:
        raise SystemExit("graph_node_cost needs a CUDA device")
    n = 20960
    cap = 8 * d.sm_count
    z = wp.zeros(1, dtype=int, device=d)
    c0 = wp.zeros(1, dtype=int, device=d)
    c300 = wp.array([300], dtype=int, device=d)
    out = wp.zeros(1, dtype=int, device=d)
    off = wp.zeros(1, dtype=wp.int32, device=d)
    on = wp.ones(1, dtype=wp.int32, device=d)
    cases = {
        "empty": lambda: wp.launch(empty, 1, [z], device=d),
        "list_idle": lambda: wp.launch(list_walk, n, [c0, out], device=d),
        "list_idle_capped": lambda: wp.launch(list_walk, n, [c0, out], device=d, max_blocks=cap),
        "tiled_idle": lambda: wp.launch(tiled_walk, (n, 32), [c0, out], device=d, block_dim=32),
        "tiled_idle_capped": lambda: wp.launch(tiled_walk, (n, 32), [c0, out], device=d, block_dim=32, max_blocks=cap),
        "list_work": lambda: wp.launch(list_walk, n, [c300, out], device=d, max_blocks=cap),
        "cond_off": lambda: wp.capture_if(off, on_true=lambda: wp.launch(empty, 1, [z], device=d)),
        "cond_on": lambda: wp.capture_if(on, on_true=lambda: wp.launch(empty, 1, [z], device=d)),
    }
    res = {k: round(time_graph(d, f, a.nodes), 2) for k, f in cases.items()}
    print(json.dumps(dict(device=f"{d.alias} ({d.name})", nodes=a.nodes, us_per_node=res)))


if __name__ == "__main__":
    main()
