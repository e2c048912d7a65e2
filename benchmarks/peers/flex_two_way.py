"""MuJoCo's flex beside physhand_mj's two-way skin on the soft slab: a box on a tilted slab (stick
below atan(mu) - 2 degrees, slide above atan(mu) + 2) and a box dropped onto it (rest force, bounces,
penetration), with the time per 5 ms frame (issue 52's item 6).

    python benchmarks/peers/flex_two_way.py [--slab SLAB.npz] [--mu 0.3,0.6,1.0] [--hold 120]
                                            [--out docs/benchmarks/flex_two_way_cpu.json]

Both run the same slab (physhand_mj/bench/slab.py's :func:`soft_slab`: 80 x 80 mm, 6 mm of flesh
over a pinned core; ``--slab`` a saved one, else built here with TetGen) and a free 30 x 30 x 20 mm
box of 100 g whose geom friction is mu (MuJoCo's larger-of-two rule: the flex's and the slab's skin
coefficient are set to 0, so mu decides on both sides).

- physhand_mj: :class:`~physhand_mj.bench.slab.SlabRig` (``Config(two_way=True)``), the tilt the
  box's gravity turned by -angle about x as the flex's (the flesh's own weight stays along -z);
- MuJoCo flex: the slab's tets as one dim-3 flex (``peers/mujoco_flex.flex_spec``: each skin and
  flesh vertex a body on three slide joints, the core's vertices in the world body; young 30 kPa,
  poisson 0.3, contact solref 0.2 ms as the hand's flex in docs/peers.md, Euler at 0.05 ms, 100
  steps a frame: at the hand's 0.1 ms the slab's flex diverged in its first step), the box on a free joint; the tilt is the gravity turned by -angle about x (the
  same load in the slab's frame, since its core is pinned).

Protocol (each peer, each mu, each angle atan(mu) -/+ 2 degrees): ``--level`` frames level (the box
starts 1 mm over the skin), ``--turn`` frames turning to the angle at a steady rate, ``--hold``
frames held; ``slid_mm`` is the box's move down the slope over the hold, ``speed_mm_s`` its speed
over the last 5 frames. Drop: the box from 1 mm, 200 frames level; ``rest_force_over_mg``
(physhand_mj: the skin's force on the box, its report; flex: MuJoCo's contact forces on the box, summed
over its contacts), ``peaks_mm`` (the box's heights over its rest at the local maxima after the first
contact: bounces decay when they fall), and both penetration measures at the end
(``physhand_mj.contact`` measure kernels on either body's vertex positions: skin samples inside the
box, order 5 and 9; box surface points inside the closed skin).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import physhand_mj as ph  # noqa: E402
from common import Measure  # noqa: E402
from mujoco_flex import flex_spec  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402
from physhand_mj.bench.slab import SlabRig, soft_slab  # noqa: E402
from physhand_mj.types import GeomType  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
MASS = 0.1  # kg
HALF = (0.015, 0.015, 0.01)  # m
GAP = 1.0e-3  # m: the box starts this far over the skin's top
STEPS = 100  # flex steps a 5 ms frame (0.05 ms, Euler: at 0.1 ms the slab's flex diverged in its first step)
SOLREF = (0.0002, 1.0)  # the flex contact's time constant (s) and damping ratio: as docs/peers.md's runs


class BoxMeasure(Measure):
    """Both penetration measures of a slab's vertex positions against the box (common.Measure's,
    on the box instead of a case's object)."""

    def __init__(self, asset):
        from physhand_mj.contact import Objects

        cfg = ph.Config(device="cpu")
        self.objects = Objects("cpu", 1)
        self.objects.add(GeomType.BOX, HALF, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), name="box")
        self.solver = ph.Solver(ph.make_model(asset, cfg), cfg, objects=self.objects)
        self.state = self.solver.make_state()
        self.n = asset.n_vertices


