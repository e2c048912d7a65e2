"""What only a soft hand can sense, pooled on the solver's device inside the frame.

Per hand region (fingertips, phalanges, palm, ... or one region per pad of a robot gripper) and per
contact object, after every solver frame:

- contact area (m^2): the skin area (a third of each adjacent deformed triangle) of the vertices
  the contact moved this frame;
- normal force estimate (N): SoftHand's estimate (each Eq. 9 projection of a vertex of mass m by dx
  in a substep h is an impulse m dx / h; averaged over the frame's substeps), summed;
- contacting vertices (count);
- deformation (m): the largest distance of a region's skin vertex from where its bone would carry
  its rest position rigidly (pad / fingertip compression, plus the settled sag and joint bending).

**One host sync.** :class:`SensedHand` launches the pooling kernels after the solver frame and
before SoftHand's write-back; on CUDA their small results go to pinned host buffers with
asynchronous copies and one device sync completes them (the write-back's device half runs inside
the solver's frame graph since 2026-11-25 and has no sync of its own to share), so reading them
afterwards is a host read. On the CPU Warp kernels run synchronously and the outputs are host memory already.
The penetration figures come from the frame's own metrics row (``SoftHand.step``'s return), which
the solver reads at its one sync.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from physhand_mj import SoftHand

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

# The embedded MyoHand's anatomical regions: skin vertices go to the body of their nearest skeleton
# vertex (the asset's flesh/skin attachment pairs); metacarpal and carpal skin is split into palm and
# back by the side of the bone it lies on (the asset's palm normal).
FINGERS = ("thumb", "index", "middle", "ring", "little")
_TIPS = ("distal_thumb_r", "distph2_r", "distph3_r", "distph4_r", "distph5_r")
_PHALANGES = (("proximal_thumb_r",), ("2proxph_r", "midph2_r"), ("3proxph_r", "midph3_r"), ("4proxph_r", "midph4_r"),
              ("5proxph_r", "midph5_r"))
_FOREARM = ("ulna_r", "radius_r")
HAND_REGIONS = tuple(f"{f}_tip" for f in FINGERS) + tuple(f"{f}_phalanges" for f in FINGERS) + (
    "palm", "back", "forearm")


def skin_bones(asset) -> np.ndarray:
    """(n_skin,) body index (into ``asset.body_names``) of each skin vertex's nearest skeleton vertex."""
    n = asset.n_skin
    bone = np.full(n, -1, np.int64)
    att = np.asarray(asset.attach)
    skin = att[:, 0] < n
    bone[att[skin, 0]] = np.asarray(asset.vertex_body)[att[skin, 1]]
    if np.any(bone < 0):
        raise ValueError(f"{int(np.sum(bone < 0))} skin vertices have no skeleton attachment: rebuild the asset")
    return bone


def regions(asset) -> tuple[tuple[str, ...], np.ndarray]:
    """(region names, (n_skin,) region index of each skin vertex) for ``asset``: the anatomical
    regions :data:`HAND_REGIONS` for the embedded MyoHand, else one region per body (robot pads)."""
    names = [str(b) for b in asset.body_names]
    bone = skin_bones(asset)
    if not set(_TIPS) <= set(names):
        return tuple(names), bone.astype(np.int32)
    out = np.full(asset.n_skin, -1, np.int32)
    by_body = {}
    for r, tip in enumerate(_TIPS):
        by_body[tip] = r
    for r, group in enumerate(_PHALANGES):
        for b in group:
            by_body[b] = 5 + r
    for b in _FOREARM:
        by_body[b] = 12
    palm, back = 10, 11
    x = asset.positions
    att = np.asarray(asset.attach)
    nearest = np.empty(asset.n_skin, np.int64)
    skin = att[:, 0] < asset.n_skin
    nearest[att[skin, 0]] = att[skin, 1]
    normal = np.asarray(asset.meta.get("palm_normal", (0.0, 0.0, -1.0)), float)
    side = np.einsum("ij,j->i", x[: asset.n_skin] - x[nearest], normal) > 0.0
    for i, b in enumerate(bone):
        out[i] = by_body.get(names[b], palm if side[i] else back)
    return HAND_REGIONS, out


