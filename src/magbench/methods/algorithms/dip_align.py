"""Dip-angle alignment: MAG.I.C.AL.'s magnetometer fit, then the rotation to the accelerometer
from the invariance of the angle between gravity and the field (Liu, Li, Zhang and Feng,
"Novel Calibration Algorithm for a Three-Axis Strapdown Magnetometer", Sensors, 2014;
Papafotis and Sotiriadis, "Accelerometer and Magnetometer Joint Calibration and Axes
Alignment", Technologies 8(1):11, 2020).

Sources. Neither paper's numbered equations could be read (only their opening pages and
abstracts are in the reference corpus), so no equation numbers are cited. Liu et al.'s
abstract confirms the principle: an ellipsoid fit fixes the calibration matrix up to an
unknown rotation ``R``, which the "constant intersection angle" between the geomagnetic and
gravitational fields estimates, with a Tikhonov-regularised solve where the system is ill
conditioned. Papafotis and Sotiriadis's abstract confirms a joint calibration and axes
alignment of an accelerometer and a magnetometer on one rigid platform, without equipment.

Here: the magnetometer is calibrated first (review Algorithm 7, eqs. 58-65), which fixes ``T``
up to a rotation; its symmetric gauge gives unit field directions ``m_k``. At the rows where
the accelerometer sees gravity only (:func:`~._alignment_common.static_rows`), the dip
constraint ``a_k^T R m_k = c`` is solved linearly for ``X = R / s`` (a null vector of the
centred products ``a_k m_k^T``) and ``R`` is the nearest rotation
(:func:`~._alignment_common.dip_rotation`).

Named differences from Liu et al. (as far as the abstract shows their method):

* Magnetometer fit: MAG.I.C.AL.'s Algorithm 7, not Liu et al.'s ellipsoid fit; both fix ``T``
  up to a rotation, and they agree on noise-free data.
* The linear solve: the null vector of the centred products by SVD (``c`` eliminated by the
  centring, no regularisation) and then the nearest proper rotation, not a Tikhonov-
  regularised least squares; the refusal of rests that turn about too few axes
  (:func:`~._alignment_common.check_spread`) replaces the regularisation.
* The accelerometer is taken as calibrated (``magical_aligned`` calibrates it first).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._alignment_common import (
    dip_rotation,
    magical_at_rest,
    unit_rows,
)
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
    fit0 = magical_at_rest(samples, acceleration, static_tol, min_spread, max_iter, tol, rtol)
    R, c = dip_rotation(fit0.m, unit_rows(fit0.a))
    dip = np.degrees(np.arcsin(np.clip(-c, -1.0, 1.0)))
    return Calibration(fit0.T, fit0.h, fit0.n_iter, fit0.converged,
                       f"MAG.I.C.AL. fit in {fit0.n_iter} iterations; alignment from "
                       f"{fit0.rows.size} "
                       f"static rows, inclination {dip:.2f} deg", alignment=R)
