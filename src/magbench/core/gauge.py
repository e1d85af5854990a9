"""The one gauge every written calibration is in: ``m = A (y - b)``, A symmetric positive definite.

The model ``y = T m + h`` with ``||m|| = 1`` (review eq. 2) fixes ``T`` only up to an orthogonal
factor on the right: ``T Q`` with ``Q^T Q = I`` explains the samples exactly as well, because
``||Q^T m|| = ||m||``. A method's ``T`` therefore carries an arbitrary rotation, and may even be a
mirror image (``det T < 0``); the benchmark's J removes it by Procrustes, but a correction
written for firmware keeps it, and a compass then reads offset or mirrored headings.

The gauge fixes it. With the singular value decomposition ``T = U S V^T``,

    A = (T T^T)^(-1/2) = U S^-1 U^T,    b = h,

so ``A`` is symmetric positive definite (``det A > 0`` always) and depends on ``T`` only through
``T T^T``: ``A(T Q) = A(T)`` for every orthogonal ``Q``. Since ``T^-1 = V S^-1 U^T = R A`` with the
orthogonal ``R = V U^T``, the corrected field ``A (y - b) = R^T T^-1 (y - h)`` has exactly the
norms of the method's own ``T^-1 (y - h)`` (eq. 82): only ``R`` (the rotation, and the mirror
image when ``det R = -1``) is removed. ``A^-1 = U S U^T`` is the symmetric ``T`` of the same
gauge (the right polar factor of ``T`` taken off).

*Heading-true gauge.* When inertial data fix the rotation between the magnetometer and the
inertial sensors (an alignment ``R``, det +1, from the symmetric gauge to the IMU axes), the
written correction is ``A_aligned = R A`` instead: ``m = R A (y - b)`` is the field in the IMU's
axes, so a compass built on the IMU's attitude reads true headings. Its norms are those of the
symmetric gauge; ``A_aligned`` is not symmetric, and the gauge's label says which is written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["GAUGE_TEXT", "HEADING_TRUE", "SYMMETRIC", "Gauge", "check_rotation",
           "removed_rotation", "rotation_angle_deg", "safe_gauge", "symmetric_T"]

#: Condition number of T above which it is treated as singular (matches Calibration.is_finite).
MAX_CONDITION = 1e12
#: The two gauges a written correction can be in.
SYMMETRIC = "symmetric"
HEADING_TRUE = "heading-true"
#: What each gauge means, in the words written beside the correction.
GAUGE_TEXT = {
    SYMMETRIC: "m = A (y - b), A symmetric positive definite",
    HEADING_TRUE: "m = A (y - b), A = R S with S symmetric positive definite and R the rotation "
                  "to the IMU's axes (heading-true)",
}


@dataclass(frozen=True)
class Gauge:
    """A calibration in the safe gauge and what was taken out of it.

    Attributes
    ----------
    A : ndarray, shape (3, 3)
        Symmetric positive definite correction matrix, ``A = (T T^T)^(-1/2)``.
    b : ndarray, shape (3,)
        Offset in the recording's units, ``b = h``; the correction is ``m = A (y - b)``.
    rotation_deg : float
        Angle of the rotation removed from ``T^-1``, in degrees (for a mirror image, the angle
        of the rotation part of the rotoinversion ``R = -R_p``).
    mirrored : bool
        True when ``det T < 0``: the method's own correction was a mirror image.
    label : str
        ``"symmetric"``, or ``"heading-true"`` when ``A`` is ``R`` times the symmetric one.
    """

    A: np.ndarray
    b: np.ndarray
    rotation_deg: float
    mirrored: bool
    label: str = SYMMETRIC


def check_rotation(R: object, name: str = "R", tol: float = 1e-6) -> np.ndarray:
    """``R`` as a float ``(3, 3)`` proper rotation (``R^T R = I``, det +1), or ``ValueError``."""
    R = np.array(R, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"{name} must be a finite 3x3 rotation matrix, got shape {R.shape}")
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > tol or np.linalg.det(R) <= 0:
        raise ValueError(f"{name} must be a proper rotation (R^T R = I, det R = +1); max |R^T R "
                         f"- I| = {err:.3g}, det R = {np.linalg.det(R):.6g}")
    return R


def _checked_svd(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    T = np.asarray(T, dtype=float)
    if T.shape != (3, 3):
        raise ValueError(f"T must have shape (3, 3), got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError("T is not finite; no correction can be written")
    U, s, Vt = np.linalg.svd(T)
    # A singular T has no correction; refusing here keeps it from ever being written.
    if not s[-1] > 0 or s[0] / s[-1] > MAX_CONDITION:
        raise ValueError(f"T is singular (singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g}); "
                         "no correction can be written")
    return U, s, Vt


def _symmetrised(M: np.ndarray) -> np.ndarray:
    # U diag U^T is symmetric in exact arithmetic; make it so bit for bit for the file formats.
    return 0.5 * (M + M.T)


def symmetric_T(T: np.ndarray) -> np.ndarray:
    """``A^-1 = (T T^T)^(1/2) = U S U^T``: the symmetric positive definite T of the gauge.

    Raises
    ------
    ValueError
        If ``T`` is not finite or is singular.
    """
    U, s, _ = _checked_svd(T)
    return _symmetrised((U * s) @ U.T)


def removed_rotation(T: np.ndarray) -> np.ndarray:
    """The orthogonal ``R = V U^T`` with ``T^-1 = R A``: what the gauge removes (det +-1)."""
    U, _, Vt = _checked_svd(T)
    return Vt.T @ U.T


def rotation_angle_deg(R: np.ndarray) -> float:
    """Rotation angle of an orthogonal 3x3 matrix in degrees, in [0, 180].

    For an improper ``R`` (det -1) it is the angle of the proper rotation ``-R``.
    """
    R = np.asarray(R, dtype=float)
    proper = R if np.linalg.det(R) > 0 else -R
    cos = (np.trace(proper) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def safe_gauge(T: np.ndarray, h: np.ndarray, alignment: np.ndarray | None = None) -> Gauge:
    """The correction ``m = A (y - b)`` with ``A = (T T^T)^(-1/2)`` and ``b = h``.

    Parameters
    ----------
    T : array_like, shape (3, 3)
        The model matrix of ``y = T m + h`` (review eq. 2), in any gauge.
    h : array_like, shape (3,)
        The offset.
    alignment : array_like of shape (3, 3), optional
        The rotation ``R`` from the symmetric gauge to the inertial sensors' axes; with it the
        correction is heading-true, ``A = R (T T^T)^(-1/2)``.

    Returns
    -------
    Gauge
        ``A`` symmetric positive definite (or ``R`` times it), ``b = h``, the angle of the
        rotation removed from the method's own ``T^-1``, whether ``T`` was a mirror image, and
        the gauge's label.

    Raises
    ------
    ValueError
        If ``T`` is not finite or is singular, or ``h`` is not a finite 3-vector.
    """
    h = np.asarray(h, dtype=float).reshape(-1)
    if h.shape != (3,) or not np.all(np.isfinite(h)):
        raise ValueError(f"h must be a finite vector of 3 values, got {h}")
    U, s, Vt = _checked_svd(T)
    A = _symmetrised((U / s) @ U.T)
    R = Vt.T @ U.T
    mirrored = bool(np.linalg.det(np.asarray(T, dtype=float)) < 0)
    if alignment is not None:
        return Gauge(A=check_rotation(alignment, "alignment") @ A, b=h.copy(),
                     rotation_deg=rotation_angle_deg(R), mirrored=mirrored, label=HEADING_TRUE)
    return Gauge(A=A, b=h.copy(), rotation_deg=rotation_angle_deg(R), mirrored=mirrored)