def rest_local(asset) -> tuple[np.ndarray, np.ndarray]:
    """(bone (n_skin,), local (n_skin, 3)): each skin vertex's bone and its rest position in that
    bone's frame, R_rest^T (x_rest - p_rest) (m)."""
    n = asset.n_skin
    bone = skin_bones(asset)
    rel = asset.positions[:n] - np.asarray(asset.body_rest_pos, float)[bone]
    return bone, _rotate(_conj(np.asarray(asset.body_rest_quat, float)[bone]), rel)


def rigid_skin(asset, xpos: np.ndarray, xquat: np.ndarray) -> np.ndarray:
    """(n_skin, 3) the rest skin carried rigidly by each vertex's bone at bone poses ``xpos`` (B, 3),
    ``xquat`` (B, 4) w x y z (ordered as ``asset.body_names``)."""
    bone, local = rest_local(asset)
    return _rotate(np.asarray(xquat, float)[bone], local) + np.asarray(xpos, float)[bone]


@wp.kernel
def vertex_area(faces: wp.array2d(dtype=int), x: wp.array(dtype=wp.vec3), area_out: wp.array(dtype=float)):
    """A third of each deformed skin triangle's area to each of its vertices (m^2)."""
    f = wp.tid()
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    a = wp.length(wp.cross(x[i1] - x[i0], x[i2] - x[i0])) / 6.0
    wp.atomic_add(area_out, i0, a)
    wp.atomic_add(area_out, i1, a)
    wp.atomic_add(area_out, i2, a)


@wp.kernel
def pool(
    # Model:
    mass: wp.array(dtype=float), region: wp.array(dtype=int), bone: wp.array(dtype=int),
    local: wp.array(dtype=wp.vec3), force_scale: float,
    # Data in:
    x: wp.array(dtype=wp.vec3), area: wp.array(dtype=float), push: wp.array(dtype=float),
    vertex_obj: wp.array(dtype=int), body_pose: wp.array2d(dtype=wp.transform),
    # Data out:
    region_out: wp.array2d(dtype=float), obj_out: wp.array2d(dtype=float),
):
    """Per skin vertex i: deformation |x_i - T_bone(local_i)| (max per region, m); where the contact
    moved it this frame (push_i > 0), force m_i push_i / (h^2 s) (N), its area and a count go to its
    region and its object. Rows: region [area, force, count, max deformation], object [area, force, count]."""
    i = wp.tid()
    r = region[i]
    rigid = wp.transform_point(body_pose[1, bone[i]], local[i])
    wp.atomic_max(region_out, r, 3, wp.length(x[i] - rigid))
    p = push[i]
    if p > 0.0:
        f = mass[i] * p * force_scale
        wp.atomic_add(region_out, r, 0, area[i])
        wp.atomic_add(region_out, r, 1, f)
        wp.atomic_add(region_out, r, 2, 1.0)
        k = vertex_obj[i]
        if k >= 0:
            wp.atomic_add(obj_out, k, 0, area[i])
            wp.atomic_add(obj_out, k, 1, f)
            wp.atomic_add(obj_out, k, 2, 1.0)


