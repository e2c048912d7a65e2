"""The demo's contact, frame by frame, by every measure: ``grasp_glass`` from ``approach``.

    python benchmarks/demo_residue.py [--device cpu] [--frames 80] [--scene PATH] [--out JSON]

Steps MuJoCo and ``SoftHand`` (default Config) for ``--frames`` 5 ms frames and after each frame
measures the skin against the glass four ways: skin samples inside the glass on the metric's
order-5 lattice and on an order-9 lattice (no strategy queries those), the contact's own object
points inside the closed skin, and the denser check points (``Contact.check_points``, none of them
a point the feature push works on); and, in MuJoCo, how deep the hand's collision proxies and its
bone meshes (their convex hulls, ``mujoco.mj_geomDistance``) are inside the glass: skin over a bone
that deep cannot be outside it. Prints one JSON line (frames with residue per measure, closing =
frames before 40, held = from 40; worst depths) and writes it with the per-frame rows to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mujoco  # noqa: E402
from tqdm import tqdm  # noqa: E402

import physhand_mj as ph  # noqa: E402
from physhand_mj.bench import device_name  # noqa: E402

HELD = 40  # frames from which the demo's hand holds the glass (it closes over the first ~40)


def hand_depths(model, data, glass: int) -> tuple[float, float]:
    """Deepest collision proxy and deepest bone hull of the hand inside the glass (m, 0 if none)."""
    ft = np.zeros(6)
    proxy = bone = 0.0
    for g in range(model.ngeom):
        name = model.geom(g).name
        if name.endswith("_proxy") or name.endswith("_bone"):
            d = -mujoco.mj_geomDistance(model, data, g, glass, 0.05, ft)
            if name.endswith("_proxy"):
                proxy = max(proxy, d)
            else:
                bone = max(bone, d)
    return proxy, bone


def run(device: str, frames: int, scene: str | None) -> dict:
    model = mujoco.MjModel.from_xml_path(scene or str(ph.scene_path("grasp_glass")))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, ph.Config(device=device))
    c, state = hand.solver.contact, hand.state
    glass = model.geom("glass").id
    rows = []
    for _ in tqdm(range(frames), desc="demo frames", file=sys.stderr):
        mujoco.mj_step(model, data)
        hand.step()
        o5, o9 = c.measure(state, order=5), c.measure(state, order=9, objects_side=False)
        chk = c.measure(state, check=True)
        proxy, bone = hand_depths(model, data, glass)
        rows.append(dict(order5_um=1e6 * o5[2], order9_um=1e6 * o9[2], object_um=1e6 * o5[5],
                         check_um=1e6 * chk[5], proxy_mm=1e3 * proxy, bone_mm=1e3 * bone))
    out = dict(device=device_name(device), frames=frames, scene=scene or "grasp_glass")
    for k in ("order5_um", "order9_um", "object_um", "check_um"):
        v = np.array([r[k] for r in rows])
        out[k.replace("_um", "")] = dict(frames=int((v > 0).sum()), held_frames=int((v[HELD:] > 0).sum()),
                                         worst_um=round(float(v.max()), 2), held_worst_um=round(float(v[HELD:].max(initial=0)), 2))
    for k in ("proxy_mm", "bone_mm"):
        v = np.array([r[k] for r in rows])
        out[k.replace("_mm", "")] = dict(worst_mm=round(float(v.max()), 2), held_worst_mm=round(float(v[HELD:].max(initial=0)), 2))
    out["rows"] = [{k: round(float(v), 3) for k, v in r.items()} for r in rows]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="Warp device: cpu or cuda[:N]")
    ap.add_argument("--frames", type=int, default=80, help="5 ms frames (count)")
    ap.add_argument("--scene", default=None, help="MJCF path (default: the shipped grasp_glass.xml)")
    ap.add_argument("--out", default=None, help="JSON path for the summary and per-frame rows")
    a = ap.parse_args()
    out = run(a.device, a.frames, a.scene)
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}), flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
