"""MagFactor3 (GTSAM's ``MagFactor3``, as used by navlib): scale and hard iron from a known
attitude and a known reference field.

With the attitude ``R_k`` (body to world) and the reference field ``m0`` (world axes) known,
each sample is ``y_k = s R_k^T m0 + b + eps``: one factor per sample on the unknown scale ``s``
and bias ``b``. The residual is linear in ``(s, b)``, so the factor graph's minimiser is the
linear least-squares solution, computed here in closed form (no GTSAM needed).

API: ``attitude`` and ``reference_field`` are keyword options of :func:`magbench.calibrate`,
besides ``angular_rate`` and ``time`` (registered as gyro-aided because it needs motion
data; it checks and otherwise ignores the gyro). It does not fit the magnetometer-only
signature: without an attitude it raises ``ValueError``.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._gyro_common import check_gyro_inputs
from magbench.methods.registry import register


def check_attitude(attitude: object, reference_field: object,
                   K: int) -> tuple[np.ndarray, np.ndarray]:
    """``(K, 3, 3)`` rotation matrices and a non-zero ``(3,)`` field, or ``ValueError``."""
    if attitude is None or reference_field is None:
        raise ValueError("magfactor3 needs attitude (K, 3, 3) body-to-world rotation matrices "
                         "and reference_field (3,) in world axes")
    R = np.array(attitude, dtype=float)
    m0 = np.array(reference_field, dtype=float).reshape(-1)
    if R.shape != (K, 3, 3):
        raise ValueError(f"attitude must have shape ({K}, 3, 3), got {R.shape}")
    if m0.shape != (3,) or not np.all(np.isfinite(m0)) or not np.linalg.norm(m0) > 0:
        raise ValueError("reference_field must be a finite, non-zero vector of shape (3,)")
    if not np.all(np.isfinite(R)):
        raise ValueError("attitude contains NaN or infinite values")
    orth = np.abs(np.einsum("kji,kjl->kil", R, R) - np.eye(3)).max()
    if orth > 1e-6:
        raise ValueError(f"attitude matrices must be rotations (max |R^T R - I| = {orth:.3g})")
    return R, m0 / np.linalg.norm(m0)


@register("magfactor3", label="MagFactor3", min_samples=5, family="extra", needs_gyro=True,
          model="sphere")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        attitude: np.ndarray | None = None,
        reference_field: np.ndarray | None = None) -> Calibration:
    """Calibrate scale and hard iron with MagFactor3 (known attitude and field).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate, time : ndarray
        Gyro samples and times (checked, unused).
    attitude : ndarray, shape (K, 3, 3)
        Body-to-world rotation of every sample.
    reference_field : ndarray, shape (3,)
        The field in world axes; only its direction is used (the scale is estimated).

    Returns
    -------
    Calibration
        ``T = s I`` and ``h = b``; closed form.

    Notes
    -----
    navlib builds this graph in GTSAM (scale node, bias node, one factor per sample) after
    replacing the heading with the magnetometer's own; here the full attitude is taken as
    given, which is the factor's definition.
    """
    check_gyro_inputs(samples, angular_rate, time)
    R, m0 = check_attitude(attitude, reference_field, samples.shape[0])
    u = np.einsum("kji,j->ki", R, m0)                 # R_k^T m0
    # Normal equations of y_k = s u_k + b, 4 unknowns.
    K = samples.shape[0]
    A = np.array([[np.sum(u * u), *u.sum(axis=0)],
                  *[[u[:, i].sum(), *(K * np.eye(3)[i])] for i in range(3)]])
    rhs = np.array([np.sum(u * samples), *samples.sum(axis=0)])
    ev = np.linalg.eigvalsh(A)
    if ev[0] <= 1e-12 * ev[-1]:
        raise CalibrationFailed("MagFactor3: the field direction in body axes does not change; "
                                "scale and bias cannot be separated")
    s, *b = np.linalg.solve(A, rhs)
    return Calibration(s * np.eye(3), np.array(b), 0, True, "closed-form MagFactor3")
