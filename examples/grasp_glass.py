"""The soft hand in a MuJoCo scene: position actuators close the hand on a glass, MuJoCo's collision
proxies stop the bones at the glass, and SoftHand deforms the skin around it every step.

Run:  python examples/grasp_glass.py [OUT_DIR]
Success looks like: per 20 frames the contact area (cm^2), force estimate (N) and remaining
penetration (um, near zero), then OUT_DIR/grasp_glass.png with the contact pressure as coloured dots.
"""

import sys
from pathlib import Path

import physhand_mj as ph  # before mujoco: it picks MuJoCo's offscreen GL backend (MUJOCO_GL)
import mujoco  # noqa: E402
from physhand_mj import figures
from physhand_mj.render import make_renderer, write_png


def main(out: Path, frames: int = 80) -> dict:
    model = mujoco.MjModel.from_xml_path(str(ph.scene_path("grasp_glass")))  # includes ../hand/myohand.xml
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("approach").id)  # open hand, closing targets in ctrl
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data)  # bones, skin geom and object geoms found by name
    print("frame  area cm2  force N  penetration um")
    for f in range(frames):
        mujoco.mj_step(model, data)
        hand.step()
        if f % 20 == 19:
            glass = hand.contacts()["objects"]["glass"]
            m = hand.metrics()
            print(f"{f + 1:5d}  {glass['area_m2'] * 1e4:8.2f}  {glass['force_n']:7.3f}  {m['penetration_max_um']:14.2f}")
    renderer = make_renderer(model, 960, 720)
    try:
        png = write_png(figures.render_contact_frame(renderer, model, data, hand,
                                                     figures.contact_camera(hand.skin_vertices)), out / "grasp_glass.png")
    finally:
        renderer.close()
    return dict(picture=png, hand=hand)


def test_final(tmp_path=None):
    res = main(Path(tmp_path or "example_out"), frames=40)
    glass = res["hand"].contacts()["objects"]["glass"]
    assert glass["force_n"] > 0 and len(glass["vertices"]) > 10, glass
    assert res["hand"].metrics()["finite"]
    assert res["picture"].stat().st_size > 20_000


if __name__ == "__main__":
    print(main(Path(sys.argv[1] if len(sys.argv) > 1 else "example_out"))["picture"])
