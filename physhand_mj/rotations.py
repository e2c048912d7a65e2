"""Rotations of host arrays (numpy): MuJoCo quaternions (w, x, y, z) to matrices, their product and
normalised interpolation. Used by the solver, the contact's object poses, the coupling and the
builders alike, so they sit at the bottom of the package."""

from __future__ import annotations

import math

import numpy as np


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """(..., 4) MuJoCo quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=float)
    q = q / np.sqrt((q * q).sum(axis=-1, keepdims=True))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    m = np.empty(q.shape[:-1] + (3, 3))  # filled in place: the per-frame sleep tests call this
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - z * w)
    m[..., 0, 2] = 2 * (x * z + y * w)
    m[..., 1, 0] = 2 * (x * y + z * w)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - x * w)
    m[..., 2, 0] = 2 * (x * z - y * w)
    m[..., 2, 1] = 2 * (y * z + x * w)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def compose_quat(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Hamilton product q * r for (4,) q and (B, 4) r, w x y z."""
    w1, x1, y1, z1 = q
    w2, x2, y2, z2 = np.moveaxis(np.asarray(r, float), -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


def nlerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    """Normalised linear interpolation of (B, 4) quaternions q0 -> q1 at a in [0, 1], the shorter way."""
    dot = np.sum(q0 * q1, axis=1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    q = (1 - a) * q0 + a * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def pose_turn(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) between two orientations given as poses [p, q x y z w]."""
    d = abs(float(np.dot(a[3:].astype(np.float64), b[3:].astype(np.float64))))
    d /= max(float(np.linalg.norm(a[3:]) * np.linalg.norm(b[3:])), 1e-30)
    return 2.0 * math.acos(min(d, 1.0))