class FlexSlab:
    """The slab as a MuJoCo flex with a free box over it; ``tilt`` turns gravity."""

    def __init__(self, asset, mu: float):
        s = flex_spec(asset, None, poisson=0.3, steps=STEPS, integrator="euler", solref=SOLREF)
        s.flexes[0].friction = [0.0, 0.005, 0.0001]
        top = float(asset.skin_vertices[:, 2].max())
        b = s.worldbody.add_body(name="box", pos=[0.0, 0.0, top + HALF[2] + GAP])
        b.add_freejoint()
        b.add_geom(name="box", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(HALF), mass=MASS, friction=[mu, 0.005, 0.0001],
                   solref=list(SOLREF))
        t = time.perf_counter()
        self.model = s.compile()
        self.compile_s = time.perf_counter() - t
        self.data = mujoco.MjData(self.model)
        self.box = self.model.body("box").id
        self.geom = self.model.geom("box").id
        self.top = top
        mujoco.mj_forward(self.model, self.data)

    def tilt(self, angle: float) -> None:
        self.model.opt.gravity[:] = [0.0, -9.81 * np.sin(angle), -9.81 * np.cos(angle)]

    def frame(self) -> float:
        t = time.perf_counter()
        for _ in range(STEPS):
            mujoco.mj_step(self.model, self.data)
        return (time.perf_counter() - t) * 1e3

    def box_pos(self) -> np.ndarray:  # in the slab's frame (the flex is not turned)
        return self.data.xpos[self.box].copy()

    def box_pose(self):
        return self.data.xpos[self.box].copy(), self.data.xquat[self.box].copy()

    def x(self) -> np.ndarray:
        return self.data.flexvert_xpos.copy()

    def force_z(self) -> float:
        """MuJoCo's contact forces on the box along the slab's normal (N)."""
        m, d = self.model, self.data
        f6 = np.zeros(6)
        total = np.zeros(3)
        for i in range(d.ncon):
            c = d.contact[i]
            if c.geom1 != self.geom and c.geom2 != self.geom:
                continue
            mujoco.mj_contactForce(m, d, i, f6)
            fw = c.frame.reshape(3, 3).T @ f6[:3]  # contact frame -> world; the force on geom2
            total += fw if c.geom2 == self.geom else -fw
        return float(total[2])

    @property
    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.data.qpos)))


class PhysSlab:
    """physhand_mj's SlabRig with the same interface (the box's pose in the table's frame)."""

    def __init__(self, asset, mu: float):
        self.rig = SlabRig(asset, mass=MASS, half=HALF, mu=mu, gap=GAP)
        self.top = self.rig.top
        self.compile_s = 0.0

    def tilt(self, angle: float) -> None:
        # the box's gravity turned, as the flex's (a table turned within 0.2 s throws the box: it slid
        # 160 mm at 2 degrees under atan(0.6)); the flesh's own weight stays along -z (Config.gravity)
        self.rig.model.opt.gravity[:] = [0.0, -9.81 * np.sin(angle), -9.81 * np.cos(angle)]

    def frame(self) -> float:
        t = time.perf_counter()
        self.rig.step()
        return (time.perf_counter() - t) * 1e3

    def box_pos(self) -> np.ndarray:
        return self.rig.state()["pos"]

    def box_pose(self):
        """The box's pose in the slab asset's frame (the table's origin and turn taken out)."""
        from physhand_mj.bench.slab import _quat_mat

        d = self.rig.data
        r = _quat_mat(d.mocap_quat[0])
        pos = r.T @ (d.xpos[self.rig.box] - d.mocap_pos[0])
        q = np.zeros(4)
        qt = np.array(d.mocap_quat[0], float)
        mujoco.mju_mulQuat(q, np.array([qt[0], -qt[1], -qt[2], -qt[3]]), d.xquat[self.rig.box])
        return pos, q

    def x(self) -> np.ndarray:
        from physhand_mj.bench.slab import _quat_mat

        d = self.rig.data
        r = _quat_mat(d.mocap_quat[0])
        xw = self.rig.hand.state.x.numpy().astype(float)
        return (xw - d.mocap_pos[0]) @ r

    def force_z(self) -> float:
        return float(self.rig.state()["force"][2])

    @property
    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.rig.data.qpos)))


