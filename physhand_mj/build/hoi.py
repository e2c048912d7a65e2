"""The seven hand-object grasps of the paper's HOI experiment (section 4.3, Table 2) as scenes.

Each scene (``mjcf/scenes/hoi_<name>.xml``) holds the hand and one static object built from MuJoCo
geoms (the bowl: a mesh shell, since no union of convex geoms is hollow), and a keyframe ``grasp``
whose *undeformed* skin penetrates the object by a few millimetres, as generated grasps do (the
paper's ContactGen inputs reach 2.5-5.7 mm). The grasps are generated, not hand-tuned:

1. the hand is mounted as in grasp_glass (fingers along +x, palm normal +y) with its palm centre at
   ``PALM``; the object is placed in front of the palm (its pose given in that frame) and moved
   along the palm normal to the lowest height where the rigidly skinned open-hand skin penetrates
   it by at most ``palm_depth`` and every bone keeps ``bone_clearance``;
2. each joint of each finger and the thumb, proximal first, closes from the open pose toward the
   power fist and stops at the last value where its chain's skin penetrates at most
   ``finger_depth`` and its bones keep ``bone_clearance`` from the object (bones are rigid: nothing
   could resolve a bone inside the object).

Rigid skinning (each skin vertex follows the bone of its nearest skeleton vertex) is only the
generator's estimate; a rollout measures the real initial penetration of the solver's posed skin.
The objects do not collide in MuJoCo (contype 0): the soft skin alone resolves the contact.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

PALM = np.array([0.0, 0.0, 0.2])  # m: world position of the palm centre in every HOI scene
FINGER_CHAINS = {k: ([f"mcp{k}_flexion_r", f"pm{k}_flexion_r", f"md{k}_flexion_r"],
                     [f"{k}proxph_r", f"midph{k}_r", f"distph{k}_r"]) for k in (2, 3, 4, 5)}
THUMB_CHAIN = (["cmc_flexion_r", "cmc_abduction_r", "mp_flexion_r", "ip_flexion_r"],
               ["firstmc_r", "proximal_thumb_r", "distal_thumb_r"])


def _rot(axis: str, deg: float) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


# name: geoms (type, size in m, position in the object frame), object rotation (world, the palm
# frame: x fingers, y palm normal, z across), offset of the object along x and z (m), depths (m)
SCENES = {
    "glass1": dict(label="glass (grasp 1)", geoms=[("cylinder", (0.035, 0.06), (0, 0, 0))], rot=np.eye(3),
                   offset=(0.012, 0.0), rgba="0.7 0.85 0.95 0.6"),
    "glass2": dict(label="glass (grasp 2)", geoms=[("cylinder", (0.035, 0.06), (0, 0, 0))], rot=_rot("y", 35.0),
                   offset=(0.03, 0.01), rgba="0.7 0.85 0.95 0.6"),
    "toothpaste": dict(label="toothpaste", geoms=[("capsule", (0.017, 0.07), (0, 0, 0))], rot=np.eye(3),
                       offset=(0.02, 0.0), rgba="0.9 0.9 0.95 1"),
    "phone": dict(label="phone", geoms=[("box", (0.0375, 0.0045, 0.075), (0, 0, 0))], rot=np.eye(3),
                  offset=(0.025, 0.0), rgba="0.15 0.15 0.18 1"),
    "apple": dict(label="apple", geoms=[("sphere", (0.04,), (0, 0, 0))], rot=np.eye(3), offset=(0.02, 0.0),
                  rgba="0.75 0.15 0.1 1"),
    "bowl": dict(label="bowl", geoms=[("mesh", (0.065, 0.008), (0, 0, 0))], rot=_rot("x", 90.0), offset=(0.025, 0.0),
                 rgba="0.85 0.8 0.7 1"),
    "box": dict(label="box", geoms=[("box", (0.03, 0.03, 0.03), (0, 0, 0))], rot=np.eye(3), offset=(0.015, 0.0),
                rgba="0.6 0.45 0.3 1"),
}


def bowl_mesh(radius: float, wall: float):
    """A hemispherical shell (outer ``radius``, ``wall`` thick, m), opening toward -z, as a closed
    trimesh: the outer half-sphere minus the inner one."""
    import trimesh

    outer = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=radius - wall)
    cut = trimesh.creation.box(extents=[3 * radius] * 3)
    cut.apply_translation([0, 0, -1.5 * radius])
    shell = outer.difference(inner, engine="manifold").difference(cut, engine="manifold")
    return shell


def _sdf(kind: str, size, p: np.ndarray, mesh=None) -> np.ndarray:
    """Signed distance (m) of points p (n, 3) in the geom frame (MuJoCo size conventions)."""
    if kind == "sphere":
        return np.linalg.norm(p, axis=1) - size[0]
    if kind == "capsule":
        q = p.copy()
        q[:, 2] -= np.clip(p[:, 2], -size[1], size[1])
        return np.linalg.norm(q, axis=1) - size[0]
    if kind == "cylinder":
        d = np.stack([np.hypot(p[:, 0], p[:, 1]) - size[0], np.abs(p[:, 2]) - size[1]], axis=1)
        return np.minimum(d.max(axis=1), 0) + np.linalg.norm(np.maximum(d, 0), axis=1)
    if kind == "box":
        q = np.abs(p) - np.asarray(size)
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
    if kind == "mesh":
        import trimesh

        return -trimesh.proximity.signed_distance(mesh, p)  # trimesh: positive inside
    raise ValueError(kind)


class _Grasp:
    """Rigidly skinned hand at a qpos, for the generator's estimates."""

    def __init__(self, asset, hand_only_xml: Path):
        import mujoco

        from physhand_mj.rotations import quat_to_mat
        from physhand_mj.types import Layer

        self.model = mujoco.MjModel.from_xml_path(str(hand_only_xml))
        self.data = mujoco.MjData(self.model)
        self.asset = asset
        names = list(asset.body_names)
        self.bodies = np.array([self.model.body(n).id for n in names])
        skel = np.flatnonzero(asset.layer == Layer.SKELETON)
        skin = np.arange(asset.n_skin)
        from scipy.spatial import cKDTree

        owner = asset.vertex_body[skel][cKDTree(asset.positions[skel]).query(asset.positions[skin])[1]]
        rest_r = quat_to_mat(asset.body_rest_quat)
        self.skin_body = owner
        self.skin_local = np.einsum("kji,kj->ki", rest_r[owner], asset.positions[skin] - asset.body_rest_pos[owner])
        self.skel_body = asset.vertex_body[skel]
        self.skel_local = np.einsum("kji,kj->ki", rest_r[self.skel_body], asset.positions[skel] - asset.body_rest_pos[self.skel_body])
        self.names = names
        self.open = self.model.key("open").qpos.copy()
        self.power = self.model.key("power").qpos.copy()
        self.adr = {self.model.joint(i).name: int(self.model.jnt_qposadr[i]) for i in range(self.model.njnt)}

    def place(self, mpos, mquat):
        self.data.mocap_pos[0], self.data.mocap_quat[0] = mpos, mquat

    def points(self, qpos):
        import mujoco

        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        xp, xm = self.data.xpos[self.bodies], self.data.xmat[self.bodies].reshape(-1, 3, 3)
        skin = np.einsum("kij,kj->ki", xm[self.skin_body], self.skin_local) + xp[self.skin_body]
        skel = np.einsum("kij,kj->ki", xm[self.skel_body], self.skel_local) + xp[self.skel_body]
        return skin, skel


