"""Per-region sleeping (``Config.region_sleep``): parts of the hand that have settled sleep alone.

The whole hand sleeps when nothing moves (activity.py, ``Config.sleep_speed``). Often only a part
of it is still: the fingers of a hand pressing a button with its index, the thumb of a hand closing
its fingers. The soft vertices are split into regions by the bone that carries them at rest
(``Model.vertex_carrier``): the palm (carpals, metacarpals 2-5, the forearm stub), the thumb (first
metacarpal and its phalanges) and each finger (its three phalanges). A region falls asleep after
``Config.tuning.sleep_frames`` frames in which

- its bones and those of the regions it shares a constraint with (a finger's neighbours: the palm and
  the fingers beside it, whose motion pulls on the web between them) moved relative to the first
  bone by at most ``Config.tuning.sleep_bone_motion`` (m per frame, the whole-hand test's measure,
  :func:`physhand_mj.solver.sleep.bone_motions`),
- none of its soft vertices moved faster than ``Config.sleep_speed`` relative to its carrier bone
  (the whole-hand test's, counted per region by ``integrate.advance``), and
- no object came within ``Config.contact_frame_margin`` of the region's skin (a bound of it from its
  bones, spheres about points fixed to them holding their soft vertices at rest plus BOUND_SLACK,
  against the objects' bounding spheres, ``activity.objects_near``: host work only).

Asleep, its vertices are kinematic: each rides its carrier bone rigidly from where it was when the
region fell asleep (``inv_mass`` 0, ``vertex_body`` its carrier, ``body_local`` its position in that
bone's frame, the skeleton vertices' own mechanism in ``integrate.advance``), and the constraints
whose vertices are all asleep are left out of the launches (``order``: a compacted list of the
others per family, rebuilt when a region falls asleep or wakes; on CUDA the launch keeps its size
and the threads past the list return; where that does not apply, colour ranges or gather slots,
every constraint runs and returns at once). Awake neighbours see the sleeping side as fixed to
its bones. A region wakes, before the frame that would break one of the conditions is solved, when
one of its or its neighbours' bones moves relative to the first bone by more than the tolerance in
that frame or since it fell asleep, the first bone turns by more than SLEEP_TURN
(gravity turns in the hand) or changes its velocity by more than ``Config.sleep_speed`` since then,
or an object comes within the margin; its vertices then go on from their carried positions (no
jump: they never left them). One world (batched worlds: not yet).
"""

from __future__ import annotations

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # forward only: no gradients are taken; adjoints cost compile time

REGION_NAMES = ("palm", "thumb", "index", "middle", "ring", "little")
BOUND_SLACK = 0.005  # m: a region's skin bound beyond its soft vertices' rest distance from their bone


def body_regions(body_names) -> np.ndarray:
    """Region index (into REGION_NAMES) of every bone, from the MyoHand's bone names: the thumb's
    first metacarpal and phalanges, each finger's three phalanges, the palm for the rest (an asset
    with other names is all palm: it sleeps as one region)."""
    out = np.zeros(len(body_names), np.int32)
    for b, name in enumerate(str(n) for n in body_names):
        if name.startswith(("firstmc", "proximal_thumb", "distal_thumb")):
            out[b] = 1
        for k in range(2, 6):
            if name.startswith((f"{k}proxph", f"midph{k}", f"distph{k}")):
                out[b] = k
    return out


