"""The soft skin on any MuJoCo model that has the hand's bones (MyoHand's kinematic chain).

    spec = mujoco.MjSpec.from_file("my_arm.xml")         # a model with the MyoHand bones
    skin = ph.add_skin(spec, naming="myosuite_old")      # or "asset", "auto", a prefix, a name map
    model = spec.compile(); data = mujoco.MjData(model)
    hand = ph.SoftHand(model, data, naming=skin.naming)  # as with mjcf/hand/myohand.xml

Namings (how the model names the asset's 29 bone bodies, ``load_asset().body_names``):

- ``"asset"``: the asset's own names (``ulna_r``, ``2proxph_r``, ``distph2_r``, ...), as in
  ``mjcf/hand/myohand.xml`` and MyoSuite 3's ``myoHandReorient*`` / ``myoHandPose*`` / ``myoHandReach*``;
- ``"myosuite_old"``: MyoHand's older names without the ``_r`` suffix and with ``proxphN`` for
  ``Nproxph_r`` (MyoSuite's ``myoHandObjHold*``, ``myoHandKeyTurn*``, ``myoHandPenTwirl*``);
- any other string: a prefix before the asset's names (``MjSpec.attach(..., prefix="left_")``);
- a dict ``{asset name: model name}`` (names it leaves out keep the asset's name);
- ``"auto"``: whichever built-in scheme, under whichever prefix, names all bones of exactly one hand.

The bones' frames are checked against the asset's rest frames (relative to the first bone, the
ulna): first at the model's ``qpos0``; if that misses, the hand's joints are fitted (damped
Gauss-Newton on the bone frames) because the asset's rest pose need not be ``qpos0`` (the embedded
hand rests with its fingers spread: ``mcp2_abduction`` 0.25 rad, ...). What no joint pose removes
(a moved or scaled bone, a wrong name map) is an error naming the worst bone and its offset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physhand_mj.hand_mjcf import SKIN_GEOM

# Measured on MyoSuite 3.0.0's hand models (env.unwrapped.model body names): myoHandObjHold*,
# myoHandKeyTurn*, myoHandPenTwirl* name the MyoHand bones like this; the *Reorient*, *Pose* and
# *Reach* hands use the asset's names.
_OLD = {"ulna_r": "ulna", "radius_r": "radius", "lunate_r": "lunate", "scaphoid_r": "scaphoid",
        "pisiform_r": "pisiform", "triquetrum_r": "triquetrum", "capitate_r": "capitate",
        "trapezium_r": "trapezium", "firstmc_r": "firstmc", "proximal_thumb_r": "proximal_thumb",
        "distal_thumb_r": "distal_thumb", "trapezoid_r": "trapezoid", "hamate_r": "hamate",
        "secondmc_r": "secondmc", "2proxph_r": "proxph2", "midph2_r": "midph2", "distph2_r": "distph2",
        "thirdmc_r": "thirdmc", "3proxph_r": "proxph3", "midph3_r": "midph3", "distph3_r": "distph3",
        "fourthmc_r": "fourthmc", "4proxph_r": "proxph4", "midph4_r": "midph4", "distph4_r": "distph4",
        "fifthmc_r": "fifthmc", "5proxph_r": "proxph5", "midph5_r": "midph5", "distph5_r": "distph5"}
NAMINGS = ("asset", "myosuite_old")
"""The built-in naming schemes (besides a prefix string, a name map and ``"auto"``)."""

TOL_MM = 0.5
"""Largest bone-origin offset (mm) from the asset's rest frames that the frame check accepts."""
TOL_DEG = 0.5
"""Largest bone-rotation offset (degrees) from the asset's rest frames that the frame check accepts."""


@dataclass(frozen=True)
class Naming:
    """How one model names the asset's bones: ``bones`` (model body names, in the asset's order),
    the ``scheme`` (``"asset"``, ``"myosuite_old"`` or ``"map"``) and the ``prefix`` before them;
    the skin geom and mesh are called ``prefix + "physhand_skin"``."""

    scheme: str
    prefix: str
    bones: tuple

    @property
    def skin_geom(self) -> str:
        return self.prefix + SKIN_GEOM


@dataclass(frozen=True)
class SkinAttachment:
    """What :func:`add_skin` added: the skin ``geom`` / ``mesh`` names, the ``naming`` to give
    ``SoftHand(naming=...)``, and the measured frame offset: ``offset_mm`` / ``offset_deg`` (worst
    bone, after the joint fit if ``fitted``), ``worst_bone``; ``self_proxies``: the self proxies'
    geom names it added (empty where the model had them or they were not asked for)."""

    geom: str
    mesh: str
    naming: Naming
    offset_mm: float
    offset_deg: float
    worst_bone: str
    fitted: bool
    self_proxies: tuple = ()


