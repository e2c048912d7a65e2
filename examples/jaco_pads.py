"""Soft fingertip pads on a robot gripper: the Kinova Jaco hand from dm-control closes on a cylinder
under position control; the same SoftHand coupling as the human hand deforms the pads.

Run:  python examples/jaco_pads.py [OUT_DIR]
Success looks like: the fingers close within about 0.25 s, then a steady contact report (about 100
pad vertices on the cylinder, a force of about 2 N, penetration near zero) and OUT_DIR/jaco_pads.png.
"""

import sys
from pathlib import Path

import physhand_mj as ph  # before mujoco: it picks MuJoCo's offscreen GL backend (MUJOCO_GL)
import mujoco  # noqa: E402
from physhand_mj import figures
from physhand_mj.render import make_renderer, write_png
from physhand_mj.robots import jaco_pads_scene


def main(out: Path, steps: int = 200) -> dict:
    model, data, pads = jaco_pads_scene()  # MjSpec: dm-control's jaco_hand.xml + pad skin + actuators + cylinder
    hand = ph.SoftHand(model, data, asset=pads, settle_frames=2)  # the pads asset instead of the hand's
    print("step  finger q (rad)  pad vertices  force N  penetration um")
    for i in range(steps):
        mujoco.mj_step(model, data)
        hand.step()
        if i % 50 == 49:
            obj = hand.contacts()["objects"]["object"]
            print(f"{i + 1:4d}  {data.qpos[0]:14.3f}  {len(obj['vertices']):12d}  {obj['force_n']:7.3f}  "
                  f"{hand.metrics()['penetration_max_um']:14.2f}")
    renderer = make_renderer(model, 640, 480)
    try:
        cam = figures.contact_camera(hand.skin_vertices, distance=0.35, azimuth=150, elevation=-20)
        png = write_png(figures.render_contact_frame(renderer, model, data, hand, cam), out / "jaco_pads.png")
    finally:
        renderer.close()
    return dict(picture=png, hand=hand)


def test_final(tmp_path=None):
    res = main(Path(tmp_path or "example_out"), steps=150)
    hand = res["hand"]
    obj = hand.contacts()["objects"]["object"]
    assert len(obj["vertices"]) > 20 and obj["force_n"] > 0.1, obj
    m = hand.metrics()
    assert m["finite"] and m["penetration_max_um"] < 100.0, m
    assert res["picture"].stat().st_size > 10_000


if __name__ == "__main__":
    print(main(Path(sys.argv[1] if len(sys.argv) > 1 else "example_out"))["picture"])
