"""Where a Ray rollout's start goes, piece by piece, in one process (issue 15: the fixed start that
keeps two GPUs below 1.8 x one on short lists).

    python benchmarks/ray_start_split.py [--device cuda] [--runs 2048] [--batch 64]

Times (s): importing physhand_mj; a local ``ray.init``; the first task in a fresh worker with the
GPU tasks' runtime_env (worker start), then the warm-up task's body there (imports, Warp, the
device's context, the asset) and again in the same worker; the driver grouping ``--runs`` copies of
hoi_apple's grasp (every scene loaded); ``ray.shutdown``. One JSON line.
"""

import argparse
import json
import logging
import time

T0 = time.perf_counter()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--runs", type=int, default=2048, help="list length for the grouping (count)")
    ap.add_argument("--batch", type=int, default=64, help="worlds per batch (count)")
    a = ap.parse_args()
    out = {}
    t = time.perf_counter()
    import physhand_mj as ph
    from physhand_mj.batch_rollout import batch_groups
    from physhand_mj.distributed import NOSET_CUDA, _warm
    out["import_physhand_s"] = time.perf_counter() - t
    import ray
    t = time.perf_counter()
    ray.init(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    out["ray_init_s"] = time.perf_counter() - t
    gpu = a.device.startswith("cuda")
    opts = dict(num_cpus=1, num_gpus=1 if gpu else 0)
    if gpu:
        opts["runtime_env"] = {"env_vars": {NOSET_CUDA: "1"}}

    def stamp():
        return time.time()

    t = time.perf_counter()
    ray.get(ray.remote(stamp).options(**opts).remote())
    out["worker_start_s"] = time.perf_counter() - t

    def body(kw):
        s = time.perf_counter()
        _warm(kw)
        return time.perf_counter() - s

    for name in ("warm_body_first_s", "warm_body_again_s"):
        out[name] = ray.get(ray.remote(body).options(**opts).remote(dict(device=a.device)))
    t = time.perf_counter()
    groups, _ = batch_groups([(ph.scene_path("hoi_apple"), "grasp")] * a.runs, a.batch)
    out["group_s"] = time.perf_counter() - t
    t = time.perf_counter()
    ray.shutdown()
    out["ray_shutdown_s"] = time.perf_counter() - t
    out = {k: round(v, 2) for k, v in out.items()}
    out.update(device=a.device, runs=a.runs, batches=len(groups), total_s=round(time.perf_counter() - T0, 2))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
