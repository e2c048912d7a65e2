"""Two-way coupling's pinch against 2 mu N >= m g: the slip onset over a sweep of mu, on two soft pads
and on the hand, and how still a held box stays.

    python benchmarks/two_way_pinch.py [--device cpu|cuda] [--pads PATH] [--no-hand] [--out docs/benchmarks/two_way_pinch_<device>.json]

The pads (physhand_mj/bench/pinch.py, PinchRig): two 24 x 24 mm pads of 4 mm flesh on mocap bodies
squeeze a free 10 g box by 0.4 mm each (gravity off), then gravity is ramped in over 0.2 s, 0.8 s in
all; mu is swept in multiples of the bound with the squeeze's N, and each run's ratio is taken with N
under the full load (the 20 frames after the ramp). Slipped: fell > 10 mm or still falling > 20 mm/s
at the end. Creep: a box held at ~1.2 and ~1.5 x the bound, m/s down over 1 s after the 0.8 s. The hand
(HandPinch): hand_only's pinch keyframe, a 16 x 16 x 3 mm 10 g card between the thumb's and index's
tips, 0.3 s without gravity, then gravity ramped over 0.2 s, 1.3 s in all; N the tips' push along the
card's normal. ``--pads``: pads saved with physhand_mj.asset.save_asset (a machine without TetGen).
"""

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.pinch import G, HandPinch, PinchRig, pinch_pads  # noqa: E402

MASS, DEPTH = 0.01, 0.4e-3


def pad_run(pads, mu, device, extra=0):
    rig = PinchRig(pads, mass=MASS, mu=mu, config=ph.Config(two_way=True, device=device))
    rig.squeeze(DEPTH, frames=40, settle=20)
    out = rig.hold(160, ramp=40)
    zs = list(out["zs"])
    for _ in range(extra):  # held on: the creep
        zs.append(rig.step()["z"])
    slipped = bool(out["drop"] > 0.01 or out["speed"] > 0.02)
    row = dict(mu=round(mu, 4), N=round(out["normal"], 4), ratio=round(mu / (MASS * G / (2 * out["normal"])), 3),
               slipped=slipped, fell_mm=round(out["drop"] * 1e3, 2))
    if extra:
        z = np.array(zs)
        row["creep_mm_s"] = round(float((z[-1 - extra] - z[-1]) / (extra * rig.model.opt.timestep)) * 1e3, 3)
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--pads", default=None, help="saved pads (.npz); default: built here (the build extra)")
    ap.add_argument("--no-hand", action="store_true", help="skip the hand's pinch")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/two_way_pinch_<device>.json)")
    args = ap.parse_args()
    from physhand_mj.asset import load_asset

    pads = load_asset(args.pads) if args.pads else pinch_pads()
    rig = PinchRig(pads, mass=MASS, mu=0.5, config=ph.Config(two_way=True, device=args.device))
    n_squeeze = rig.squeeze(DEPTH, frames=40, settle=20)
    bound = MASS * G / (2 * n_squeeze)
    out = dict(device=device_name(args.device), N_squeeze=round(n_squeeze, 4), pads=[], creep=[], hand=[])
    for r in (0.9, 1.1, 1.15, 1.2, 1.25, 1.3, 1.5):
        out["pads"].append(dict(x_squeeze_bound=r, **pad_run(pads, r * bound, args.device)))
        print(out["pads"][-1], flush=True)
    for r in (1.35, 1.65):
        out["creep"].append(dict(x_squeeze_bound=r, **pad_run(pads, r * bound, args.device, extra=200)))
        print(out["creep"][-1], flush=True)
    if not args.no_hand:
        for mu in (0.2, 0.22, 0.25, 0.265, 0.28, 0.3, 0.5):
            h = HandPinch(mu=mu, mass=MASS, config=ph.Config(two_way=True, device=args.device))
            moved = h.settle(60)
            o = h.hold(200, ramp=40)
            slipped = bool(o["drop"] > 0.01 or o["speed"] > 0.02)
            out["hand"].append(dict(mu=mu, N=round(o["normal"], 4), ratio=round(mu / (MASS * G / (2 * o["normal"])), 3),
                                    slipped=slipped, fell_mm=round(o["drop"] * 1e3, 2), settled_mm=round(moved * 1e3, 2),
                                    turned_deg=round(o["turned"], 2),
                                    proxy_contacts=o["proxy_contacts"]))
            print(out["hand"][-1], flush=True)
    for name in ("pads", "hand"):
        rows = out[name]
        slip = [r["ratio"] for r in rows if r["slipped"]]
        held = [r["ratio"] for r in rows if not r["slipped"]]
        if slip and held:
            out[f"{name}_onset"] = dict(largest_slipping=max(slip), smallest_holding=min(held),
                                        midpoint=round(0.5 * (max(slip) + min(held)), 3))
            print(name, out[f"{name}_onset"], flush=True)
    path = Path(args.out or Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / f"two_way_pinch_{args.device.split(':')[0]}.json")
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(path)


if __name__ == "__main__":
    main()
