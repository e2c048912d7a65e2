"""hand_hold with gravity along the palm: how far each HOI object moves in 2 s with one-way coupling
(the bones' proxies) and with two-way (the skin), from the same grasp (docs/dm_control.md's table).

Per object the grasp two-way uses by default (the holding grasp where there is one, else the HOI
keyframe squeezed 1.2 x), the same squeeze and the same 0.3 s float without gravity for both; the
reset's ctrl held for 2 s. Prints per run the largest offset from the start, the skin's force on
the object at the end, both penetration measures at the end and the bones' clearance.

Run: ``python benchmarks/hand_hold_table.py [OBJECT ...] [--modes one,two] [--no-proxies]`` (CPU; the box and the
bowl take minutes).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import physhand_mj as ph
from physhand_dmc.suite import hand_hold


def run(obj: str, two_way: bool, seconds: float = 2.0, object_proxies: bool = True) -> dict:
    grasp = "hold" if obj in hand_hold.HOLD_GRASPS else "hoi"
    worst, env = hand_hold.hold_still(obj, seconds, config=ph.Config(two_way=two_way), grasp=grasp,
                                      object_proxies=object_proxies,
                                      squeeze=hand_hold.SQUEEZE if grasp == "hoi" else 1.0,
                                      float_frames=hand_hold.FLOAT_FRAMES)
    h = env.physics.soft
    c, mt = h.contacts()["objects"][obj], h.metrics()
    return dict(grasp=grasp, worst_mm=worst * 1e3, force=np.asarray(c.get("force", np.zeros(3))),
                skin_in=(mt["penetration_count"], mt["penetration_max_um"]),
                obj_in=(mt["object_in_skin_count"], mt["object_in_skin_max_um"]), bone_mm=c["bone_clearance_mm"])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("objects", nargs="*", default=list(hand_hold.OBJECTS))
    p.add_argument("--modes", default="one,two", help="one (one-way), two (two-way), comma separated")
    p.add_argument("--no-proxies", action="store_true",
                   help="take the object out of the hand's proxies' MuJoCo collisions (the skin alone holds it)")
    a = p.parse_args()
    for obj in a.objects:
        for mode in a.modes.split(","):
            t0 = time.perf_counter()
            r = run(obj, mode == "two", object_proxies=not a.no_proxies)
            print(f"{obj} {mode}-way ({r['grasp']}): {r['worst_mm']:.1f} mm; skin force {np.round(r['force'], 2)} N; "
                  f"skin samples in it {r['skin_in'][0]} ({r['skin_in'][1]:.0f} um), its points in the skin "
                  f"{r['obj_in'][0]} ({r['obj_in'][1]:.0f} um); bones {r['bone_mm']:.2f} mm; "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
