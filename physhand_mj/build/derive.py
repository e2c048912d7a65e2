"""Data the XPBD solver needs, derived once from the tet mesh (paper section 3.2).

All functions take numpy arrays in metres and return numpy arrays; none depends on MuJoCo.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def tet_signed_volumes(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes ``(x2-x1) x (x3-x1) . (x4-x1) / 6`` of ``tets`` (Eq. 3 with C = 0)."""
    a, b, c, d = (x[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def orient_tets(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Swap two vertices of negatively oriented tets so every rest volume is positive."""
    tets = tets.copy()
    neg = tet_signed_volumes(x, tets) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3].copy(), tets[neg, 2].copy()
    return tets


def tet_edges(tets: np.ndarray) -> np.ndarray:
    """Unique undirected edges ``(E, 2)`` of a tet mesh, sorted, lower index first."""
    pairs = tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]].reshape(-1, 2)
    return np.unique(np.sort(pairs, axis=1), axis=0)


def lumped_masses(x: np.ndarray, tets: np.ndarray, density: float) -> np.ndarray:
    """Per-vertex mass (kg): each tet's mass ``density * V`` split equally over its 4 vertices."""
    m = np.zeros(len(x))
    np.add.at(m, tets.reshape(-1), np.repeat(density * tet_signed_volumes(x, tets) / 4.0, 4))
    return m


def nearest_skeleton_pairs(x: np.ndarray, movable: np.ndarray, skeleton: np.ndarray) -> np.ndarray:
    """Flesh attachment pairs (Eq. 4-5): each movable vertex with its nearest skeleton vertex."""
    _, j = cKDTree(x[skeleton]).query(x[movable])
    return np.stack([movable, skeleton[j]], axis=1).astype(np.int32)


def dihedral_pairs(x: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle pairs sharing an edge and their rest dihedral angles (Eq. 6).

    Returns ``(quads, angles)``: ``quads[k] = (e0, e1, o0, o1)`` with shared edge ``(e0, e1)`` and the
    opposite vertices ``o0`` (of the triangle whose directed edge is e0->e1) and ``o1``; the angle is
    ``arccos(n0 . n1)`` with ``n0 = (x_e1 - x_e0) x (x_o0 - x_e0)`` and
    ``n1 = (x_e0 - x_e1) x (x_o1 - x_e1)`` normalised (both outward normals for a consistently
    oriented surface), so a flat pair has angle 0.
    """
    f = np.asarray(faces)
    directed = np.concatenate([f[:, [0, 1, 2]], f[:, [1, 2, 0]], f[:, [2, 0, 1]]])  # (a, b, opposite)
    key = {(a, b): o for a, b, o in directed.tolist()}
    quads = []
    for (a, b), o0 in key.items():
        if a < b and (b, a) in key:
            quads.append((a, b, o0, key[(b, a)]))
    quads = np.asarray(quads, dtype=np.int32).reshape(-1, 4)
    return quads, dihedral_angles(x, quads)


def dihedral_angles(x: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """``arccos(n0 . n1)`` for each quad as defined in :func:`dihedral_pairs` (radians)."""
    e0, e1, o0, o1 = (x[quads[:, i]] for i in range(4))
    n0 = np.cross(e1 - e0, o0 - e0)
    n1 = np.cross(e0 - e1, o1 - e1)
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    return np.arccos(np.clip(np.einsum("ij,ij->i", n0, n1), -1.0, 1.0))


def tet_min_dihedral_deg(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Smallest interior dihedral angle of each tet, degrees (a quality figure)."""
    v = [x[tets[:, i]] for i in range(4)]
    faces = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)]  # face i opposite vertex i
    normals = []
    for a, b, c in faces:
        n = np.cross(v[b] - v[a], v[c] - v[a])
        normals.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    out = np.full(len(tets), np.inf)
    for i in range(4):
        for j in range(i + 1, 4):
            ang = np.pi - np.arccos(np.clip(np.einsum("ij,ij->i", normals[i], normals[j]), -1, 1))
            out = np.minimum(out, ang)
    return np.degrees(out)
