"""Rotations: cross-product matrices, the exponential map, Euler angles, running products.

Shared by the gyro-aided methods (which integrate angular rate), the trajectory simulator and
the direction metrics (:mod:`magbench.core.direction`); quaternions are in
:mod:`magbench.core.quaternions`. The exponential map and Euler angles are
:class:`scipy.spatial.transform.Rotation`'s; the running product and the cross-product matrix
are plain NumPy (scipy has neither as an array operation).
"""

from __future__ import annotations

import numpy as np

__all__ = ["cross_rows", "cumulative_product", "euler_zyx_to_matrix", "rotation_class",
           "rotation_exp", "skew", "span_deg"]


def rotation_class() -> type:
    """:class:`scipy.spatial.transform.Rotation`, imported on first use.

    Importing ``scipy.spatial`` costs about 0.09 CPU seconds, which ``calibrate`` on a file
    without attitude or gyro columns never needs, so no module imports it at load time.
    """
    from scipy.spatial.transform import Rotation
    return Rotation


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` (``[v]x u = v x u``) of ``(..., 3)`` vectors."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` of two ``(n, 3)`` arrays, row by row: :func:`numpy.cross`'s numbers (the same
    products and differences) without its axis handling, which costs more than the arithmetic
    on the short arrays of an iterative fit."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a1 * b2 - a2 * b1
    out[:, 1] = a2 * b0 - a0 * b2
    out[:, 2] = a0 * b1 - a1 * b0
    return out


def rotation_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: ``exp([phi]x)`` for ``(..., 3)`` rotation vectors, exact
    (:meth:`scipy.spatial.transform.Rotation.from_rotvec`, a Taylor series near zero)."""
    phi = np.asarray(phi, dtype=float)
    flat = phi.reshape(-1, 3)
    return rotation_class().from_rotvec(flat).as_matrix().reshape(phi.shape[:-1] + (3, 3))


def euler_zyx_to_matrix(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Body-to-world ``Rz(psi) Ry(theta) Rx(phi)`` (roll phi, pitch theta, yaw psi; radians).

    scipy's intrinsic ``"ZYX"`` sequence, whose angles are given yaw first."""
    psi, theta, phi = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (psi, theta, phi)))
    angles = np.stack([psi, theta, phi], axis=-1).reshape(-1, 3)
    return rotation_class().from_euler("ZYX", angles).as_matrix().reshape(np.shape(phi) + (3, 3))


def cumulative_product(steps: np.ndarray) -> np.ndarray:
    """``P_n = S_0 S_1 ... S_n`` for ``(N, 3, 3)`` steps, by a vectorised doubling scan."""
    P = np.array(steps, dtype=float)
    shift = 1
    while shift < len(P):
        P[shift:] = P[:-shift] @ P[shift:]
        shift *= 2
    return P


def span_deg(R: np.ndarray) -> float:
    """Largest rotation angle (deg) between ``R[0]`` and any ``R[k]`` of ``(K, 3, 3)``
    rotations: how far a recording's attitude turned."""
    cos = (np.einsum("ji,kji->k", R[0], R) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)).max()))
