"""Two soft pads squeezing a box: the rig of the pinch reference of two-way coupling.

A thumb-index pinch holds a box of mass m against gravity by friction at two opposed contacts: it
holds while 2 mu N >= m g (N: each side's normal force) and slips otherwise. The hand's fingertips
are curved and their grip changes with the pose, so the reference wants two flat pads whose squeeze
is set directly. Each pad is a layered body built like the hand (``build.build_from_meshes``): a
skin box ``flesh`` thick over and around a 4 mm core plate, its core carried by a mocap body
(``left`` below the box at -z, ``right`` above it at +z; the squeeze is along z and gravity along -x,
since the builder's level-set bones come out empty for a plate thin along x). A free box (MuJoCo)
stands between them; the pads close on it by ``depth`` each in zero gravity, N is read off the
reaction on each pad's core (the exchange's bone wrenches), then gravity is turned on.

    asset = pinch_pads()                        # ~3 s on a CPU (TetGen), cached
    rig = PinchRig(asset, mass=0.01, mu=0.4)
    n = rig.squeeze(depth=0.4e-3)               # N per side, gravity off
    out = rig.hold(frames=160)                  # gravity on: did the box slip?

The pads' faces (24 mm) are smaller than the box's (40 mm): a box edge pressed into a pad carries
much of the normal load (a rigid punch's edge) while the shear is spread evenly, so friction there
is mobilised unevenly and the box slipped only at 1.2-1.3 x the bound (tried: 40 mm pads, a 20 mm
box); with the pads inside the box's faces the skin is pressed evenly.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

PAD_Z = 0.1  # m: the pads' centre height
G = 9.81


@functools.lru_cache(maxsize=2)
def pinch_pads(half: float = 0.012, flesh: float = 0.004, skin_vertices: int = 1000, gap: float = 0.024,
               max_tet_volume: float = 2.0e-8):
    """Two pads facing each other along z (m; ``half``: half their face's width, ``flesh``: the skin's
    distance from the core plate, ``gap``: between their skins' inner faces at rest). Needs the
    ``build`` extra (TetGen, pyacvd)."""
    # the builder's level-set bone surface comes out empty for some plate sizes on its 0.4 mm grid
    # (e.g. 16 x 16 x 4 mm at z = 18 mm): a core a few tenths of a mm thicker then does
    for core_half in (0.002, 0.0021, 0.0022, 0.0023):
        try:
            return _pads(half, flesh, skin_vertices, gap, max_tet_volume, core_half)
        except ValueError:
            continue
    raise ValueError("pinch_pads: no core plate thickness gave a bone surface")


def _pads(half, flesh, skin_vertices, gap, max_tet_volume, core_half):
    import trimesh

    from physhand_mj.build import build_from_meshes
    from physhand_mj.build.layered import TetOptions
    from physhand_mj.build.skin import remesh_uniform

    thick = flesh + core_half  # the skin's half thickness along z
    skins, cores, poses = [], {}, {}
    for name, side in (("left", -1.0), ("right", 1.0)):
        c = side * (gap / 2 + thick)  # the pad's centre
        skin = trimesh.creation.box(extents=[2 * half, 2 * half, 2 * thick])
        v, f = trimesh.remesh.subdivide_to_size(skin.vertices, skin.faces, max_edge=0.002)
        skin = remesh_uniform(trimesh.Trimesh(v, f), skin_vertices)
        skin.apply_translation([0.0, 0.0, c])
        skins.append(skin)
        core = trimesh.creation.box(extents=[2 * (half - flesh), 2 * (half - flesh), 2 * core_half])
        core.apply_translation([0.0, 0.0, c])
        cores[name] = core
        poses[name] = (np.array([0.0, 0.0, c]), np.array([1.0, 0.0, 0.0, 0.0]))
    skin = trimesh.util.concatenate(skins)
    return build_from_meshes(skin, cores, poses, skeleton_vertices=600, tet=TetOptions(max_volume=max_tet_volume),
                             meta=dict(name="pinch pads", flesh_m=flesh, half_m=half, gap_m=gap))


class PinchRig:
    """The two pads on their mocap bodies and a free box between them, in one MuJoCo model stepped
    with a SoftHand of the pads.

    Args: asset (:func:`pinch_pads`); mass (kg), half (3,) m: the box (its z half width leaves
    ``clearance`` m to each pad's rest skin); mu: the box's friction coefficient (the pads' is 0, so
    MuJoCo's larger-of-two rule gives mu); config: the solver's (``two_way`` True unless given)."""

    def __init__(self, asset, mass: float = 0.01, half=(0.02, 0.02, 0.01), mu: float = 0.5, clearance: float = 2.0e-4,
                 config=None):
        import physhand_mj as ph

        self.asset, self.mass, self.half, self.mu = asset, float(mass), np.asarray(half, float), float(mu)
        self.gap = float(asset.meta["gap_m"])
        self.touch = self.gap / 2 - self.half[2]  # each pad's inward shift at which its rest skin touches the box
        self.shift = self.touch - clearance
        self.centre = float(asset.body_rest_pos[list(asset.body_names).index("right"), 2])  # the pads' rest |x|
        cfg = config or ph.Config(two_way=True)
        xml = f"""<mujoco><option timestep="{cfg.frame_dt}" gravity="{-G} 0 0"/><worldbody>
          <body name="left" mocap="true" pos="0 0 {PAD_Z - self.centre + self.shift}"/>
          <body name="right" mocap="true" pos="0 0 {PAD_Z + self.centre - self.shift}"/>
          <body name="box" pos="0 0 {PAD_Z}"><freejoint/>
            <geom name="box" type="box" size="{self.half[0]} {self.half[1]} {self.half[2]}" mass="{self.mass}"
                  friction="{mu} 0.005 0.0001"/></body></worldbody></mujoco>"""
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.g = self.model.opt.gravity.copy()
        self.model.opt.gravity[:] = 0.0  # off while the pads close
        mujoco.mj_forward(self.model, self.data)
        self.hand = ph.SoftHand(self.model, self.data, cfg, asset=asset, writeback=False, settle_frames=5)
        self.hand.skin_friction = 0.0
        self.box = self.model.body("box").id
        self.pads = [list(self.hand.bones).index(self.model.body(n).id) for n in ("left", "right")]
        self.frames = 0

    def step(self) -> dict:
        """One MuJoCo step and one solver frame; returns the frame's figures (:meth:`state`)."""
        mujoco.mj_step(self.model, self.data)
        self.hand.step()
        self.frames += 1
        return self.state()

    def state(self) -> dict:
        """``z`` m: the box's position along gravity's up (+x) since the rig was made; ``normal`` (2,) N: the z force on the
        left and right pad's core (their reactions: the squeeze, as a positive figure each); ``force``
        (3,) N and ``friction`` (3,) N: what the skin applied to the box last frame; both penetration
        measures against it (counts)."""
        w = self.hand.contacts()["objects"]["box"]
        wr = self.hand._wrenches
        bones = wr["bones"][:, :3] if wr is not None else np.zeros((len(self.hand.bones), 3))
        normal = np.array([-bones[self.pads[0], 2], bones[self.pads[1], 2]])
        return dict(z=float(self.data.xpos[self.box][0]), normal=normal, force=w.get("force", np.zeros(3)),
                    friction=w.get("friction", np.zeros(3)), penetration=w["penetration_count"],
                    object_in_skin=w["object_in_skin_count"])

    def squeeze(self, depth: float, frames: int = 60, settle: int = 40) -> float:
        """Gravity off, move each pad ``depth`` m (beyond touching) toward the box over ``frames``,
        hold ``settle`` frames; returns N, each side's mean normal force over the last 20 frames."""
        s0, s1 = self.shift, self.touch + depth
        rows = []
        for f in range(frames + settle):
            self.shift = s0 + (s1 - s0) * min(1.0, (f + 1) / frames)
            self.data.mocap_pos[0, 2] = PAD_Z - self.centre + self.shift
            self.data.mocap_pos[1, 2] = PAD_Z + self.centre - self.shift
            rows.append(self.step()["normal"])
        return float(np.mean(rows[-20:]))

    def hold(self, frames: int = 200, ramp: int = 40) -> dict:
        """Gravity on, ramped up over ``ramp`` frames (a sudden load would swing the flesh's shear past
        its static value), for ``frames`` in all: returns ``drop`` (m the box fell), ``speed`` (m/s down
        over the last 10 frames), ``normal`` (N per side while the full weight first hangs on the pads:
        the mean over the 20 frames after the ramp, those before the box fell 5 mm; the flesh's shear
        lowers it from the squeeze's), ``normal_ramp`` (the mean over the ramp's last 10 frames),
        ``zs`` (m, the box's height each frame) and the final state."""
        z0 = self.state()["z"]
        zs, ns = [], []
        for f in range(frames):
            self.model.opt.gravity[:] = self.g * min(1.0, (f + 1) / max(ramp, 1))
            s = self.step()
            zs.append(s["z"])
            ns.append(s["normal"].mean())
        dt = self.model.opt.timestep
        speed = (zs[-11] - zs[-1]) / (10 * dt) if len(zs) > 10 else 0.0
        # N while the pads hold the full weight: the 20 frames after the ramp, those before the box fell
        # 5 mm (a box sliding out of the pads unloads them)
        held = [n for n, z in zip(ns[ramp: ramp + 20], zs[ramp: ramp + 20]) if z0 - z < 5.0e-3]
        return dict(drop=z0 - zs[-1], speed=speed, normal=float(np.mean(held or ns[max(ramp - 10, 0): max(ramp, 10)])),
                    normal_ramp=float(np.mean(ns[max(ramp - 10, 0): max(ramp, 10)])), zs=np.array(zs), state=s)


class HandPinch:
    """The hand's own pinch: ``hand_only``'s ``pinch`` keyframe (thumb and index tips facing) with a
    free card (a box ``size`` m wide, ``thick`` m thick, ``mass`` kg, friction ``mu``) placed midway
    between the two tips' proxies, its faces across the line joining them; the hand's actuators hold
    the keyframe's targets and the hand's bodies are gravity-compensated. No proxy touches the card:
    the skin alone holds it. N per side is the bones' force along the card's normal (the thumb's
    three bones against the index's three): the part of each tip's push that presses the card.

        rig = HandPinch(mu=0.3)
        rig.settle(60)         # gravity off: the card settles where the tips' pushes balance
        out = rig.hold(200)    # gravity ramped in over 40 frames"""

    THUMB = ("distal_thumb_r", "proximal_thumb_r", "firstmc_r")
    INDEX = ("distph2_r", "midph2_r", "2proxph_r")

    def __init__(self, mu: float = 0.5, mass: float = 0.01, size: float = 0.016, thick: float = 0.003, config=None):
        import physhand_mj as ph
        from physhand_mj.hand_mjcf import SCENES_DIR

        self.mass, self.mu = float(mass), float(mu)
        path = str(SCENES_DIR / "hand_only.xml")
        m0 = mujoco.MjModel.from_xml_path(path)
        d0 = mujoco.MjData(m0)
        key = m0.key("pinch").id
        mujoco.mj_resetDataKeyframe(m0, d0, key)
        mujoco.mj_forward(m0, d0)
        ft = np.zeros(6)
        mujoco.mj_geomDistance(m0, d0, m0.geom("distal_thumb_r_proxy").id, m0.geom("distph2_r_proxy").id, 0.1, ft)
        a, b = ft[:3], ft[3:]
        c = 0.5 * (a + b)
        z = (b - a) / np.linalg.norm(b - a)  # the card's normal: from the thumb's proxy to the index's
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.c_[x, np.cross(z, x), z].ravel())
        spec = mujoco.MjSpec.from_file(path)
        body = spec.worldbody.add_body(name="card", pos=c.tolist(), quat=q.tolist())
        body.add_freejoint(name="card_free")
        body.add_geom(name="card", type=mujoco.mjtGeom.mjGEOM_BOX, size=[size / 2, size / 2, thick / 2], mass=mass,
                      friction=[mu, 0.005, 0.0001])
        self.model = m = spec.compile()
        self.data = d = mujoco.MjData(m)
        nh = m0.nq
        d.qpos[:nh] = m0.key_qpos[key]
        d.qpos[nh: nh + 3], d.qpos[nh + 3: nh + 7] = c, q
        d.ctrl[:] = np.clip(m0.key_ctrl[key], m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
        self.g = m.opt.gravity.copy()
        m.opt.gravity[:] = 0.0
        mujoco.mj_forward(m, d)
        self.hand = ph.SoftHand(m, d, config or ph.Config(two_way=True), object_bodies=["card"], settle_frames=20)
        self.hand.skin_friction = 0.0  # (MuJoCo's rule: the card's mu)
        self.hand.solver.warn_feature_slack = False
        self.card = m.body("card").id
        self.card_geom = m.geom("card").id
        names = [m.body(int(bb)).name for bb in self.hand.bones]
        self.thumb = [i for i, n in enumerate(names) if n in self.THUMB]
        self.index = [i for i, n in enumerate(names) if n in self.INDEX]

    def normal(self) -> np.ndarray:
        """(2,) N: the thumb's and the index's bones' force along the card's normal (pressing it)."""
        w = self.hand._wrenches
        if w is None:
            return np.zeros(2)
        n = self.data.xmat[self.card].reshape(3, 3)[:, 2]
        return np.array([-(w["bones"][self.thumb, :3].sum(0) @ n), w["bones"][self.index, :3].sum(0) @ n])

    def step(self) -> None:
        mujoco.mj_step(self.model, self.data)
        self.hand.step()

    def settle(self, frames: int = 60) -> float:
        """Gravity off for ``frames``: the card moves to where the tips' pushes balance; returns how far (m)."""
        p0 = self.data.xpos[self.card].copy()
        for _ in range(frames):
            self.step()
        return float(np.linalg.norm(self.data.xpos[self.card] - p0))

    def hold(self, frames: int = 200, ramp: int = 40) -> dict:
        """Gravity on, ramped over ``ramp`` frames, ``frames`` in all: ``drop`` (m the card fell),
        ``speed`` (m/s down over the last 10 frames), ``normal`` (N per side while the full weight
        hangs on the tips: the mean over the 20 frames after the ramp, those before it fell 5 mm),
        ``fall`` (m, how far it has fallen each frame), ``turned`` (degrees the card has turned 20
        frames after the ramp) and ``proxy_contacts`` (MuJoCo contacts with the card at the end: 0
        when the skin alone holds it)."""
        p0, q0 = self.data.xpos[self.card].copy(), self.data.xquat[self.card].copy()
        zs, ns, turn = [], [], []
        for f in range(frames):
            self.model.opt.gravity[:] = self.g * min(1.0, (f + 1) / max(ramp, 1))
            self.step()
            zs.append(float(p0[2] - self.data.xpos[self.card][2]))
            ns.append(float(self.normal().mean()))
            turn.append(2.0 * np.degrees(np.arccos(min(1.0, abs(float(self.data.xquat[self.card] @ q0))))))
        held = [n for n, z in zip(ns[ramp: ramp + 20], zs[ramp: ramp + 20]) if z < 5.0e-3]
        dt = self.model.opt.timestep
        d = self.data
        return dict(drop=zs[-1], speed=(zs[-1] - zs[-11]) / (10 * dt) if len(zs) > 10 else 0.0,
                    normal=float(np.mean(held or ns[max(ramp - 10, 0): max(ramp, 10)])), fall=np.array(zs),
                    turned=float(turn[ramp + 19] if len(turn) > ramp + 19 else turn[-1]),
                    proxy_contacts=sum(1 for i in range(d.ncon) if self.card_geom in (d.contact[i].geom1, d.contact[i].geom2)))
