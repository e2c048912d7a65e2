"""Per frame, what an HOI grasp's object feature lists hold in a batch (Config.tuning.feature_slack,
Config.feature_list_share): the points listed, each contact stage's list, the slack the next frame
lists with, the worlds the frame's check flagged, and the frame's wall time.

CUDA's path (a thread per feature over its patch) is forced on the CPU with ``--scan``, so the
counts are the GPU's; the frames are timed on the host (one run; compare settings in one process
or interleaved runs only: this host's speed drifts).

    python benchmarks/feature_list_stats.py [--scene box] [--worlds 2] [--frames 16] [--scan]
                                            [--config '{"feature_list_share": 1.0}']
"""

from __future__ import annotations

import argparse
import json
import time



def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="box", help="HOI scene (hoi_<name>)")
    p.add_argument("--worlds", type=int, default=2, help="worlds in the batch")
    p.add_argument("--frames", type=int, default=16, help="5 ms frames after the settling")
    p.add_argument("--scan", action="store_true", help="CUDA's feature kernels (a thread per feature) on the CPU")
    p.add_argument("--config", default="{}", help="Config fields as JSON")
    a = p.parse_args()
    import warp as wp

    import physhand_mj as ph
    from physhand_mj.batch_rollout import replicated_batch
    from physhand_mj.contact.contact import Contact

    if a.scan:
        init = Contact.__init__

        def scan_init(self, *args, **kw):
            init(self, *args, **kw)
            self.tiled_features = self.feature_scan = True

        Contact.__init__ = scan_init
    wp.init()
    hands, (pos, quat, op, oq) = replicated_batch(ph.load_asset(), ph.scene_path(f"hoi_{a.scene}"), "grasp", a.worlds,
                                                  **json.loads(a.config))
    cfg, W = hands.solver.config, a.worlds
    c = hands.solver.contact
    for f in range(a.frames):
        t = time.perf_counter()
        out = hands.step(pos, quat, op, oq)
        ms = (time.perf_counter() - t) * 1e3
        stages = c.feat_stage_counts.numpy()[: cfg.substeps].tolist()
        print(json.dumps(dict(frame=f, ms=round(ms, 1), listed=int(c.feat_count.numpy()[0]), stage_lists=stages,
                              next_slack_mm=[round(float(s) * 1e3, 2) for s in c.slack.numpy()[:W]],
                              flagged=out.get("feature_slack_exceeded"))), flush=True)


if __name__ == "__main__":
    main()
