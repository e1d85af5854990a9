"""MAG.I.C.AL. with its alignment step (Papafotis and Sotiriadis, "MAG.I.C.AL.-A Unified
Methodology for Magnetic and Inertial Sensors Calibration and Alignment", IEEE Sensors J.
19(18), 2019): the review's MAG.I.C.AL. (Algorithm 7, eqs. 58-65) is its magnetometer part.

Sources. The review (Papafotis, Nikitas and Sotiriadis) gives the magnetometer algorithm,
eqs. (58)-(65); of the 2019 paper only the opening page and abstract could be read, so the
alignment step is cited by no equation number. The abstract confirms: the same
least-squares-based iterative algorithm calibrates the magnetometer and the accelerometer,
the methodology then aligns their axes and calibrates the gyroscope from their joint data,
in a 15-step sequence.

Here: both sensors by Algorithm 7 (the accelerometer on its static rows, in its symmetric
gauge, since the accelerometer's axes are the IMU's), the linear dip solution as the start
(``_alignment_common.dip_rotation``) and Gauss-Newton over the rotation itself on ``sum_k
(a_k^T R m_k - c)^2`` (``refine_dip_rotation``).

Named differences (what the abstract leaves open is not claimed to match):

* The alignment's cost and solver: the dip constraint with ``R`` kept a rotation, solved by
  Gauss-Newton on SO(3) from the linear start; the paper's own alignment equations could
  not be checked.
* The gyroscope step of the methodology is not implemented (the benchmark scores the
  magnetometer and its alignment).
* Static rows are selected by the specific-force norm and steadiness
  (``_alignment_common.static_rows``), not by the paper's protocol of held poses.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._alignment_common import (
    dip_rotation,
    magical_at_rest,
    refine_dip_rotation,
    symmetric_directions,
    unit_rows,
)
from magbench.methods.algorithms.magical import iterate
from magbench.methods.registry import register


def gravity_directions(a: np.ndarray, max_iter: int, tol: float, rtol: float) -> np.ndarray:
    """Unit gravity directions of static accelerometer rows calibrated by Algorithm 7
    (symmetric gauge), or ``CalibrationFailed`` when too few or too alike to fit."""
    scale = float(np.median(np.sqrt(np.einsum("ij,ij->i", a, a))))
    if a.shape[0] < 10:
        raise CalibrationFailed(f"MAG.I.C.AL. alignment: {a.shape[0]} static accelerometer rows "
                                "are too few to calibrate it (10 needed); pass "
                                "calibrate_accelerometer=False to use it as given")
    centred = a / scale - np.mean(a / scale, axis=0)
    if np.linalg.svd(centred, compute_uv=False)[-1] <= 1e-3 * np.sqrt(a.shape[0]):
        raise CalibrationFailed("MAG.I.C.AL. alignment: the static accelerometer rows do not "
                                "span an ellipsoid (too few distinct rests); pass "
                                "calibrate_accelerometer=False to use it as given")
    T, h, *_ = iterate(np.ascontiguousarray(a / scale), int(max_iter), float(tol),
                       float(rtol), np.inf)
    return symmetric_directions(a / scale, T, h)[1]


@register("magical_aligned", label="MAG.I.C.AL. aligned", min_samples=10, family="extra",
          needs_accel=True)
def fit(samples: np.ndarray, *, acceleration: np.ndarray, static_tol: float = 0.05,
        min_spread: float = 0.02,
        calibrate_accelerometer: bool = True, max_iter: int = 2000, tol: float = 1e-24,
        rtol: float = 1e-12) -> Calibration:
    """Calibrate the magnetometer (and accelerometer) and align them, MAG.I.C.AL.'s way.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    acceleration : ndarray, shape (K, 3)
        Accelerometer samples (specific force, IMU axes, any unit) at the same instants.
    static_tol : float
        Rows whose specific-force norm is within this fraction of the median are static.
    min_spread : float
        Smallest middle eigenvalue of the covariance of the static gravity directions
        (``_alignment_common.check_spread``); below it the rotation is refused.
    calibrate_accelerometer : bool
        True (the methodology): calibrate the accelerometer on the static rows first; False:
        take it as calibrated (a recording with few distinct rests cannot fit it).
    max_iter, tol, rtol
        Algorithm 7's stopping rule for both sensors (see ``magical.fit``).

    Returns
    -------
    Calibration
        ``T`` in the symmetric gauge, ``h`` and the alignment ``R`` (heading-true gauge).
    """
    fit0 = magical_at_rest(samples, acceleration, static_tol, min_spread, max_iter, tol, rtol)
    g = (gravity_directions(fit0.a, max_iter, tol, rtol) if calibrate_accelerometer
         else unit_rows(fit0.a))
    R0, _ = dip_rotation(fit0.m, g)
    R, c, steps = refine_dip_rotation(fit0.m, g, R0)
    dip = np.degrees(np.arcsin(np.clip(-c, -1.0, 1.0)))
    return Calibration(fit0.T, fit0.h, fit0.n_iter, fit0.converged,
                       f"MAG.I.C.AL. fit in {fit0.n_iter} iterations; rotation-constrained "
                       f"alignment on {fit0.rows.size} static rows in {steps} steps, inclination "
                       f"{dip:.2f} deg", alignment=R)