def ramp(make, asset, mu: float, angle: float, hold: int, level: int = 40, turn: int = 200) -> dict:
    sim = make(asset, mu)
    ms = []
    for _ in range(level):
        ms.append(sim.frame())
    for k in range(turn):
        sim.tilt(angle * (k + 1) / turn)
        ms.append(sim.frame())
    y0 = float(sim.box_pos()[1])
    ys = []
    for _ in range(hold):
        ms.append(sim.frame())
        ys.append(float(sim.box_pos()[1]))
    y1 = ys[-1]
    speed = (ys[-6] - ys[-1]) / (5 * 0.005) if len(ys) > 5 else float("nan")
    return dict(mu=mu, angle_deg=float(np.degrees(angle)), slid_mm=(y0 - y1) * 1e3, speed_mm_s=speed * 1e3,
                finite=sim.finite, ms_frame=float(np.median(ms)), frames=len(ms))


def drop(make, asset, meas: BoxMeasure, frames: int = 200) -> dict:
    sim = make(asset, 0.5)
    ms, z, f = [], [], []
    for _ in range(frames):
        ms.append(sim.frame())
        z.append(float(sim.box_pos()[2]))
        f.append(sim.force_z())
    z = np.array(z)
    rest = float(np.median(z[-20:]))
    first = int(np.argmax(np.array(f) > 0)) if np.any(np.array(f) > 0) else 0
    zz = z[first:]
    peaks = [float((zz[i] - rest) * 1e3) for i in range(1, len(zz) - 1) if zz[i] > zz[i - 1] and zz[i] >= zz[i + 1]][:6]
    pos, quat = sim.box_pose()
    m = meas(sim.x(), pos, quat)
    return dict(rest_force_over_mg=float(np.mean(f[-20:]) / (MASS * 9.81)), rest_sink_mm=float((sim.top + HALF[2] - rest) * 1e3),
                peaks_mm=peaks, finite=sim.finite, ms_frame=float(np.median(ms)), compile_s=sim.compile_s, **m)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slab", default=None, help="a saved slab asset (.npz); default: built here (TetGen)")
    ap.add_argument("--mu", default="0.3,0.6,1.0", help="friction coefficients (comma-separated)")
    ap.add_argument("--hold", type=int, default=120, help="frames held at the angle (5 ms each)")
    ap.add_argument("--level", type=int, default=40, help="frames level before turning (5 ms each)")
    ap.add_argument("--turn", type=int, default=200, help="frames turning to the angle (5 ms each)")
    ap.add_argument("--drop", type=int, default=200, help="frames of the drop (5 ms each)")
    ap.add_argument("--flex-mu", default="0.6", help="the flex's friction coefficients (its frames cost ~1 s on a CPU)")
    ap.add_argument("--peers", default="physhand_mj,mujoco_flex", help="which to run (comma-separated)")
    ap.add_argument("--out", default=str(ROOT / "docs/benchmarks/flex_two_way_cpu.json"), help="JSON path")
    args = ap.parse_args()
    asset = ph.load_asset(args.slab) if args.slab else soft_slab()
    meas = BoxMeasure(asset)
    makes = {"physhand_mj": PhysSlab, "mujoco_flex": FlexSlab}
    out = dict(device="cpu", cpu=device_name("cpu"), args=vars(args), mass_kg=MASS, box_half_m=list(HALF), flex=dict(young=3.0e4, poisson=0.3, timestep=0.005 / STEPS,
               integrator="euler"), ramps=[], drops=[])
    for peer in args.peers.split(","):
        make = makes[peer]
        d = drop(make, asset, meas, args.drop)
        d["peer"] = peer
        out["drops"].append(d)
        print(json.dumps(d), flush=True)
        for mu in [float(v) for v in (args.flex_mu if peer == "mujoco_flex" else args.mu).split(",")]:
            for sign in (-1, 1):
                r = ramp(make, asset, mu, np.arctan(mu) + sign * np.radians(2.0), args.hold, args.level, args.turn)
                r["peer"] = peer
                out["ramps"].append(r)
                print(json.dumps(r), flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(args.out)


if __name__ == "__main__":
    main()