def _scheme_names(scheme: str, asset_names) -> list[str]:
    return [str(n) if scheme == "asset" else _OLD.get(str(n), str(n)) for n in asset_names]


def resolve_naming(body_names, naming="auto", asset=None, prefix: str = "") -> Naming:
    """The model body names of the asset's bones under ``naming`` (see the module docstring).

    ``body_names``: every body name of the model (or spec); a :class:`Naming` is checked and returned. ``prefix`` is put before a built-in
    scheme's names. Raises ValueError listing the missing bones, or the candidates if ``"auto"``
    finds the bones of more than one hand (or a name map sends two bones to one body)."""
    from physhand_mj.asset import load_asset

    asset = asset if asset is not None else load_asset()
    names = [str(n) for n in asset.body_names]
    present = set(str(b) for b in body_names)
    if isinstance(naming, Naming):
        scheme, prefix, bones = naming.scheme, naming.prefix, list(naming.bones)
    elif isinstance(naming, dict):
        unknown = sorted(set(naming) - set(names))
        if unknown:
            raise ValueError(f"the name map's keys {unknown} are not bones of the asset; its bones are {names}")
        bones = [str(naming.get(n, n)) for n in names]
        dup = sorted({b for b in bones if bones.count(b) > 1})
        if dup:
            raise ValueError(f"ambiguous name map: bodies {dup} are given to more than one bone")
        scheme, prefix = "map", ""
    elif naming == "auto":
        cands = []
        for scheme in NAMINGS:
            sn = _scheme_names(scheme, names)
            for b in present:  # every prefix under which the scheme's first bone appears
                if b.endswith(sn[0]) and b.startswith(prefix) and all(b[: len(b) - len(sn[0])] + n in present
                                                                     for n in sn):
                    cands.append((scheme, b[: len(b) - len(sn[0])]))
        if len(cands) > 1:
            listed = ", ".join(f"{s} with prefix '{p}'" for s, p in sorted(cands))
            raise ValueError(f"ambiguous bones: the model names the hand's bones more than once ({listed}); "
                             f"pass naming= and prefix= to pick one")
        if not cands:  # name the closest scheme and prefix: the one that finds the most bones
            guesses = {(s, prefix) for s in NAMINGS} | {(s, b[: len(b) - len(n)]) for s in NAMINGS for n in _scheme_names(s, names)
                                       for b in present if b.endswith(n) and b.startswith(prefix)}
            best, pre = max(sorted(guesses), key=lambda g: sum(g[1] + n in present for n in _scheme_names(g[0], names)))
            missing = [pre + n for n in _scheme_names(best, names) if pre + n not in present]
            raise ValueError(f"the model lacks the hand's bone bodies {missing} (closest naming: '{best}', prefix "
                             f"'{pre}'); pass naming= ('asset', 'myosuite_old', a prefix or a name map)")
        scheme, prefix = cands[0]
        bones = [prefix + n for n in _scheme_names(scheme, names)]
    elif isinstance(naming, str):
        if naming not in NAMINGS:  # a prefix before the asset's names
            scheme, prefix = "asset", prefix + naming
        else:
            scheme = naming
        bones = [prefix + n for n in _scheme_names(scheme, names)]
    else:
        raise ValueError(f"naming must be 'auto', {list(NAMINGS)}, a prefix string or a dict, got {naming!r}")
    missing = [b for b in bones if b not in present]
    if missing:
        raise ValueError(f"the model lacks the hand's bone bodies {missing} (naming '{scheme}', prefix "
                         f"'{prefix}'); pass naming= ('asset', 'myosuite_old', 'auto', a prefix or a name map)")
    return Naming(scheme, prefix, tuple(bones))


def _frame_errors(data, ids, target_pos, target_rot):
    """Per bone: origin offset (m) and rotation offset (rad, axis-angle vector) to its target."""
    import mujoco

    ep = target_pos - data.xpos[ids]
    er = np.empty((len(ids), 3))
    q = np.empty(4)
    for k, b in enumerate(ids):
        mujoco.mju_mat2Quat(q, (target_rot[k] @ data.xmat[b].reshape(3, 3).T).ravel())
        mujoco.mju_quat2Vel(er[k], q, 1.0)
    return ep, er


