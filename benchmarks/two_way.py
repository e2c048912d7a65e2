"""Two-way coupling (Config.two_way) against analytic references on the flat soft slab, and its cost.

    python benchmarks/two_way.py [--device cpu|cuda] [--slab PATH] [--out docs/benchmarks/two_way_<device>.json]

The rig (physhand_mj/bench/slab.py): an 80 x 80 mm slab, 6 mm of flesh over a rigid core on a mocap
table, a 30 x 30 x 20 mm box. Measured: a 100 g box dropped from 1 mm (200 frames) and 50 g / 200 g
boxes laid on the skin (120 frames): the skin's mean force over the last 50 frames against m g, the
box's height range over the first and last 50 frames, how deep it sinks, both penetration measures,
Newton's third law (the largest |sum of forces on objects + on bones| over the frames); the table
tilted until the box slides (slab.slide_angle) at mu 0.3, 0.6, 1.0 against atan(mu); and the cost: a
box held (mocap) 0.3 mm into the skin and sliding 3 mm to and fro, one-way against two-way, the same
contact, alternating runs in one process, median ms of mj_step + SoftHand.step. ``--slab``: a slab
saved with physhand_mj.asset.save_asset (a machine without TetGen); default: built here.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.slab import SlabRig, slide_angle, soft_slab  # noqa: E402


def rest(asset, device, mass, gap, frames, trace=None):
    rig = SlabRig(asset, mass=mass, mu=0.5, gap=gap, config=ph.Config(two_way=True, device=device))
    r = []
    for _ in range(frames):
        s = rig.step()
        w = rig.hand.solver.contact.two_way.wrenches()
        r.append((s["height"], s["force"][2], s["penetration"], s["object_in_skin"],
                  np.abs(w["objects"].sum(0)[:3] + w["bones"].sum(0)[:3]).max()))
    r = np.array(r)
    if trace is not None:
        trace.append((mass, r[:, 0].copy(), r[:, 1].copy()))
    return dict(mass_kg=mass, frames=frames, force_n=round(float(r[-50:, 1].mean()), 5), mg_n=round(mass * 9.81, 5),
                swing_first_mm=round(float(np.ptp(r[:50, 0])) * 1e3, 4), swing_last_mm=round(float(np.ptp(r[-50:, 0])) * 1e3, 4),
                sink_mm=round(float(rig.half[2] - r[-40:, 0].mean()) * 1e3, 4),
                penetration_max=int(r[-50:, 2].max()), object_in_skin_max=int(r[-50:, 3].max()),
                third_law_max_n=float(r[:, 4].max()))


def cost(asset, device, frames=75, skip=15):
    top = float(asset.skin_vertices[:, 2].max())
    res = {False: [], True: []}
    for _ in range(2):
        for two in (False, True):
            xml = f"""<mujoco><option timestep="0.005"/><worldbody><body name="table" mocap="true" pos="0 0 0.1"/>
              <body name="box" mocap="true" pos="0 0.003 {0.1 + top + 0.01 - 3e-4}"><geom name="box" type="box" size="0.015 0.015 0.01"/></body>
              </worldbody></mujoco>"""
            m = mujoco.MjModel.from_xml_string(xml)
            d = mujoco.MjData(m)
            mujoco.mj_forward(m, d)
            h = ph.SoftHand(m, d, ph.Config(two_way=two, device=device), asset=asset, writeback=False, settle_frames=2)
            t = []
            for f in range(frames):
                d.mocap_pos[1][1] = 0.003 * np.cos(f * 0.05)  # the box slides a little: friction works
                t0 = time.perf_counter()
                mujoco.mj_step(m, d)
                h.step()
                t.append(time.perf_counter() - t0)
            res[two].append(float(np.median(t[skip:])) * 1e3)
    one, two = min(res[False]), min(res[True])
    return dict(one_way_ms=round(one, 3), two_way_ms=round(two, 3), ratio=round(two / one, 3), runs_ms=res)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device (cpu, cuda)")
    ap.add_argument("--slab", default=None, help="a saved slab asset (.npz); default: built here (the build extra)")
    ap.add_argument("--out", default=None, help="JSON path (default docs/benchmarks/two_way_<device>.json)")
    args = ap.parse_args()
    from physhand_mj.asset import load_asset

    asset = load_asset(args.slab) if args.slab else soft_slab()
    out = dict(device=device_name(args.device), rest=[], ramp=[], cost=None)
    traces, tracks = [], []
    for mass, gap, frames in ((0.1, 1e-3, 200), (0.05, -2e-4, 120), (0.2, -2e-4, 120)):
        out["rest"].append(rest(asset, args.device, mass, gap, frames, traces))
        print(out["rest"][-1], flush=True)
    for mu in (0.3, 0.6, 1.0):
        rig = SlabRig(asset, mass=0.1, mu=mu, gap=-3.5e-4, config=ph.Config(two_way=True, device=args.device))
        r = slide_angle(rig, np.arctan(mu) - np.radians(8.0))
        tracks.append((mu, r["track"]))
        out["ramp"].append(dict(mu=mu, atan_deg=round(float(np.degrees(np.arctan(mu))), 2),
                                slid_deg=round(float(np.degrees(r["angle"])), 2), moved_mm=round(r["moved"] * 1e3, 3)))
        print(out["ramp"][-1], flush=True)
    out["cost"] = cost(asset, args.device)
    print(out["cost"], flush=True)
    path = Path(args.out or Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / f"two_way_{args.device.split(':')[0]}.json")
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(path)
    plot(traces, tracks, out["device"], path.parents[1] / "images" / f"two_way_{args.device.split(':')[0]}.png")


def plot(traces, tracks, device: str, path: Path) -> None:
    """Left: the skin's force on each box against time, m g dashed; right: how far the box moved down
    the tilting table against the table's angle, atan(mu) dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for (mass, _, force), c in zip(traces, ("C0", "C1", "C2")):
        t = np.arange(1, len(force) + 1) * 5.0
        a.plot(t, force, c, lw=1, label=f"{mass * 1e3:.0f} g")
        a.axhline(mass * 9.81, color=c, ls="--", lw=0.8)
    a.set(xlabel="time (ms)", ylabel="skin force on the box, vertical (N)", title="a box laid or dropped on the skin (m g dashed)")
    a.legend()
    for (mu, tr), c in zip(tracks, ("C0", "C1", "C2")):
        b.plot(np.degrees(tr[:, 0]), tr[:, 1] * 1e3, c, label=f"mu {mu}")
        b.axvline(np.degrees(np.arctan(mu)), color=c, ls=":", lw=1)
    b.set(xlabel="table angle (deg)", ylabel="box moved down the slope (mm)", ylim=(-1, 12),
          title="the tilting table (atan(mu) dotted)")
    b.legend()
    fig.suptitle(f"two-way coupling on the soft slab, {device}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(path)


if __name__ == "__main__":
    main()
