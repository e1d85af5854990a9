"""Dip-angle alignment: MAG.I.C.AL.'s magnetometer fit, then the rotation to the accelerometer
from the invariance of the angle between gravity and the field (Liu et al., Sensors 2014;
Papafotis and Sotiriadis, "Accelerometer and Magnetometer Joint Calibration and Axes
Alignment", Technologies 8(1):11, 2020, section 3).

The magnetometer is calibrated first (review Algorithm 7, eqs. 58-65), which fixes ``T`` up to
a rotation; its symmetric gauge gives unit field directions ``m_k``. At the rows where the
accelerometer sees gravity only (its norm within ``static_tol`` of the median), the dip
constraint ``a_k^T R m_k = c`` is solved linearly for ``X = R / s`` (a null vector of the
centred products ``a_k m_k^T``) and ``R`` is the nearest rotation (``_alignment_common``).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._alignment_common import (
    check_acceleration,
    check_spread,
    dip_rotation,
    static_rows,
    symmetric_directions,
    unit_rows,
)
from magbench.methods.algorithms.magical import iterate
from magbench.methods.registry import register


@register("dip_align", label="Dip alignment", min_samples=10, family="extra",
          needs_accel=True)
def fit(samples: np.ndarray, *, acceleration: np.ndarray, static_tol: float = 0.05,
        min_spread: float = 0.02,
        max_iter: int = 2000, tol: float = 1e-24, rtol: float = 1e-12) -> Calibration:
    """Calibrate the magnetometer and align it to the accelerometer by the dip constraint.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    acceleration : ndarray, shape (K, 3)
        Accelerometer samples (specific force, IMU axes, any unit) at the same instants.
    static_tol : float
        Rows whose specific-force norm is within this fraction of the median enter the
        alignment (where the accelerometer sees gravity alone).
    min_spread : float
        Smallest middle eigenvalue of the covariance of the static gravity directions
        (``_alignment_common.check_spread``); below it the rotation is refused.
    max_iter, tol, rtol
        MAG.I.C.AL.'s stopping rule for the magnetometer fit (see ``magical.fit``).

    Returns
    -------
    Calibration
        ``T`` in the symmetric gauge, ``h``, and ``alignment`` ``R``: the field in the IMU's
        axes is ``R T^-1 (y - h)`` (heading-true gauge).
    """
    a = check_acceleration(samples, acceleration)
    T, h, n_iter, converged, _ = iterate(np.ascontiguousarray(samples, dtype=np.float64),
                                         int(max_iter), float(tol), float(rtol), np.inf)
    T_s, m = symmetric_directions(samples, T, h)
    rows = static_rows(a, static_tol)
    check_spread(unit_rows(a[rows]), min_spread)
    R, c = dip_rotation(m[rows], unit_rows(a[rows]))
    dip = np.degrees(np.arcsin(np.clip(-c, -1.0, 1.0)))
    return Calibration(T_s, h, n_iter, converged,
                       f"MAG.I.C.AL. fit in {n_iter} iterations; alignment from {rows.size} "
                       f"static rows, inclination {dip:.2f} deg", alignment=R)