@wp.kernel
def set_region_sleep(
    region: wp.array(dtype=int),
    carrier: wp.array(dtype=int),
    asleep: wp.array(dtype=int),
    inv_mass0: wp.array(dtype=float),
    vertex_body0: wp.array(dtype=int),
    body_local0: wp.array(dtype=wp.vec3),
    body_pose: wp.array2d(dtype=wp.transform),
    x: wp.array(dtype=wp.vec3),
    inv_mass: wp.array(dtype=float),
    vertex_body: wp.array(dtype=int),
    body_local: wp.array(dtype=wp.vec3),
):
    """Make the soft vertices of the regions with ``asleep[r]`` != 0 kinematic on their carrier bone
    at their position now (in the bone's frame at the frame's start, ``body_pose[0]``), and restore
    the others' model values (``*0``)."""
    i = wp.tid()
    r = region[i]
    if r < 0:
        return
    if asleep[r] != 0:
        b = carrier[i]
        inv_mass[i] = 0.0
        vertex_body[i] = b
        body_local[i] = wp.transform_point(wp.transform_inverse(body_pose[0, b]), x[i])
    else:
        inv_mass[i] = inv_mass0[i]
        vertex_body[i] = vertex_body0[i]
        body_local[i] = body_local0[i]


@wp.kernel
def reset_region_fast(fast: wp.array(dtype=int)):
    fast[wp.tid()] = 0


