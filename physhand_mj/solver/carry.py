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

wp.set_module_options({"enable_backward": False})


@wp.kernel
def snapshot_skin(x: wp.array(dtype=wp.vec3), before: wp.array(dtype=wp.vec3)):
    """The skin's positions before the contact stage (every world's skin: vertices [0, n_skin))."""
    i = wp.tid()
    before[i] = x[i]


@wp.kernel
def carry_flesh(flesh: wp.array(dtype=int), off: wp.array(dtype=int), skin: wp.array(dtype=int),
                before: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), share: float,
                x: wp.array(dtype=wp.vec3)):
    """Flesh vertex ``flesh[k]`` moves by ``share`` x the mean move of its skin neighbours
    ``skin[off[k]:off[k + 1]]`` over the stage (none where it is kinematic now: a bone's, a sleeping
    region's)."""
    k = wp.tid()
    j = flesh[k]
    if inv_mass[j] == 0.0:
        return
    s = wp.vec3(0.0)
    for q in range(off[k], off[k + 1]):
        i = skin[q]
        s = s + (x[i] - before[i])
    x[j] = x[j] + s * (share / float(off[k + 1] - off[k]))


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
    """The carry's lists on the model's device and its snapshot buffer (one per solver)."""

    def __init__(self, model, share: float, device):
        d = device
        flesh, off, skin = flesh_neighbours(model.tet_ids.numpy(), model.n_skin, model.inv_mass.numpy())
        self.share = float(share)
        self.flesh = wp.array(flesh, dtype=int, device=d)
        self.off = wp.array(off, dtype=int, device=d)
        self.skin = wp.array(skin, dtype=int, device=d)
        self.before = wp.zeros(model.n_skin, dtype=wp.vec3, device=d)
        self.n_skin = int(model.n_skin)

    def record(self, rec, state, inv_mass, stage) -> None:
        """Record the skin's snapshot, ``stage()`` (the contact stage's launches), then the carry."""
        rec.launch(snapshot_skin, self.n_skin, [state.x], [self.before])
        stage()
        rec.launch(carry_flesh, int(self.flesh.shape[0]),
                   [self.flesh, self.off, self.skin, self.before, inv_mass, self.share], [state.x])
