"""Write the hand MJCF: MyoHand's chain, position actuators, bone display meshes, collision proxies
set a few millimetres inside the rest skin, and the skin as a non-colliding mesh geom.

Every bone body carries ``gravcomp="1"``: MuJoCo cancels gravity on the hand's own bodies with a
passive force, as muscle tone does, so the soft position actuators (kp = 2 N m/rad) hold a
keyframe's pose exactly instead of sagging under the bones' weight (7 mm at the fingertips within
36 frames without it), and still move the hand when ``ctrl`` changes. Objects keep their gravity.
See docs/coupling.md, "Holding a pose".

Meshes are written inline (``<mesh vertex=... face=...>``) so the file is includable from any
directory and attachable with ``MjSpec`` without path resolution issues.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from physhand_mj.asset import HandAsset
from physhand_mj.build.myohand import FINGER_CHAINS, METACARPAL_BODIES, HandSource
from physhand_mj.hand_mjcf import PROXY_INSET, SELF_PROXY_BIT, SELF_PROXY_SUFFIX
from physhand_mj.types import Layer

# Each proxy has a self copy (class ``self_proxy``): the same shape, colliding only with the other self
# copies once SoftHand turns them on (Config.tuning.self_proxies with Config.self_collision:
# hand_mjcf.enable_self_proxies), with a margin of PROXY_INSET each. MuJoCo adds two geoms' margins,
# so two parts' bones stop where their rest skins would meet over the proxies (docs/self_collision.md).
SELF_PROXY_MARGIN = PROXY_INSET
# As shipped a self copy has its contype bit (hand_mjcf.SELF_PROXY_BIT, so MuJoCo's compiler keeps it in
# the bodies' collision trees) and no conaffinity: nothing collides with it until SoftHand sets that bit too.


def _fmt(a, digits: int = 6) -> str:
    return " ".join(f"{v:.{digits}g}" for v in np.asarray(a, dtype=float).reshape(-1))


def _quat_wxyz(mat: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(mat).as_quat()
    return np.array([w, x, y, z])


def _body_frame(asset: HandAsset, body: str) -> tuple[np.ndarray, np.ndarray]:
    i = list(asset.body_names).index(body)
    w, x, y, z = asset.body_rest_quat[i]
    return asset.body_rest_pos[i], Rotation.from_quat([x, y, z, w]).as_matrix()


def _skin_depth(skin: trimesh.Trimesh, pts: np.ndarray) -> np.ndarray:
    from physhand_mj.build.skin import signed_distance

    return -signed_distance(skin, pts)  # > 0 inside


def fit_capsule(asset: HandAsset, skin: trimesh.Trimesh, body: str) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule along a bone's principal axis, ``PROXY_INSET`` inside the rest skin (hand frame)."""
    bi = list(asset.body_names).index(body)
    pts = asset.positions[asset.vertex_body == bi]
    c = pts.mean(axis=0)
    axis = np.linalg.svd(pts - c)[2][0]
    s = (pts - c) @ axis
    p0, p1 = c + axis * s.min(), c + axis * s.max()
    # Skin vertices attached to this bone give the local skin radius around the axis.
    att = asset.attach[(asset.layer[asset.attach[:, 0]] == Layer.SKIN) & (asset.vertex_body[asset.attach[:, 1]] == bi)]
    q = asset.positions[att[:, 0]]
    t = np.clip((q - p0) @ axis, 0, np.linalg.norm(p1 - p0))
    radial = np.linalg.norm(q - (p0 + np.outer(t, axis)), axis=1)
    r = max(1.5e-3, float(np.percentile(radial, 5)) - PROXY_INSET)
    for _ in range(20):  # shrink until the whole capsule sits PROXY_INSET/2 inside the skin
        a, b = p0 + axis * min(r, 0.45 * np.linalg.norm(p1 - p0)), p1 - axis * min(r, 0.45 * np.linalg.norm(p1 - p0))
        caps = trimesh.creation.capsule(height=np.linalg.norm(b - a), radius=r, count=[8, 8])
        caps.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], b - a))
        caps.apply_translation((a + b) / 2)
        if _skin_depth(skin, caps.vertices).min() >= PROXY_INSET / 2:
            return a, b, r
        r *= 0.9
    return a, b, r


