"""MuJoCo's native flex (dim 3) as a peer: the same tet mesh, built through ``mujoco.MjSpec``.

Every movable vertex (skin and flesh) is a body with three slide joints, as ``<flexcomp dof="full">``
makes them; skeleton vertices sit in the world body (pinned, as physhand_mj's inverse mass 0).
The flex's elements are the body's tets, its elasticity MuJoCo's linear tet FEM (``young``,
``poisson``). ``integrator="discrete"`` is the only one under which MuJoCo 3.17 integrates flex
elasticity implicitly (stable at 0.5 ms with poisson 0.495), but on the hand its steps with contact
took minutes (docs/peers.md); run_cpu.py uses Euler at 0.1 ms with poisson 0.3 (Euler diverged at
0.25 ms on the hand, measured).

Matched to physhand_mj's ``Config`` defaults (docs/peers.md says what is and is not):
- masses: the asset's lumped vertex masses (density 1100 kg/m^3), gravity -9.81 m/s^2 along z;
- flesh: young 30 kPa (Config.edge_compliance_flesh 1e-2 m/N on ~3 mm edges: k / L ~ 33 kPa) and
  poisson 0.495, so the bulk modulus E / (3 (1 - 2 nu)) = 1 MPa = 1 / Config.volume_compliance;
- damping: not matched. MuJoCo refuses joint damping on flex vertex bodies, so Config.damping's
  2 /s velocity decay has no equivalent; the flex's own (stiffness-proportional) ``damping`` is
  MuJoCo's default 0 unless given;
- time: 5 ms frames of ``steps`` MuJoCo steps (default 10, as Config.substeps).
Not matched: the skin's stiffer membrane and bending (Eq. 2 on skin edges, Eq. 6) and the flesh
attachments (Eq. 4-5): a flex has one material. Contact is MuJoCo's: soft constraints between the
flex's elements (inflated by ``radius``) and the object geom, default solref/solimp unless given.

The object is a mocap body moved along common.object_path, interpolated linearly over each
frame's steps so it reaches the frame's pose at the frame's end.
"""

from __future__ import annotations

import time

import mujoco
import numpy as np

from common import FRAME_DT, object_path
from physhand_mj.types import GeomType, Layer

YOUNG = 3.0e4  # Pa
POISSON = 0.495
DAMPING = 0.0  # s: flex elasticity damping (Rayleigh, stiffness-proportional); MuJoCo's default
RADIUS = 2.0e-4  # m: the flex's collision radius (elements are inflated by it)

_GEOM = {GeomType.SPHERE: mujoco.mjtGeom.mjGEOM_SPHERE, GeomType.CAPSULE: mujoco.mjtGeom.mjGEOM_CAPSULE,
         GeomType.BOX: mujoco.mjtGeom.mjGEOM_BOX, GeomType.CYLINDER: mujoco.mjtGeom.mjGEOM_CYLINDER,
         GeomType.ELLIPSOID: mujoco.mjtGeom.mjGEOM_ELLIPSOID}


def flex_spec(asset, case=None, *, young: float = YOUNG, poisson: float = POISSON, damping: float = DAMPING,
              radius: float = RADIUS, steps: int = 10, solref=None, integrator: str = "discrete", gravity=(0.0, 0.0, -9.81)) -> mujoco.MjSpec:
    """An MjSpec with ``asset``'s tet mesh as one dim-3 flex (vertices in asset order) and, with a
    ``case``, its object as a mocap body ``object`` (geom ``object``). Raises ValueError for an
    object MuJoCo has no geom for (the analytic cone: use the mesh cone)."""
    s = mujoco.MjSpec()
    s.modelname = "peer_flex"
    s.option.timestep = FRAME_DT / steps
    s.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
    s.option.gravity = list(gravity)
    x = np.asarray(asset.positions, float)
    movable = np.asarray(asset.layer) != Layer.SKELETON
    vertbody = []
    for i in np.arange(len(x)):
        if not movable[i]:
            vertbody.append("world")
            continue
        b = s.worldbody.add_body(name=f"v{i}", pos=x[i])
        m = float(asset.mass[i])
        b.mass, b.explicitinertial = m, True
        b.inertia = [m * 1e-8] * 3  # a point mass; slide joints never rotate it
        for ax in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
            b.add_joint(type=mujoco.mjtJoint.mjJNT_SLIDE, axis=ax)
        vertbody.append(b.name)
    f = s.add_flex()
    f.name, f.dim = "body", 3
    f.vertbody = vertbody
    f.vert = np.where(movable[:, None], 0.0, x).ravel().tolist()  # in each vertex body's frame
    f.elem = np.asarray(asset.tets).ravel().tolist()
    f.young, f.poisson, f.damping, f.radius = young, poisson, damping, radius
    f.selfcollide = mujoco.mjtFlexSelf.mjFLEXSELF_NONE
    if solref is not None:
        f.solref = list(solref)
    if case is not None:
        pos, quat, start = object_path(asset, case, 1)
        body = s.worldbody.add_body(name="object", mocap=True, pos=start, quat=quat)
        if case.gtype == GeomType.MESH:
            s.add_mesh(name="object_mesh", uservert=np.asarray(case.vertices, float).ravel().tolist(),
                       userface=np.asarray(case.faces, int).ravel().tolist())
            body.add_geom(name="object", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="object_mesh")
        elif case.gtype in _GEOM:
            size = np.asarray(case.size, float)
            body.add_geom(name="object", type=_GEOM[case.gtype], size=size)
        else:
            raise ValueError(f"MuJoCo has no geom for {case.gtype.name}; use a mesh (e.g. press_case('mesh_cone'))")
    return s


class FlexRun:
    """A compiled flex scene and its path: ``frame(k)`` advances one 5 ms frame with the object moving
    to its frame-k pose; ``x`` is the vertex positions (N, 3) m in asset order."""

    def __init__(self, asset, case, frames: int, steps: int = 10, **kw):
        t = time.perf_counter()
        self.spec = flex_spec(asset, case, steps=steps, **kw)
        self.model = self.spec.compile()
        self.compile_s = time.perf_counter() - t
        self.data = mujoco.MjData(self.model)
        self.steps = steps
        self.path, self.quat, self.start = object_path(asset, case, frames)
        self.data.mocap_pos[0], self.data.mocap_quat[0] = self.start, self.quat
        mujoco.mj_forward(self.model, self.data)

    @property
    def x(self) -> np.ndarray:
        return self.data.flexvert_xpos.copy()

    def object_world_vertices(self) -> np.ndarray:
        """The object mesh's vertices in the world as MuJoCo places them (checks the mesh frame)."""
        m, d = self.model, self.data
        g = m.geom("object").id
        mid = m.geom_dataid[g]
        v = m.mesh_vert[m.mesh_vertadr[mid]: m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
        return v @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]

    def frame(self, k: int) -> dict:
        """Advance frame k; returns ms (wall clock of the steps alone), contacts at the end, unstable."""
        m, d = self.model, self.data
        p0 = self.start if k == 0 else self.path[k - 1]
        t = time.perf_counter()
        for j in range(self.steps):
            d.mocap_pos[0] = p0 + (j + 1) / self.steps * (self.path[k] - p0)
            mujoco.mj_step(m, d)
        ms = (time.perf_counter() - t) * 1e3
        bad = d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0
        return dict(ms=ms, ncon=int(d.ncon), unstable=bool(bad), finite=bool(np.all(np.isfinite(d.qpos))))