class RegionSleep:
    """The per-region sleep state of one :class:`~physhand_mj.solver.Solver` (one world, one state):
    the live copies of the model's ``inv_mass`` / ``vertex_body`` / ``body_local`` the solver's
    kernels read, the per-region counters, and the host decisions (module docstring)."""

    def __init__(self, solver):
        m, d = solver.model, solver.device
        self.solver = solver
        self.n = len(REGION_NAMES)
        of_body = body_regions(m.body_names)
        carrier = m.vertex_carrier.numpy()
        vb, w = m.vertex_body.numpy(), m.inv_mass.numpy()
        soft = (carrier >= 0) & (vb < 0) & (w > 0)
        vr = np.where(soft, of_body[np.maximum(carrier, 0)], -1).astype(np.int32)
        self.bones = [np.flatnonzero(of_body == r) for r in range(self.n)]
        # regions joined by a constraint (edges and tets between their vertices, skeleton vertices
        # by their bone's region): a region's bones moving wakes its neighbours too, whose flesh and
        # skin it pulls on (the web between two fingers)
        vbody = np.where(vb >= 0, of_body[np.maximum(vb, 0)], np.where(carrier >= 0, of_body[np.maximum(carrier, 0)], -1))
        adj = np.eye(self.n, dtype=bool)
        for ids in (m.edge_ids, m.tet_ids):
            e = ids.numpy() if hasattr(ids, "numpy") else np.asarray(ids)
            if len(e):
                reg = vbody[e]
                for a in range(reg.shape[1]):
                    for b in range(reg.shape[1]):
                        ok = (reg[:, a] >= 0) & (reg[:, b] >= 0)
                        adj[reg[ok, a], reg[ok, b]] = True
        self.neighbours = adj
        # per constraint family, the constraints to solve (those with a vertex awake): the regions of
        # its soft vertices as a bit mask (bit n: a soft vertex in no region, never asleep); one
        # colour range per family (Jacobi) and no gather slots (a skipped constraint's slots would go
        # stale), else every constraint runs and returns at once when all its vertices are asleep
        self.order: dict = {}
        self._masks: dict = {}
        if solver.config.scheme.name == "JACOBI" and not m.gather_off:
            soft_any = (vb < 0) & (w > 0)
            bit = np.where(vr >= 0, 1 << np.maximum(vr, 0), np.where(soft_any, 1 << self.n, 0)).astype(np.int64)
            for name, ids in (("edge", m.edge_ids), ("tet", m.tet_ids), ("dih", m.dih_ids)):
                e = ids.numpy()
                if not len(e) or m.colors.get(name) != [(0, len(e))]:
                    continue
                mask = np.bitwise_or.reduce(bit[e], axis=1)
                self._masks[name] = mask
                order = wp.array(np.arange(len(e), dtype=np.int32), dtype=int, device=d)
                count = wp.array([len(e)], dtype=int, device=d)
                self.order[name] = (order, count)
        # constraints solved per family (without compacted lists every constraint runs)
        self.solved = {name: len(mk) for name, mk in self._masks.items()} or {
            name: int(ids.shape[0]) for name, ids in (("edge", m.edge_ids), ("tet", m.tet_ids), ("dih", m.dih_ids))}
        self.vertices = np.bincount(vr[vr >= 0], minlength=self.n)  # soft vertices per region
        self.vertex_region = wp.array(vr, dtype=int, device=d)
        self.inv_mass = wp.clone(m.inv_mass)
        self.vertex_body = wp.clone(m.vertex_body)
        self.body_local = wp.clone(m.body_local)
        self._asleep_dev = wp.zeros(self.n, dtype=int, device=d)
        self.fast = wp.zeros(self.n, dtype=int, device=d)
        pinned = d.is_cuda
        self._fast_host = wp.zeros(self.n, dtype=int, device="cpu", pinned=pinned)
        # each region's skin bound from its bones (host only, no kernel or copy): per carrier bone a
        # sphere about a point fixed to it (its skeleton vertices' centre) holding every soft vertex
        # it carries at rest, grown by BOUND_SLACK for the flesh's sag and deformation
        rest = m.rest_x.numpy().astype(np.float64)
        local = m.body_local.numpy().astype(np.float64)
        self._centre_local = np.zeros((m.n_bodies, 3))
        self._radius = np.zeros(m.n_bodies)
        for b in range(m.n_bodies):
            skel = vb == b
            if not skel.any():
                continue
            self._centre_local[b] = local[skel].mean(axis=0)
            centre_rest = rest[skel].mean(axis=0)
            carried = soft & (carrier == b)
            self._radius[b] = np.linalg.norm(rest[carried] - centre_rest, axis=1).max(initial=0.0) + BOUND_SLACK
        self.asleep = np.zeros(self.n, bool)
        self.still = np.zeros(self.n, int)  # consecutive still frames per region
        self.near = np.zeros(self.n, bool)  # an object within the margin of the region at the last frame's end
        self.onset: list = [None] * self.n  # ((B, 7) poses, first bone's velocity) when the region fell asleep
        self._dirty = False
        self._moved = np.zeros(self.n)  # m, the last frame's relative bone motion per region

    # -- recording ---------------------------------------------------------------------------------
    def record_start(self, launch) -> None:
        launch(reset_region_fast, self.n, [], [self.fast])

    def copy_back(self) -> None:
        wp.copy(self._fast_host, self.fast)

    def boxes(self, poses: np.ndarray) -> np.ndarray:
        """(R, 2, 3) m: each region's skin bound for bone poses (B, 7) [p, q x y z w]."""
        from physhand_mj.rotations import quat_to_mat

        rot = quat_to_mat(poses[:, [6, 3, 4, 5]].astype(np.float64))
        centre = np.einsum("bij,bj->bi", rot, self._centre_local) + poses[:, :3]
        out = np.zeros((self.n, 2, 3))
        for r in range(self.n):
            b = self.bones[r]
            if len(b):
                out[r, 0] = (centre[b] - self._radius[b, None]).min(axis=0)
                out[r, 1] = (centre[b] + self._radius[b, None]).max(axis=0)
        return out

    # -- host, per frame -------------------------------------------------------------------------
    def before_frame(self, p0: np.ndarray, p1: np.ndarray) -> None:
        """Wake the regions this frame's bone motion (poses (B, 7) at its start and end) or a near
        object calls for, and put to sleep those that have been still long enough."""
        from physhand_mj.rotations import pose_turn
        from physhand_mj.solver.sleep import SLEEP_TURN, bone_motions

        cfg = self.solver.config
        tol = cfg.sleep_bone_motion
        if not len(p0):
            return
        vel = (p1[0, :3].astype(np.float64) - p0[0, :3]) / cfg.frame_dt  # the first bone's velocity, m/s
        motion = bone_motions(p0, p1)
        own = np.array([motion[b].max(initial=0.0) for b in self.bones])
        # a region's motion: its own bones' and its neighbours' (relative to the first bone)
        self._moved = np.array([own[self.neighbours[r]].max(initial=0.0) for r in range(self.n)])
        for r in range(self.n):
            if not self.vertices[r]:
                continue
            if self.asleep[r]:
                onset, vel0 = self.onset[r]
                # since it fell asleep: its own bones and its neighbours' (a neighbour creeping under
                # the per-frame tolerance would otherwise pull on the frozen web without waking it)
                near_bones = np.concatenate([self.bones[q] for q in np.flatnonzero(self.neighbours[r])])
                since = bone_motions(onset, p1)[near_bones].max(initial=0.0)
                if (self._moved[r] > tol or since > tol or self.near[r] or np.linalg.norm(vel - vel0) > cfg.sleep_speed
                        or pose_turn(onset[0], p1[0]) > SLEEP_TURN):
                    self.asleep[r] = False
                    self.still[r] = 0
                    self.onset[r] = None
                    self._dirty = True
            elif self.still[r] >= cfg.sleep_frames and not self.near[r] and self._moved[r] <= tol:
                self.asleep[r] = True
                self.onset[r] = (p0.copy(), vel)
                self._dirty = True

    def apply(self, state) -> None:
        """After the frame's pose upload: the kinematic switch of the regions that changed."""
        if not self._dirty:
            return
        m = self.solver.model
        self._asleep_dev.assign(self.asleep.astype(np.int32))
        asleep_bits = int(sum(1 << r for r in range(self.n) if self.asleep[r]))
        for name, mask in self._masks.items():  # the awake constraints first, in their order
            keep = np.flatnonzero(mask & ~asleep_bits).astype(np.int32)
            order, count = self.order[name]
            if order.device.is_cpu:
                order.numpy()[: len(keep)] = keep  # (a view of CPU memory)
            elif len(keep):
                wp.copy(order, wp.array(keep, dtype=int, device=order.device), count=len(keep))
            count.assign(np.array([len(keep)], np.int32))
            self.solved[name] = len(keep)
        wp.launch(set_region_sleep, m.n_vertices,
                  inputs=[self.vertex_region, m.vertex_carrier, self._asleep_dev, m.inv_mass, m.vertex_body,
                          m.body_local, state.body_pose, state.x],
                  outputs=[self.inv_mass, self.vertex_body, self.body_local], device=self.solver.device)
        self._dirty = False

    def after_frame(self, poses: np.ndarray) -> None:
        """After the frame's sync: count still frames per region (bones, vertex speeds, objects near
        its skin bound at the frame's end bone ``poses`` (B, 7))."""
        from physhand_mj.solver.activity import objects_near

        cfg = self.solver.config
        fast = self._fast_host.numpy()
        c = self.solver.contact
        box = self.boxes(poses).reshape(self.n, 6) if c is not None and len(c.objects) else None
        for r in range(self.n):
            if not self.vertices[r]:
                continue
            near = False
            if c is not None and len(c.objects):
                near = objects_near(c.objects, box[r, :3].astype(float), box[r, 3:].astype(float),
                                    cfg.contact_frame_margin) > 0
            self.near[r] = near
            still = self._moved[r] <= cfg.sleep_bone_motion and fast[r] == 0 and not near
            self.still[r] = self.still[r] + 1 if still else 0

    def wake_all(self) -> None:
        if self.asleep.any():
            self._dirty = True
        self.asleep[:] = False
        self.still[:] = 0
        self.onset = [None] * self.n

    def report(self, whole_hand: bool = False) -> dict:
        """The regions asleep after the last frame (names), the soft vertices they hold and the
        constraints solved; ``whole_hand``: the whole hand slept (every region rode its bones and no
        constraint was solved; the regions' own state waits for it to wake)."""
        asleep = self.vertices > 0 if whole_hand else self.asleep
        names = [REGION_NAMES[r] for r in range(self.n) if asleep[r]]
        return dict(regions_asleep=names, vertices_asleep=int(self.vertices[asleep].sum()),
                    constraints_solved=0 if whole_hand else int(sum(self.solved.values())))
