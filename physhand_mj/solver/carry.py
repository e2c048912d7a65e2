"""The flesh behind contact-moved skin (``Config.tuning.flesh_carry``; docs/contact.md "The flesh
follows the contact").

The contact stage moves skin vertices only, and it comes after the constraints in every substep
(the object keeps the last word), so a push deeper than the skin layer's tets are thick shears them
inside out before the flesh behind can follow: an object 3 mm into the palm inverted 20-60 tets, a
bone 5 mm inside a sphere 389, however stiff the tets (a hard volume floor at 90 % of the rest
volume left 380). With ``flesh_carry`` = s > 0 each movable flesh vertex that shares a tet with skin
vertices moves, right after every contact stage, by s x the mean of those skin vertices' moves in
that stage: the layer under pushed skin goes with it, and the constraints of the next substep settle
the rest. Only the skin's positions are read and only those flesh vertices written: the contact's
own result (where the skin ends) is untouched within the stage.

    carry = FleshCarry(model, share, device)  # the flesh-skin neighbour lists, built once
    carry.record(rec, state, inv_mass, stage) # snapshot the skin, record the stage, then the carry
"""

from __future__ import annotations

import numpy as np
import warp as wp

from physhand_mj.contact.broadphase import TriList

wp.set_module_options({"enable_backward": False})


@wp.kernel
def snapshot_skin(x: wp.array(dtype=wp.vec3), before: wp.array(dtype=wp.vec3)):
    """The skin's positions before the contact stage (every world's skin: vertices [0, n_skin))."""
    i = wp.tid()
    before[i] = x[i]


@wp.kernel
def carry_flesh(flesh: wp.array(dtype=int), off: wp.array(dtype=int), skin: wp.array(dtype=int),
                before: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), share: float,
                near_wall: wp.array(dtype=int), wall_share: float, x: wp.array(dtype=wp.vec3)):
    """Flesh vertex ``flesh[k]`` moves by the mean over its skin neighbours ``skin[off[k]:off[k + 1]]``
    of their moves over the stage, each taken by ``share``, or by ``wall_share`` where
    ``near_wall`` (per skin vertex; empty: none) marks it (none where the flesh vertex is kinematic
    now: a bone's, a sleeping region's)."""
    k = wp.tid()
    j = flesh[k]
    if inv_mass[j] == 0.0:
        return
    s = wp.vec3(0.0)
    t = wp.vec3(0.0)
    walls = near_wall.shape[0] > 0
    for q in range(off[k], off[k + 1]):
        i = skin[q]
        if walls and near_wall[i] != 0:
            t = t + (x[i] - before[i])
        else:
            s = s + (x[i] - before[i])
    n = float(off[k + 1] - off[k])
    x[j] = x[j] + s * (share / n) + t * (wall_share / n)


