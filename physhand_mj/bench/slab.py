"""A flat soft slab on a tilting table: the rig of two-way coupling's analytic references.

The hand's palm is curved and its thumb stands out of it, so a box laid on it rolls or tips for
reasons of shape; the references of Coulomb friction (a box on a ramp sticks below atan(mu) and
slides above it) and of resting contact (the skin carries m g) want a flat support. The slab is a
layered body built like the hand (``build.build_from_meshes``: a skin, flesh tets, a rigid core):
an 80 x 80 mm skin box ``flesh`` thick over and around a 4 mm core plate, the core carried by a mocap
body ``table`` whose quaternion tilts it. A free box (MuJoCo) is dropped onto it; the slab is the
soft body of a :class:`~physhand_mj.SoftHand` (``writeback=False``), so everything the hand's
contact does (Eq. 9, features, friction, the exchange with MuJoCo) acts between the two.

    asset = soft_slab()                                   # ~1.5 s on a CPU (TetGen), cached
    rig = SlabRig(asset, mass=0.1, mu=0.5)                # model, data and the SoftHand
    rig.settle(200); rig.tilt_to(np.radians(10), rate=np.radians(10))
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

TABLE_Z = 0.1  # m: the table's height


@functools.lru_cache(maxsize=4)
def soft_slab(half: float = 0.04, flesh: float = 0.006, skin_vertices: int = 2500, max_tet_volume: float = 2.0e-8):
    """The slab's layered asset (m; ``half``: half its width, ``flesh``: the skin's distance from the
    core's faces, ``max_tet_volume`` m^3: TetGen's bound). Needs the ``build`` extra (TetGen, pyacvd)."""
    import trimesh

    from physhand_mj.build import build_from_meshes
    from physhand_mj.build.layered import TetOptions
    from physhand_mj.build.skin import remesh_uniform

    core_half = 0.002
    skin = trimesh.creation.box(extents=[2 * half, 2 * half, 2 * (flesh + core_half)])
    v, f = trimesh.remesh.subdivide_to_size(skin.vertices, skin.faces, max_edge=0.002)
    skin = remesh_uniform(trimesh.Trimesh(v, f), skin_vertices)
    core = trimesh.creation.box(extents=[2 * (half - flesh), 2 * (half - flesh), 2 * core_half])
    return build_from_meshes(skin, {"table": core}, {"table": (np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))},
                             skeleton_vertices=800, tet=TetOptions(max_volume=max_tet_volume),
                             meta=dict(name="soft slab", flesh_m=flesh, half_m=half))


class SlabRig:
    """The slab on its mocap table and a free box above its centre (``gap`` m over the skin's top), in
    one MuJoCo model stepped with a SoftHand of the slab.

    Args: asset (:func:`soft_slab`); mass (kg), half (3,) m: the box; mu: the box's and the skin's
    friction coefficient (MuJoCo's larger-of-two rule gives mu); config: the solver's (``two_way``
    True unless given; ``frame_dt`` is the model's timestep, 5 ms)."""

    def __init__(self, asset, mass: float = 0.1, half=(0.015, 0.015, 0.01), mu: float = 0.5, gap: float = 1.0e-3,
                 config=None):
        import physhand_mj as ph

        self.asset, self.mass, self.half = asset, float(mass), np.asarray(half, float)
        self.top = float(asset.skin_vertices[:, 2].max())
        cfg = config or ph.Config(two_way=True)
        xml = f"""<mujoco><option timestep="{cfg.frame_dt}"/><worldbody>
          <body name="table" mocap="true" pos="0 0 {TABLE_Z}"/>
          <body name="box" pos="0 0 {TABLE_Z + self.top + self.half[2] + gap}"><freejoint/>
            <geom name="box" type="box" size="{self.half[0]} {self.half[1]} {self.half[2]}" mass="{self.mass}"
                  friction="{mu} 0.005 0.0001"/></body></worldbody></mujoco>"""
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.hand = ph.SoftHand(self.model, self.data, cfg, asset=asset, writeback=False, settle_frames=2)
        self.hand.skin_friction = 0.0  # (the slab has no skin geom: the box's coefficient decides)
        self.box = self.model.body("box").id
        self.k = self.hand.objects.object_names.index("box")
        self.angle = 0.0
        self.frames = 0

    def step(self) -> dict:
        """One MuJoCo step and one solver frame; returns the frame's figures (:meth:`state`)."""
        mujoco.mj_step(self.model, self.data)
        self.hand.step()
        self.frames += 1
        return self.state()

    def state(self) -> dict:
        """The box in the table's frame: ``pos`` (3,) m from the table's origin, ``height`` m of its
        centre over the skin's rest top, ``force`` (3,) N the skin applied to it last frame (world), its
        ``friction`` part, and both penetration measures against it (counts)."""
        d = self.data
        r = _quat_mat(d.mocap_quat[0])
        rel = r.T @ (d.xpos[self.box] - d.mocap_pos[0])
        w = self.hand.contacts()["objects"]["box"]
        return dict(pos=rel, height=rel[2] - self.top, force=w.get("force", np.zeros(3)), friction=w.get("friction", np.zeros(3)),
                    penetration=w["penetration_count"], object_in_skin=w["object_in_skin_count"], angle=self.angle)

    def tilt(self, angle: float) -> None:
        """Turn the table to ``angle`` rad about x."""
        self.angle = float(angle)
        self.data.mocap_quat[0] = [np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]


def _quat_mat(q) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, float))
    return out.reshape(3, 3)


def slide_angle(rig: SlabRig, approach: float, fast: float = np.radians(20.0), slow: float = np.radians(4.0),
                settle: int = 100, limit: float = np.radians(60.0)) -> dict:
    """Tilt the table until the box slides: ``settle`` frames level, then ``fast`` rad/s up to
    ``approach`` rad, then ``slow`` rad/s. The box slides once it moves down the slope faster than 20
    mm/s over 10 frames (50 ms) or 10 mm from where it was at ``approach``. Returns ``angle`` (rad,
    the table's when it slid; ``limit`` if it never did), ``moved`` (m, down the slope from
    ``approach`` to 2 degrees before the slide: the flesh's shear, not a slip), the frames run and
    ``track`` (n, 2): [angle rad, m moved down the slope since ``approach``] of every slow frame."""
    dt = rig.model.opt.timestep
    for _ in range(settle):
        rig.step()
    ang = 0.0
    while ang < approach:
        ang = min(ang + fast * dt, approach)
        rig.tilt(ang)
        rig.step()
    y0 = prev = float(rig.state()["pos"][1])
    track = []  # (angle, y)
    speeds = []
    while ang < limit:
        ang += slow * dt
        rig.tilt(ang)
        y = float(rig.step()["pos"][1])
        speeds.append((prev - y) / dt)
        prev = y
        track.append((ang, y))
        if (len(speeds) >= 10 and np.mean(speeds[-10:]) > 0.02) or y0 - y > 0.01:
            break
    a = np.array(track)
    before = a[a[:, 0] <= ang - np.radians(2.0)]
    return dict(angle=ang, moved=float(y0 - before[-1, 1]) if len(before) else 0.0, frames=rig.frames,
                track=np.c_[a[:, 0], y0 - a[:, 1]])
