"""Where a SoftHand frame goes on the CPU: every recorded op of the solver's frame timed on the host.

Warp's timing (``wp.timing_begin``) covers CUDA work only, so on the CPU ``benchmarks/frame_profile.py``
gives frame times but no split. Here each op of the recorded frame (launches, refits, memsets; the
gated blocks' ops too) is wrapped with a host timer: on the CPU a launch runs to its end before it
returns, so the op's wall time is its kernel's. ``--warmup`` frames first (compilation and recording
excluded), then ``--frames`` timed.

    python benchmarks/cpu_op_split.py [--scene grasp_glass] [--key approach] [--warmup 45] [--frames 10]
                                      [--config JSON] [--features bvh|scan|tiled]

``--features`` forces the object side's feature path: ``bvh`` (the CPU's, a BVH walk per feature
after a skin refit per pass), ``scan`` (CUDA batches': a thread per feature over its patch) or
``tiled`` (one CUDA hand's: a block per feature, one thread on the CPU). Prints the frame time and
the top ops (ms per frame, calls per frame).
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

import mujoco

import physhand_mj as ph
from physhand_mj.solver.activity import _Gate
from physhand_mj.solver.solver import _ListLaunch


def op_name(op) -> str:
    if isinstance(op, _ListLaunch):
        return op.cmd.kernel.key
    owner = getattr(op, "__self__", None)
    if owner is not None and hasattr(owner, "kernel"):
        return owner.kernel.key
    return getattr(op, "__qualname__", type(op).__name__)


def wrap(ops: list, spent: dict, calls: dict) -> None:
    """Replace every leaf op of ``ops`` (recursing into gated blocks) by a timed one."""
    for k, op in enumerate(ops):
        if isinstance(op, _Gate):
            wrap(op.sub, spent, calls)
            continue

        def timed(op=op, name=op_name(op)):
            t = time.perf_counter()
            op()
            spent[name] += time.perf_counter() - t
            calls[name] += 1

        ops[k] = timed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="grasp_glass", help="shipped scene (physhand_mj.scene_path)")
    p.add_argument("--key", default="approach", help="keyframe to start from")
    p.add_argument("--warmup", type=int, default=45, help="untimed 5 ms frames first (count)")
    p.add_argument("--frames", type=int, default=10, help="timed 5 ms frames (count)")
    p.add_argument("--config", default="{}", help="Config fields as JSON")
    p.add_argument("--features", default="bvh", choices=("bvh", "scan", "tiled"), help="the feature path forced")
    p.add_argument("--top", type=int, default=22, help="ops listed (count)")
    a = p.parse_args()
    if a.features != "bvh":  # CUDA's feature kernels, forced on the CPU (as tests/test_batch.py does)
        from physhand_mj.contact.contact import Contact

        init = Contact.__init__

        def forced(self, *args, **kw):
            init(self, *args, **kw)
            self.tiled_features = True
            self.feature_scan = a.features == "scan"

        Contact.__init__ = forced
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path(a.scene)))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key(a.key).id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config.from_dict(dict(device="cpu", **json.loads(a.config))))
    for _ in range(a.warmup):
        mujoco.mj_step(model, data)
        hand.step()
    spent, calls = defaultdict(float), defaultdict(int)
    for ops in hand.solver._ops.values():
        wrap(ops, spent, calls)
    t0 = time.perf_counter()
    for _ in range(a.frames):
        mujoco.mj_step(model, data)
        out = hand.step()
    frame = (time.perf_counter() - t0) * 1e3 / a.frames
    what = {k: out[k] for k in ("triangles_tested", "features_listed", "ops_run") if k in out}
    print(json.dumps(dict(scene=a.scene, features=a.features, frame_ms=round(frame, 2),
                          ops_ms=round(sum(spent.values()) * 1e3 / a.frames, 2), **what)))
    for name, s in sorted(spent.items(), key=lambda kv: -kv[1])[: a.top]:
        print(f"{s * 1e3 / a.frames:8.2f} ms  {calls[name] / a.frames:6.1f}/frame  {name}")


if __name__ == "__main__":
    main()
