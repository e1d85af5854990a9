"""Rotations: cross-product matrices, the exponential map, Euler angles, running products.

Shared by the gyro-aided methods (which integrate angular rate), the trajectory simulator and
the direction metrics (:mod:`magbench.core.direction`); quaternions are in
:mod:`magbench.core.quaternions`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cumulative_product", "euler_zyx_to_matrix", "rotation_exp", "skew", "span_deg"]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[v]x`` (``[v]x u = v x u``) of ``(..., 3)`` vectors."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: ``exp([phi]x)`` for ``(..., 3)`` rotation vectors, exact."""
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    theta = np.sqrt(theta2)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    # Taylor series below 1e-4 rad keeps full precision where the closed form cancels.
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2**2 / 120.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0 + theta2**2 / 720.0,
                 (1.0 - np.cos(safe)) / safe**2)
    K = skew(phi)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def euler_zyx_to_matrix(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Body-to-world ``Rz(psi) Ry(theta) Rx(phi)`` (roll phi, pitch theta, yaw psi; radians)."""
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    cp, sp = np.cos(psi), np.sin(psi)
    R = np.empty(np.shape(phi) + (3, 3))
    R[..., 0, 0], R[..., 0, 1] = cp * ct, cp * st * sf - sp * cf
    R[..., 0, 2] = cp * st * cf + sp * sf
    R[..., 1, 0], R[..., 1, 1] = sp * ct, sp * st * sf + cp * cf
    R[..., 1, 2] = sp * st * cf - cp * sf
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = -st, ct * sf, ct * cf
    return R


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