def fit_palm_box(asset: HandAsset, skin: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An oriented box around metacarpals 2-5 grown towards the skin; returns (center, R, half)."""
    ids = [list(asset.body_names).index(b) for b in METACARPAL_BODIES]
    pts = asset.positions[np.isin(asset.vertex_body, ids)]
    to_obb, extents = trimesh.bounds.oriented_bounds(pts)
    world = np.linalg.inv(to_obb)
    rot, center = world[:3, :3], world[:3, 3]
    half = extents / 2 + np.where(extents == extents.min(), 4e-3, 0.0)
    for _ in range(30):
        box = trimesh.creation.box(extents=2 * half)
        box = box.subdivide().subdivide()
        box.apply_transform(world)
        if _skin_depth(skin, box.vertices).min() >= PROXY_INSET / 2:
            break
        half = half * 0.95
    return center, rot, half


def write_hand_mjcf(src: HandSource, asset: HandAsset, path, *, mount_pos=(0.0, 0.0, 0.25),
                    mount_quat=(1.0, 0.0, 0.0, 0.0), kp: float = 2.0, gravcomp: float = 1.0) -> None:
    """Write ``mjcf/hand/myohand.xml`` (see the module docstring).

    ``kp``: position-actuator stiffness (N m/rad, critically damped); ``gravcomp``: the fraction of
    gravity cancelled on every bone body (MuJoCo's ``body/gravcomp``; 0 leaves the hand to sag).
    """
    grav = f' gravcomp="{gravcomp:g}"' if gravcomp else ""
    skin = trimesh.Trimesh(asset.skin_vertices, asset.skin_faces, process=False)
    frames = {b: _body_frame(asset, b) for b in asset.body_names}

    def to_body(body, p):
        pos, rot = frames[body]
        return (np.asarray(p) - pos) @ rot

    proxies: dict[str, list[str]] = {b: [] for b in asset.body_names}
    capsule_bodies = ["firstmc_r"] + [b for chain in FINGER_CHAINS.values() for b in chain]
    for b in capsule_bodies:
        a, c, r = fit_capsule(asset, skin, b)
        shape = f'type="capsule" fromto="{_fmt(to_body(b, a))} {_fmt(to_body(b, c))}" size="{r:.5g}"'
        proxies[b].append(f'<geom name="{b}_proxy" class="proxy" {shape}/>')
        proxies[b].append(f'<geom name="{b}{SELF_PROXY_SUFFIX}" class="self_proxy" {shape}/>')
    center, rot, half = fit_palm_box(asset, skin)
    pos, brot = frames["thirdmc_r"]
    shape = (f'type="box" pos="{_fmt(to_body("thirdmc_r", center))}" quat="{_fmt(_quat_wxyz(brot.T @ rot))}" '
             f'size="{_fmt(half)}"')
    proxies["thirdmc_r"].append(f'<geom name="palm_proxy" class="proxy" {shape}/>')
    proxies["thirdmc_r"].append(f'<geom name="palm{SELF_PROXY_SUFFIX}" class="self_proxy" {shape}/>')

    # Bone display meshes: every bone triangle goes to the body of its first vertex, in that frame.
    meshes, bone_geoms = [], {b: [] for b in asset.body_names}
    owner = asset.vertex_body[asset.bone_faces[:, 0]]
    for bi, b in enumerate(asset.body_names):
        f = asset.bone_faces[owner == bi]
        if not len(f):
            continue
        used, inv = np.unique(f, return_inverse=True)
        v = to_body(b, asset.positions[used])
        meshes.append(f'<mesh name="{b}_bone" inertia="shell" vertex="{_fmt(v)}" face="{_fmt(inv.reshape(-1, 3), 9)}"/>')
        bone_geoms[b].append(f'<geom name="{b}_bone" class="bone" mesh="{b}_bone"/>')
    meshes.append(f'<mesh name="physhand_skin" inertia="shell" vertex="{_fmt(asset.skin_vertices)}" '
                  f'face="{_fmt(asset.skin_faces, 9)}"/>')

    children: dict[str | None, list] = {}
    for body in src.bodies:
        children.setdefault(body.parent, []).append(body)
    joints_all = []

    def emit(body, depth):
        ind = "  " * depth
        pos, quat = (src.root_pos, src.root_quat) if body.parent is None else (body.pos, body.quat)
        lines = [f'{ind}<body name="{body.name}" pos="{_fmt(pos)}" quat="{_fmt(quat)}"{grav}>',
                 f'{ind}  <inertial pos="{_fmt(body.ipos)}" quat="{_fmt(body.iquat)}" mass="{body.mass:.6g}" '
                 f'diaginertia="{_fmt(body.inertia)}"/>']
        for j in body.joints:
            joints_all.append(j)
            lines.append(f'{ind}  <joint name="{j["name"]}" pos="{_fmt(j["pos"])}" axis="{_fmt(j["axis"])}" '
                         f'range="{_fmt(j["range"])}" damping="{j["damping"]:.4g}" armature="{j["armature"]:.4g}"/>')
        lines += [ind + "  " + g for g in bone_geoms.get(body.name, []) + proxies.get(body.name, [])]
        for child in children.get(body.name, []):
            lines += emit(child, depth + 1)
        lines.append(f"{ind}</body>")
        return lines

    tree = []
    for root in children[None]:
        tree += emit(root, 3)
    actuators = [f'    <position name="{j["name"]}_act" joint="{j["name"]}" class="hand_act" '
                 f'ctrlrange="{_fmt(j["range"])}"/>' for j in joints_all]
    xml = f"""<mujoco model="physhand_myohand">
  <!-- Generated by `physhand build-hand`; do not edit by hand.
       Bones and kinematic chain: MyoHand from the myo-sim package (Copyright MyoSuite authors,
       Apache License 2.0; see LICENSE-myo-sim.txt beside this file). Skin, flesh and collision
       proxies: physhand_mj. Each proxy's self copy (class self_proxy) collides with nothing until
       SoftHand turns it on with Config.self_collision (docs/self_collision.md). -->
  <compiler angle="radian" autolimits="true"/>
  <default>
    <default class="physhand">
      <default class="bone">
        <geom type="mesh" contype="0" conaffinity="0" group="1" density="0" rgba="0.93 0.90 0.80 1"/>
      </default>
      <default class="proxy">
        <geom contype="1" conaffinity="1" group="3" density="0" rgba="0.3 0.6 0.9 0.4" friction="1 0.005 0.0001"/>
      </default>
      <default class="self_proxy">
        <geom contype="{SELF_PROXY_BIT}" conaffinity="0" group="4" density="0" margin="{SELF_PROXY_MARGIN:g}" rgba="0.9 0.5 0.2 0.3"
              friction="1 0.005 0.0001"/>
      </default>
      <default class="skin">
        <geom type="mesh" contype="0" conaffinity="0" group="2" density="0" rgba="0.87 0.68 0.58 1"/>
      </default>
      <default class="hand_act">
        <position kp="{kp}" dampratio="1"/>
      </default>
    </default>
  </default>
  <asset>
    {chr(10).join('    ' + m for m in meshes).lstrip()}
  </asset>
  <worldbody>
    <!-- The skin lives in the world frame: the solver writes deformed world-frame vertices into it. -->
    <geom name="physhand_skin" class="skin" mesh="physhand_skin"/>
    <body name="hand_mount" mocap="true" pos="{_fmt(mount_pos)}" quat="{_fmt(mount_quat)}">
{chr(10).join(tree)}
    </body>
  </worldbody>
  <contact>
    <exclude body1="ulna_r" body2="radius_r"/>
  </contact>
  <actuator>
{chr(10).join(actuators)}
  </actuator>
</mujoco>
"""
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(xml)


def main() -> None:
    """Regenerate ``mjcf/hand/myohand.xml`` from the embedded asset and myo-sim's chain without
    rebuilding the asset (``physhand build-hand`` rebuilds both): ``python -m physhand_mj.build.mjcf``."""
    from physhand_mj.asset import load_asset
    from physhand_mj.build.myohand import load_myohand, mount_quat, palm_normal
    from physhand_mj.hand_mjcf import HAND_XML

    src = load_myohand()
    write_hand_mjcf(src, load_asset(), HAND_XML, mount_quat=mount_quat(src.finger_axis, palm_normal(src)))
    print(HAND_XML)


if __name__ == "__main__":
    main()