def rest_frame_offset(model, bone_ids, asset, fit: bool = True, iterations: int = 30) -> dict:
    """Largest offset of the bones' frames from the asset's rest frames (relative to bone 0).

    Measured at ``model.qpos0``; if it exceeds :data:`TOL_MM` / :data:`TOL_DEG` and ``fit``, again
    after fitting the joints below bone 0 (damped Gauss-Newton on origins and rotations, rotation
    weighted 0.02 m/rad). Returns ``mm``, ``deg`` (worst bones' offsets), ``bone_mm``, ``bone_deg``
    (their ids into ``bone_ids``), ``qpos0_mm``, ``qpos0_deg`` and ``fitted``."""
    import mujoco

    from physhand_mj.rotations import quat_to_mat

    ids = np.asarray(bone_ids)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    r_rest = quat_to_mat(np.asarray(asset.body_rest_quat, float))
    world = data.xmat[ids[0]].reshape(3, 3) @ r_rest[0].T  # asset frame -> world, bone 0 fixed
    tpos = (np.asarray(asset.body_rest_pos, float) - asset.body_rest_pos[0]) @ world.T + data.xpos[ids[0]]
    trot = np.einsum("ij,kjl->kil", world, r_rest)

    def measure():
        ep, er = _frame_errors(data, ids, tpos, trot)
        mm, deg = np.linalg.norm(ep, axis=1) * 1e3, np.degrees(np.linalg.norm(er, axis=1))
        return mm, deg, ep, er

    mm, deg, ep, er = measure()
    out = dict(qpos0_mm=float(mm.max()), qpos0_deg=float(deg.max()), fitted=False)
    if fit and (mm.max() > TOL_MM or deg.max() > TOL_DEG):
        # the joints that move bones relative to bone 0: dofs of bodies strictly inside its subtree
        sub = [b for b in range(model.nbody) if b != ids[0] and _in_subtree(model, b, int(ids[0]))]
        cols = np.flatnonzero(np.isin(model.dof_bodyid, sub))
        w = 0.02  # m per rad: a 1 degree miss weighs like 0.35 mm
        jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_comPos(model, data)  # the Jacobians read cdof
        for _ in range(iterations if len(cols) else 0):
            rows, res = [], []
            for k, b in enumerate(ids[1:], start=1):
                mujoco.mj_jacBody(model, data, jp, jr, int(b))
                rows += [jp[:, cols].copy(), w * jr[:, cols]]
                res += [ep[k], w * er[k]]
            jac, r = np.concatenate(rows), np.concatenate(res)
            dq = np.zeros(model.nv)
            dq[cols] = np.linalg.solve(jac.T @ jac + 1e-8 * np.eye(len(cols)), jac.T @ r)
            mujoco.mj_integratePos(model, data.qpos, dq, 1.0)
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)  # the Jacobians read cdof
            mm, deg, ep, er = measure()
            if np.abs(dq).max() < 1e-9:
                break
        out["fitted"] = True
    out.update(mm=float(mm.max()), deg=float(deg.max()), bone_mm=int(mm.argmax()), bone_deg=int(deg.argmax()))
    return out


def _in_subtree(model, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return root == 0


def check_rest_frames(model, naming: Naming, asset) -> dict:
    """:func:`rest_frame_offset` of ``naming``'s bones; ValueError naming the worst bone and its
    offset (mm, degrees) if it exceeds :data:`TOL_MM` / :data:`TOL_DEG` in the best joint pose."""
    import mujoco

    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in naming.bones]
    off = rest_frame_offset(model, ids, asset)
    if off["mm"] > TOL_MM or off["deg"] > TOL_DEG:
        raise ValueError(
            f"the model's bone frames do not match the asset's rest frames: bone '{naming.bones[off['bone_mm']]}' "
            f"is {off['mm']:.2f} mm off and '{naming.bones[off['bone_deg']]}' {off['deg']:.2f} deg off in the "
            f"best-fitting joint pose ({off['qpos0_mm']:.2f} mm / {off['qpos0_deg']:.2f} deg at qpos0; tolerance "
            f"{TOL_MM} mm / {TOL_DEG} deg): check the naming, or build an asset for this hand (physhand build-hand)")
    return off


def _add_self_proxies(spec, nm: Naming, asset) -> tuple:
    """Copy ``mjcf/hand/myohand.xml``'s self proxies (class ``self_proxy``: inert until SoftHand turns
    them on with Config.self_collision, hand_mjcf.enable_self_proxies) onto ``spec``'s bones as
    ``nm`` names them, in the same body frames (the frame check holds the bones to the asset's);
    none where a bone of the hand already carries one. Returns the names added."""
    import mujoco

    from physhand_mj.hand_mjcf import HAND_XML, SELF_PROXY_SUFFIX

    model_name = dict(zip((str(b) for b in asset.body_names), nm.bones))
    bones = set(nm.bones)
    if any(g.name.endswith(SELF_PROXY_SUFFIX) and g.parent.name in bones for g in spec.geoms):
        return ()
    added, hand = [], mujoco.MjSpec.from_file(str(HAND_XML))  # (kept alive: its geoms point into it)
    for g in hand.geoms:
        if not g.name.endswith(SELF_PROXY_SUFFIX) or g.parent.name not in model_name:
            continue
        c = spec.body(model_name[g.parent.name]).add_geom()
        c.name = nm.prefix + g.name
        for field in ("type", "size", "fromto", "pos", "quat", "contype", "conaffinity", "group", "density", "margin",
                      "friction", "rgba"):
            setattr(c, field, getattr(g, field))
        added.append(c.name)
    return tuple(added)


