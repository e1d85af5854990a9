"""Unit quaternions: Hamilton product, rotation of vectors, conversion to and from matrices.

Scalar first, ``q = (w, x, y, z)``, Hamilton convention; an attitude ``q`` maps sensor axes to
world axes, ``v_world = q v_sensor q*`` (the convention of the BROAD recordings and of the
attitude columns magbench reads). Arrays are ``(..., 4)``; every function broadcasts.
"""

from __future__ import annotations

import numpy as np

__all__ = ["matrix_to_quat", "quat_about_axis", "quat_conjugate", "quat_multiply",
           "quat_rotate", "quat_to_matrix"]


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p q`` of ``(..., 4)`` quaternions (scalar first)."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """``q* = (w, -x, -y, -z)``: the inverse rotation of a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions: ``R v = q v q*``."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``q v q*`` for ``(..., 4)`` unit quaternions and ``(..., 3)`` vectors."""
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    qv = q[..., 1:]
    # v + 2 w (u x v) + 2 u x (u x v), the product written out (no 3x3 per sample).
    t = 2.0 * np.cross(qv, v)
    return v + q[..., :1] * t + np.cross(qv, t)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (``w >= 0``) of ``(..., 3, 3)`` rotation matrices.

    Shepperd's method: the largest of ``w, x, y, z`` is taken from the diagonal and the others
    from the off-diagonal sums, so no branch divides by a small number.
    """
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.stack([tr, R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]], axis=-1)
    case = np.argmax(d, axis=-1)
    out = np.empty(R.shape[:-2] + (4,))
    a = R[..., 2, 1] - R[..., 1, 2]
    b = R[..., 0, 2] - R[..., 2, 0]
    c = R[..., 1, 0] - R[..., 0, 1]
    sxy = R[..., 0, 1] + R[..., 1, 0]
    sxz = R[..., 0, 2] + R[..., 2, 0]
    syz = R[..., 1, 2] + R[..., 2, 1]
    rows = [
        (1 + tr, a, b, c),
        (a, 1 + 2 * R[..., 0, 0] - tr, sxy, sxz),
        (b, sxy, 1 + 2 * R[..., 1, 1] - tr, syz),
        (c, sxz, syz, 1 + 2 * R[..., 2, 2] - tr),
    ]
    for k, comps in enumerate(rows):
        sel = case == k
        if np.any(sel):
            s = 0.5 / np.sqrt(comps[k][sel])
            out[sel] = np.stack([v[sel] * s for v in comps], axis=-1)
    out *= np.where(out[..., :1] < 0, -1.0, 1.0)
    return out


def quat_about_axis(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """The rotation by ``angle`` (radians, right-handed) about ``axis`` (normalised here)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle, dtype=float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)