def generate(name: str, asset, hand_only_xml: Path, *, palm_depth: float = 0.003, finger_depth: float = 0.004,
             bone_clearance: float = 0.0015) -> dict:
    """The keyframe (qpos), mount pose and object pose of scene ``name`` (see the module docstring)."""
    from physhand_mj.build.scenes import palm_mount

    spec = SCENES[name]
    g = _Grasp(asset, hand_only_xml)
    mpos, mquat = palm_mount(asset, PALM)
    g.place(mpos, mquat)
    mesh = bowl_mesh(*spec["geoms"][0][1]) if spec["geoms"][0][0] == "mesh" else None
    R = spec["rot"]

    def phi(points, centre):
        local = (points - centre) @ R  # world -> object frame
        return np.min([_sdf(k, s, local - np.asarray(o), mesh) for k, s, o in spec["geoms"]], axis=0)

    skin, skel = g.points(g.open)
    ox, oz = spec["offset"]

    def height(test) -> float:
        """Bisection on the object's height over the palm: the lowest where ``test(centre)`` holds."""
        lo, hi = 0.0, 0.25
        for _ in range(40):
            t = 0.5 * (lo + hi)
            lo, hi = (lo, t) if test(PALM + [ox, t, oz]) else (t, hi)
        return hi

    t = max(height(lambda ctr: -phi(skin, ctr).min() <= palm_depth),
            height(lambda ctr: phi(skel, ctr).min() >= bone_clearance))
    centre = PALM + np.array([ox, t, oz])
    qpos = g.open.copy()
    flex = {}
    for joints, bodies in list(FINGER_CHAINS.values()) + [THUMB_CHAIN]:
        bset = [g.names.index(b) for b in bodies]
        on_skin, on_skel = np.isin(g.skin_body, bset), np.isin(g.skel_body, bset)
        for j in joints:  # proximal first: each joint closes toward the fist until its chain touches
            i = g.adr[j]
            best = 0.0
            for a in np.linspace(0.0, 1.0, 26)[1:]:
                q = qpos.copy()
                q[i] = (1 - a) * g.open[i] + a * g.power[i]
                sk, sl = g.points(q)
                if -phi(sk[on_skin], centre).min() > finger_depth or phi(sl[on_skel], centre).min() < bone_clearance:
                    break
                best = a
            qpos[i] = (1 - best) * g.open[i] + best * g.power[i]
            flex[j] = round(float(best), 2)
    skin, skel = g.points(qpos)
    return dict(qpos=qpos, mpos=mpos, mquat=mquat, centre=centre, rot=R, flex=flex, mesh=mesh,
                est_skin_depth_mm=float(-phi(skin, centre).min() * 1e3),
                bone_clearance_mm=float(phi(skel, centre).min() * 1e3), model=g.model)


