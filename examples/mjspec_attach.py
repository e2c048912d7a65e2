"""Add the soft hand to your own scene with mujoco.MjSpec: build a scene in code, attach the hand's
MJCF under a name prefix, move the hand's mocap mount, and let SoftHand keep the skin on the bones
and off the objects.

Run:  python examples/mjspec_attach.py [OUT_DIR]
Success looks like: the palm-down hand (names prefixed `left_`) lowered 0.5 mm per frame onto a ball
until 2 mm past first contact, a line per 10 frames with the contact force on the ball (N): zero,
then positive once the palm touches; and OUT_DIR/mjspec_attach.png.
"""

import sys
from pathlib import Path

import numpy as np

import physhand_mj as ph  # before mujoco: it picks MuJoCo's offscreen GL backend (MUJOCO_GL)
import mujoco  # noqa: E402
from physhand_mj import figures
from physhand_mj.render import make_renderer, write_png


def palm_point(asset, mount_pos, mount_quat):
    """World position of the palm skin over the middle finger's metacarpal head, for a mount pose."""
    from physhand_mj.rotations import quat_to_mat

    n = np.asarray(asset.meta["palm_normal"])
    names = list(asset.body_names)
    c = asset.body_rest_pos[names.index("3proxph_r")] - 0.02 * np.asarray(asset.meta["finger_axis"])
    skin = asset.skin_vertices
    near = np.linalg.norm((skin - c) - np.outer((skin - c) @ n, n), axis=1) < 0.01
    s = skin[near][np.argmax((skin[near] - c) @ n)]
    return quat_to_mat(mount_quat) @ s + mount_pos


def build_scene(asset, radius=0.03, gap=0.01):
    """A floor, a ball 10 mm under the palm skin, and the hand's MJCF attached with the prefix `left_`."""
    scene = mujoco.MjSpec()
    scene.worldbody.add_light(pos=[0, -0.3, 0.8], dir=[0, 0.3, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    scene.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.5, 0.5, 0.01])
    hand = mujoco.MjSpec.from_file(str(ph.HAND_XML))  # mjcf/hand/myohand.xml: bones, proxies, skin mesh, actuators
    mount = hand.body("hand_mount")
    from physhand_mj.rotations import quat_to_mat

    palm = palm_point(asset, np.array(mount.pos), np.array(mount.quat))
    skin = asset.skin_vertices @ quat_to_mat(np.array(mount.quat)).T + np.array(mount.pos)
    below = np.linalg.norm(skin[:, :2] - palm[:2], axis=1) < 0.008  # skin right above the ball's top
    top = skin[below, 2].min() - gap  # the ball's top: `gap` below the lowest skin point above it
    ball = scene.worldbody.add_body(name="ball", pos=[palm[0], palm[1], top - radius])
    ball.add_geom(name="ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], rgba=[0.9, 0.5, 0.2, 1],
                  contype=0, conaffinity=0)  # a soft-skin-only object: the proxies pass, the skin does not
    scene.attach(hand, prefix="left_", frame=scene.worldbody.add_frame())
    return scene.compile()


def main(out: Path, frames: int = 60) -> dict:
    model = build_scene(ph.load_asset())
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    hand = ph.SoftHand(model, data, prefix="left_", object_bodies=["ball"])  # contact with the ball only
    start = data.mocap_pos[0].copy()
    touched = None  # frame of first contact: then 2 mm further (4 frames) and hold
    print("frame  lowered mm  force on ball N")
    for f in range(frames):
        if touched is None or f < touched + 4:
            data.mocap_pos[0] -= [0, 0, 0.0005]  # down 0.5 mm per 5 ms frame
        mujoco.mj_step(model, data)
        hand.step()
        force = hand.contacts()["objects"]["ball"]["force_n"]
        if touched is None and force > 0:
            touched = f
        if f % 10 == 9:
            print(f"{f + 1:5d}  {(start[2] - data.mocap_pos[0][2]) * 1e3:10.1f}  {force:15.3f}")
    renderer = make_renderer(model, 960, 720)
    try:
        png = write_png(figures.render_contact_frame(renderer, model, data, hand,
                                                     figures.contact_camera(hand.skin_vertices, azimuth=200)),
                        out / "mjspec_attach.png")
    finally:
        renderer.close()
    return dict(picture=png, hand=hand, model=model)


def test_final(tmp_path=None):
    res = main(Path(tmp_path or "example_out"), frames=32)
    hand, model = res["hand"], res["model"]
    assert model.body("left_hand_mount").id > 0 and hand.prefix == "left_"
    assert [model.geom(g).name for g in hand.object_geoms] == ["ball"]
    assert np.all(np.isfinite(hand.skin_vertices)) and res["picture"].stat().st_size > 20_000
    assert hand.contacts()["objects"]["ball"]["force_n"] > 0, "lowered 3 mm into the ball, the palm must touch it"


if __name__ == "__main__":
    print(main(Path(sys.argv[1] if len(sys.argv) > 1 else "example_out"))["picture"])
