"""Host-side diagnostics of a solver state: XPBD residuals, volumes, energies (numpy; not per step).

The XPBD residual of constraint j after a substep is ``r_j = C_j(x) + alpha~_j lam_j`` (Macklin et
al. 2016, Eq. 8 with the multiplier of the last substep): zero when the compliant constraint is
solved exactly. Families are made dimensionless so that they can be compared: edges and
attachments divided by the rest length, tets by 6 x rest volume, dihedrals in radians.
"""

from __future__ import annotations

import numpy as np

from physhand_mj.solver.model import signed_dihedral
from physhand_mj.types import Config, Model, State


def signed_volumes6(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """6 x signed volume of each tet (m^3), Eq. 3's x21 x x31 . x41."""
    a, b, c, d = (x[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def residuals(model: Model, state: State, config: Config) -> dict[str, float]:
    """RMS of the dimensionless XPBD residual per constraint family, and their overall RMS."""
    x = state.x.numpy().astype(np.float64)
    inv_h2 = 1.0 / config.substep_dt ** 2
    out, sq, count = {}, 0.0, 0
    fams = {
        "edge": (model.edge_ids, model.edge_rest, model.edge_alpha.numpy(), state.lam_edge),
        "tet": (model.tet_ids, model.tet_rest6v, model.tet_alpha.numpy(), state.lam_tet),
        "dih": (model.dih_ids, model.dih_rest, model.dih_alpha, state.lam_dih),
    }
    for name, (ids, rest, alpha, lam) in fams.items():
        ids = ids.numpy()
        if not len(ids):
            continue
        rest = rest.numpy().astype(np.float64)
        if name == "edge":  # (a negative rest: stretch only, no residual while shorter)
            c = np.linalg.norm(x[ids[:, 0]] - x[ids[:, 1]], axis=1) - np.abs(rest)
            c = np.where(rest < 0, np.maximum(c, 0.0), c)
            scale = np.abs(rest)
        elif name == "tet":
            c = signed_volumes6(x, ids) - rest
            scale = rest
        else:
            c = signed_dihedral(x, ids) - rest
            c = (c + np.pi) % (2 * np.pi) - np.pi
            scale = np.ones_like(rest)
        r = (c + np.asarray(alpha, dtype=np.float64) * inv_h2 * lam.numpy()) / scale
        if name == "edge":
            att = model.edge_is_att
            if att.any():
                out["att"] = float(np.sqrt(np.mean(r[att] ** 2)))
            if (~att).any():
                out["edge"] = float(np.sqrt(np.mean(r[~att] ** 2)))
        else:
            out[name] = float(np.sqrt(np.mean(r * r)))
        sq += float(np.sum(r * r))
        count += len(r)
    out["all"] = float(np.sqrt(sq / max(count, 1)))
    return out


def kinetic_energy(model: Model, state: State, mass: np.ndarray) -> float:
    """Kinetic energy of the movable vertices (J); ``mass`` is the asset's (N,) vertex masses (kg)."""
    v = state.v.numpy().astype(np.float64)
    w = model.inv_mass.numpy() > 0
    return float(0.5 * np.sum(mass[w] * np.einsum("ij,ij->i", v[w], v[w])))
