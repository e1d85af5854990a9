"""Rotations: cross-product matrices, the exponential map and Euler angles.

Shared by the gyro-aided methods (which integrate angular rate) and the trajectory simulator.
"""

from __future__ import annotations

import numpy as np

__all__ = ["euler_zyx_to_matrix", "euler_zyx_to_quaternion", "matrix_to_quaternion",
           "quaternion_to_matrix", "rotation_exp", "skew"]


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


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of ``(..., 4)`` Hamilton quaternions, scalar first ``(w, x, y, z)``.

    A unit quaternion ``q`` and its matrix ``R`` rotate a vector the same way,
    ``R v = q v q*``; for an attitude quaternion from body to world ``R`` is body-to-world.
    The quaternion is normalised first (a logged one is only nearly unit).
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), \
        2 * (x * z + w * y)
    R[..., 1, 0], R[..., 1, 1], R[..., 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), \
        2 * (y * z - w * x)
    R[..., 2, 0], R[..., 2, 1], R[..., 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), \
        1 - 2 * (x * x + y * y)
    return R


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """The scalar-first unit quaternions (``w >= 0``) of ``(..., 3, 3)`` rotation matrices,
    the inverse of :func:`quaternion_to_matrix` (from the largest of the four squared
    components, which keeps the division well conditioned)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=-2, axis2=-1)
    squares = np.stack([1 + tr, 1 + 2 * R[..., 0, 0] - tr, 1 + 2 * R[..., 1, 1] - tr,
                        1 + 2 * R[..., 2, 2] - tr], axis=-1) / 4       # w^2, x^2, y^2, z^2
    # 4 w x, 4 w y, 4 w z, 4 x y, 4 x z, 4 y z from the off-diagonal sums and differences.
    wx = R[..., 2, 1] - R[..., 1, 2]
    wy = R[..., 0, 2] - R[..., 2, 0]
    wz = R[..., 1, 0] - R[..., 0, 1]
    xy = R[..., 0, 1] + R[..., 1, 0]
    xz = R[..., 0, 2] + R[..., 2, 0]
    yz = R[..., 1, 2] + R[..., 2, 1]
    products = np.stack([np.stack([4 * squares[..., 0], wx, wy, wz], -1),
                         np.stack([wx, 4 * squares[..., 1], xy, xz], -1),
                         np.stack([wy, xy, 4 * squares[..., 2], yz], -1),
                         np.stack([wz, xz, yz, 4 * squares[..., 3]], -1)], -2)
    pick = np.argmax(squares, axis=-1)
    row = np.take_along_axis(products, pick[..., None, None], axis=-2)[..., 0, :]
    q = row / np.linalg.norm(row, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def euler_zyx_to_quaternion(phi: np.ndarray, theta: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """The scalar-first quaternion of :func:`euler_zyx_to_matrix` (roll phi, pitch theta, yaw
    psi; radians): ``q = q_z(psi) q_y(theta) q_x(phi)``, with ``w >= 0``."""
    cr, sr = np.cos(np.asarray(phi) / 2), np.sin(np.asarray(phi) / 2)
    cp, sp = np.cos(np.asarray(theta) / 2), np.sin(np.asarray(theta) / 2)
    cy, sy = np.cos(np.asarray(psi) / 2), np.sin(np.asarray(psi) / 2)
    q = np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                  cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)