class SoftSensor:
    """Preallocated buffers and launches of the pooling for one SoftHand (see the module docstring), or
    for the W worlds of a :class:`~physhand_mj.batch.BatchedHands` (``worlds``): world w's skin is
    vertices [w n_skin, (w + 1) n_skin), its regions rows [w R, (w + 1) R) of ``region_host`` and its
    objects rows [w n, (w + 1) n) of ``obj_host`` (the batch's object order); one launch pools all."""

    def __init__(self, hand, worlds: int = 1):
        a = hand.asset
        n = a.n_skin
        W = int(worlds)
        self.n, self.worlds = n, W
        self.region_names, region = regions(a)
        bone, local = rest_local(a)
        R, B = len(self.region_names), len(a.body_names)
        k = np.repeat(np.arange(W), n)  # (each world's rows: regions, bones and faces shifted by it)
        region, bone, local = np.tile(region, W) + k * R, np.tile(bone, W) + k * B, np.tile(local, (W, 1))
        faces = np.concatenate([np.asarray(a.skin_faces) + w * n for w in range(W)])
        d = hand.solver.model.device
        self.device = wp.get_device(d)
        self.mass = wp.array(np.tile(np.asarray(a.mass[:n], np.float32), W), dtype=float, device=d)
        self.region = wp.array(region.astype(np.int32), dtype=int, device=d)
        self.bone = wp.array(bone.astype(np.int32), dtype=int, device=d)
        self.local = wp.array(local.astype(np.float32), dtype=wp.vec3, device=d)
        self.faces = wp.array(faces.astype(np.int32), dtype=int, device=d)
        self.area = wp.zeros(n * W, dtype=float, device=d)
        n_obj = max(len(hand.objects.object_names), 1) if hand.solver.contact is not None else 1
        self.object_names = tuple(hand.objects.object_names) if hand.solver.contact is not None else ()
        self.region_out = wp.zeros((R * W, 4), dtype=float, device=d)
        self.obj_out = wp.zeros((n_obj, 3), dtype=float, device=d)
        cfg = hand.config
        self.force_scale = float(1.0 / (cfg.substep_dt ** 2 * cfg.substeps))
        contact = hand.solver.contact
        n_all = hand.solver.model.n_vertices
        self.push = contact.push if contact is not None else wp.zeros(n_all, dtype=float, device=d)
        self.vertex_obj = contact.vertex_obj if contact is not None else wp.full(n_all, -1, dtype=int, device=d)
        if self.device.is_cpu:  # host memory already: the numpy views alias the outputs
            self._region_host, self._obj_host = self.region_out, self.obj_out
        else:
            self._region_host = wp.zeros(self.region_out.shape, dtype=float, device="cpu", pinned=True)
            self._obj_host = wp.zeros(self.obj_out.shape, dtype=float, device="cpu", pinned=True)
        self.region_host = self._region_host.numpy()
        self.obj_host = self._obj_host.numpy()
        self.frames = 0
        self.seconds = 0.0  # host time spent launching (all of it on the CPU, where kernels run inline)

    def launch(self, hand: SoftHand) -> None:
        """Enqueue the pooling of the frame just solved (no sync; see the module docstring)."""
        t0 = time.perf_counter()
        d = self.device
        self.area.zero_()
        self.region_out.zero_()
        self.obj_out.zero_()
        x = hand.state.x
        wp.launch(vertex_area, self.faces.shape[0], inputs=[self.faces, x], outputs=[self.area], device=d)
        wp.launch(pool, self.n * self.worlds, inputs=[self.mass, self.region, self.bone, self.local, self.force_scale, x, self.area,
                                        self.push, self.vertex_obj, hand.state.body_pose],
                  outputs=[self.region_out, self.obj_out], device=d)
        if not d.is_cpu:
            wp.copy(self._region_host, self.region_out)
            wp.copy(self._obj_host, self.obj_out)
        self.frames += 1
        self.seconds += time.perf_counter() - t0


class SensedHand(SoftHand):
    """SoftHand whose frames also run :class:`SoftSensor` (between the solver frame and the write-back;
    on CUDA a device sync after its launches completes its copies: the write-back's device half runs
    inside the frame's graph, before them)."""

    sensor: SoftSensor | None = None

    def attach_sensor(self) -> SoftSensor:
        self.sensor = SoftSensor(self)
        self.sensor.launch(self)
        return self.sensor

    def _write_back(self, after_frame: bool = False) -> None:
        if self.sensor is not None:
            self.sensor.launch(self)
            if after_frame and self._tail_writer:  # (CUDA: the frame's write-back ran in its graph, no sync
                wp.synchronize_device(self.sensor.device)  # of its own is left to complete the copies)
        super()._write_back(after_frame)


def _conj(q):
    return np.concatenate([q[:, :1], -q[:, 1:]], axis=1)


def _rotate(q, v):
    """Rotate vectors v (n, 3) by unit quaternions q (n, 4) w x y z."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)