def add_skin(spec, naming="auto", asset=None, *, prefix: str = "", check_frames: bool = True,
             rgba=(0.87, 0.68, 0.58, 1.0), group: int = 2, self_proxies: bool = True) -> SkinAttachment:
    """Add the asset's skin mesh and its mesh geom to ``spec`` (a ``mujoco.MjSpec`` whose model has
    the hand's bones); returns a :class:`SkinAttachment`.

    The geom lives in the world body (world frame, like ``mjcf/hand/myohand.xml``'s), collides with
    nothing (contype = conaffinity = 0), has no mass (density 0), is drawn in geom ``group`` with
    ``rgba`` (0-1); its vertices start as the asset's rest skin placed by bone 0 at ``qpos0``.
    ``SoftHand(model, data, naming=result.naming)`` drives it after ``spec.compile()``. The spec is
    compiled once here to check the bones (``check_frames``: :func:`check_rest_frames`). Note that
    ids of geoms on bodies after the world body shift by one (compile afresh, look names up).
    ``self_proxies``: also copy the hand MJCF's self proxies onto the bones (inert until a SoftHand
    with ``Config.self_collision`` turns them on: docs/self_collision.md, "The bones keep the
    flesh's room"), unless the hand's bones carry them already; their names in the result.

    Raises ValueError: bones missing or ambiguous (listed), bone frames off the asset's rest frames
    (worst bone and offset in mm / degrees), the skin already added (geom or mesh of that name)."""
    import mujoco

    from physhand_mj.asset import load_asset
    from physhand_mj.rotations import quat_to_mat

    asset = asset if asset is not None else load_asset()
    model = spec.compile()
    nm = resolve_naming([model.body(b).name for b in range(model.nbody)], naming, asset, prefix)
    name = nm.skin_geom
    if any(g.name == name for g in spec.geoms) or any(m.name == name for m in spec.meshes):
        raise ValueError(f"the spec already has the skin ('{name}'): add_skin once per hand (a second hand "
                         f"needs its own prefix)")
    off = check_rest_frames(model, nm, asset) if check_frames else dict(mm=float("nan"), deg=float("nan"),
                                                                         bone_mm=0, fitted=False)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    b0 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, nm.bones[0])
    rot = data.xmat[b0].reshape(3, 3) @ quat_to_mat(np.asarray(asset.body_rest_quat[0], float)).T
    verts = (asset.skin_vertices - asset.body_rest_pos[0]) @ rot.T + data.xpos[b0]
    spec.add_mesh(name=name, uservert=verts.ravel().tolist(), userface=np.asarray(asset.skin_faces).ravel().tolist(),
                  inertia=mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL)
    spec.worldbody.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, contype=0, conaffinity=0,
                            group=group, density=0, rgba=list(rgba))
    added = _add_self_proxies(spec, nm, asset) if self_proxies else ()
    return SkinAttachment(geom=name, mesh=name, naming=nm, offset_mm=off["mm"], offset_deg=off["deg"],
                          worst_bone=nm.bones[off["bone_mm"]], fitted=off["fitted"], self_proxies=added)


def draw_skin(scene, vertices: np.ndarray, faces: np.ndarray, rgba=(0.87, 0.68, 0.58, 1.0)) -> int:
    """Append a skin (world vertices (n, 3) m, faces (F, 3)) to ``scene`` (``mujoco.MjvScene``) as
    ``mjGEOM_TRIANGLE`` geoms: MuJoCo draws such a geom as the triangle (0, 0, 0), (size[0], 0, 0),
    (0, size[1], 0) of its frame, so frame = (vertex 0, columns edge 1, edge 2, unit normal) and
    size 1 place the face exactly. For models compiled without the skin mesh (``SoftHand(...,
    writeback=False)``). Raises ValueError if the scene has no room (``maxgeom``)."""
    import mujoco

    x = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if scene.ngeom + len(f) > scene.maxgeom:
        raise ValueError(f"the scene has room for {scene.maxgeom - scene.ngeom} more geoms, the skin needs "
                         f"{len(f)}: make the renderer with max_geom >= {scene.ngeom + len(f)}")
    e1, e2 = x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    mats = np.stack([e1, e2, n], axis=2).reshape(-1, 9)
    size, color = np.ones(3), np.asarray(rgba, np.float32)
    tri = mujoco.mjtGeom.mjGEOM_TRIANGLE
    start = scene.ngeom
    for i in range(len(f)):
        mujoco.mjv_initGeom(scene.geoms[start + i], tri, size, x[f[i, 0]], mats[i], color)
    scene.ngeom = start + len(f)
    return len(f)