def write_hoi_scene(name: str, asset, hand_only_xml: Path, scenes_dir: Path) -> Path:
    """Generate and write ``scenes_dir/hoi_<name>.xml`` (and the bowl's mesh under ``assets/``)."""
    import mujoco

    from physhand_mj.build.scenes import scene_xml

    spec = SCENES[name]
    gen = generate(name, asset, hand_only_xml)
    model = gen["model"]
    acts = [model.jnt_qposadr[model.actuator_trnid[a, 0]] for a in range(model.nu)]

    def fmt(a):
        return " ".join(f"{v:.6g}" for v in np.ravel(a))

    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.asarray(gen["rot"], float).ravel())
    geoms, assets = [], ""
    for i, (kind, size, off) in enumerate(spec["geoms"]):
        gname = name if len(spec["geoms"]) == 1 else f"{name}_{i}"
        if kind == "mesh":
            (scenes_dir / "assets").mkdir(parents=True, exist_ok=True)
            gen["mesh"].export(scenes_dir / "assets" / f"{name}.stl")
            assets = f'  <asset>\n    <mesh name="{name}" file="assets/{name}.stl"/>\n  </asset>\n'
            geoms.append(f'      <geom name="{gname}" type="mesh" mesh="{name}" pos="{fmt(off)}" contype="0" '
                         f'conaffinity="0" rgba="{spec["rgba"]}"/>')
        else:
            geoms.append(f'      <geom name="{gname}" type="{kind}" size="{fmt(size)}" pos="{fmt(off)}" contype="0" '
                         f'conaffinity="0" rgba="{spec["rgba"]}"/>')
    body = (f'    <body name="{name}" pos="{fmt(gen["centre"])}" quat="{fmt(quat)}">\n' + "\n".join(geoms)
            + "\n    </body>\n")
    key = (f'    <key name="grasp" qpos="{fmt(gen["qpos"])}" ctrl="{fmt(gen["qpos"][acts])}" '
           f'mpos="{fmt(gen["mpos"])}" mquat="{fmt(gen["mquat"])}"/>')
    xml = scene_xml(
        f"physhand hoi {name}",
        f"""Generated by physhand_mj.build.hoi (python -m physhand_mj.build.hoi). HOI scene of the paper's
       Table 2: {spec['label']}, static, not colliding in MuJoCo (contype 0); keyframe `grasp`: a generated
       grasp whose undeformed skin penetrates the object (estimate {gen['est_skin_depth_mm']:.1f} mm, bones
       {gen['bone_clearance_mm']:.1f} mm clear; finger flexions {gen['flex']}).""",
        "../hand/myohand.xml", body, [key])
    if assets:
        xml = xml.replace("  <option timestep", assets + "  <option timestep", 1)
    path = scenes_dir / f"hoi_{name}.xml"
    path.write_text(xml)
    return path


def main() -> None:
    from physhand_mj.asset import load_asset
    from physhand_mj.hand_mjcf import scene_path

    asset = load_asset()
    hand_only = scene_path("hand_only")
    for name in SCENES:
        print(write_hoi_scene(name, asset, hand_only, hand_only.parent))


if __name__ == "__main__":
    main()