@wp.kernel
def mark_near_walls(faces: wp.array2d(dtype=int), cand: TriList, cand_count: wp.array(dtype=int),
                    tris_per_world: int, geoms_per_world: int, wall: wp.array(dtype=int),
                    near_wall: wp.array(dtype=int)):
    """near_wall[v] = 1 for the corners of every triangle of the frame's contact list (``cand``, its
    length ``cand_count[0]``) whose mask holds a wall geom (``wall``, per geom). The mask's bit 30
    stands for all of the world's geoms from its 31st on (broadphase.reach_mask), so in a world of
    more than 30 geoms a triangle near one of those counts as near a wall when any of them is one
    (the share then applies a little wider than it must)."""
    k = wp.tid()
    if k >= cand_count[0]:
        return
    t = cand.tri[k]
    mask = cand.mask[k]
    g0 = (t // tris_per_world) * geoms_per_world
    hit = int(0)
    for b in range(30):
        if (mask & (1 << b)) != 0 and b < geoms_per_world:
            hit = hit | wall[g0 + b]
    if (mask & (1 << 30)) != 0:
        for g in range(30, geoms_per_world):
            hit = hit | wall[g0 + g]
    if hit != 0:
        near_wall[faces[t, 0]] = 1
        near_wall[faces[t, 1]] = 1
        near_wall[faces[t, 2]] = 1


def flesh_neighbours(tets: np.ndarray, n_skin: int, inv_mass: np.ndarray):
    """(flesh vertices (F,), CSR offsets (F + 1,), their skin neighbours): every movable non-skin
    vertex sharing a tet with a skin vertex, and those skin vertices (each once, ascending)."""
    tets = np.asarray(tets, np.int64)
    movable = np.asarray(inv_mass) > 0
    n = int(tets.max()) + 1 if tets.size else 1
    keys = []
    for a in range(4):  # (vectorised: a batch's tets are every world's)
        for b in range(4):
            if a != b:
                f, s = tets[:, a], tets[:, b]
                keep = (f >= n_skin) & (s < n_skin)
                keep[keep] &= movable[f[keep]]
                keys.append(f[keep] * n + s[keep])
    key = np.unique(np.concatenate(keys))
    if not key.size:
        return np.zeros(0, np.int32), np.zeros(1, np.int32), np.zeros(0, np.int32)
    p = np.stack([key // n, key % n], axis=1)
    flesh, counts = np.unique(p[:, 0], return_counts=True)
    off = np.concatenate([[0], np.cumsum(counts)])
    return flesh.astype(np.int32), off.astype(np.int32), p[:, 1].astype(np.int32)


class FleshCarry:
    """The carry's lists on the model's device (built when a frame first records a carry: a scene
    where none acts pays nothing), its snapshot buffer and, for ``wall_share``, the frame's skin near
    broad walls (one per solver)."""

    def __init__(self, model, share: float, device, wall_share: float = 0.0):
        self.model = model
        self.share = float(share)
        self.wall_share = float(wall_share)
        self.n_skin = int(model.n_skin)
        self.device = device
        self.flesh = None  # (flesh vertices, CSR offsets, skin neighbours, snapshot: _build)
        self.near_wall = wp.zeros(0, dtype=int, device=device)  # (per skin vertex, made once a wall is seen)
        self._wall = None  # per geom of the contact's objects: 1 a broad wall, on the device
        self._walls_now = False  # (whether the frame being recorded marks the skin near walls)
        self._no_walls = self.near_wall

    def _build(self) -> None:
        if self.flesh is not None:
            return
        m, d = self.model, self.device
        flesh, off, skin = flesh_neighbours(m.tet_ids.numpy(), m.n_skin, m.inv_mass.numpy())
        self.flesh = wp.array(flesh, dtype=int, device=d)
        self.off = wp.array(off, dtype=int, device=d)
        self.skin = wp.array(skin, dtype=int, device=d)
        self.before = wp.zeros(m.n_skin, dtype=wp.vec3, device=d)

    def walls(self, contact) -> bool:
        """Whether the wall share acts in ``contact``'s scene as it is now: it exceeds the share
        everywhere and some object is a broad wall (asked at every recording)."""
        return self.wall_share > self.share and bool(contact.points.wall_geom.any())

    def acts(self, contact) -> bool:
        """Whether any stage's move carries flesh in ``contact``'s scene (else nothing is recorded)."""
        return self.share > 0.0 or self.walls(contact)

    def record_frame(self, rec, contact) -> None:
        """Once per frame after the contact's broadphase: the skin near a broad wall (the corners of
        the frame list's triangles within the frame margin of one), where ``wall_share`` applies.
        The walls are read here, at recording (a frame recorded again after the objects changed
        reads them again)."""
        self._build()
        self._walls_now = self.walls(contact)
        if not self._walls_now:
            return
        flags = np.zeros(max(int(contact.objects.capacity), 1), np.int32)
        w = contact.points.wall_geom
        flags[: len(w)] = w
        if self._wall is None or self._wall.shape[0] != flags.shape[0]:
            self._wall = wp.array(flags, dtype=int, device=self.device)
        else:
            self._wall.assign(flags)
        if not self.near_wall.shape[0]:
            self.near_wall = wp.zeros(self.n_skin, dtype=int, device=self.device)
        rec.ops.append(self.near_wall.zero_)
        m = contact.model
        rec.launch(mark_near_walls, contact.n_tris,
                   [m.skin_faces, contact.lists.cand_tris, contact.cand_count, contact.tris_per_world,
                    contact.geoms_per_world, self._wall], [self.near_wall], count=contact.cand_count)

    def record(self, rec, state, inv_mass, stage) -> None:
        """Record the skin's snapshot, ``stage()`` (the contact stage's launches), then the carry."""
        self._build()
        rec.launch(snapshot_skin, self.n_skin, [state.x], [self.before])
        stage()
        wall_share = max(self.wall_share, self.share)
        rec.launch(carry_flesh, int(self.flesh.shape[0]),
                   [self.flesh, self.off, self.skin, self.before, inv_mass, self.share,
                    self.near_wall if self._walls_now else self._no_walls, wall_share], [state.x])
