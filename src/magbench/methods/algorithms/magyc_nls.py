"""MAGYC-NLS (Rodriguez-Martinez and Troni 2025): hard iron, soft iron and gyro bias.

The MAGYC residual with the gyro bias ``d``, ``C dy/dt + (g - d) x (C y - b)``, is bilinear in
``(C, b)`` and ``d``; it is minimised by nonlinear least squares over the unit-volume Cholesky
parametrisation of ``C = L L^T`` (5 parameters, ``det C = 1``), ``b`` and ``d``: 11 unknowns.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._gyro_common import (
    check_gyro_inputs,
    levenberg_marquardt,
    magyc_calibration,
    magyc_linear,
    magyc_residual,
    midpoint_differences,
)
from magbench.methods.registry import register


@register("magyc_nls", label="MAGYC-NLS", min_samples=10, family="extra", needs_gyro=True,
          model="full")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        init: str = "ls", max_iter: int = 200, xtol: float = 1e-12,
        ftol: float = 1e-15) -> Calibration:
    """Calibrate hard iron, soft iron and gyro bias with MAGYC-NLS.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate : ndarray, shape (K, 3)
        Gyro samples in rad/s, in the magnetometer's axes.
    time : ndarray, shape (K,)
        Sample times in seconds, strictly increasing.
    init : {"ls", "zero"}
        Start from the MAGYC-LS closed form with zero gyro bias (default), or from ``C = I``,
        ``b = d = 0`` as navlib does.
    max_iter : int
        Levenberg-Marquardt iteration cap.
    xtol, ftol : float
        Stop when the step is below ``xtol`` relative to the parameters or the cost falls by
        less than ``ftol`` of itself.

    Returns
    -------
    Calibration
        Symmetric ``T`` scaled to unit RMS calibrated norm, ``h``, and ``gyro_bias`` (rad/s).

    Notes
    -----
    Dense Levenberg-Marquardt with the analytic Jacobian (navlib: scipy's dogbox with a jax
    Jacobian). The derivative is the midpoint difference (second order).
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    y_mid, y_dot, w_mid = midpoint_differences(samples, w, t)
    if init == "ls":
        x0 = np.concatenate([magyc_linear(y_mid, y_dot, w_mid), np.zeros(3)])
    elif init == "zero":
        x0 = np.zeros(11)
    else:
        raise ValueError(f"init must be 'ls' or 'zero', got {init!r}")
    x, n_iter, converged, cost = levenberg_marquardt(
        lambda p: magyc_residual(p, y_mid, y_dot, w_mid, True), x0,
        max_iter=max_iter, xtol=xtol, ftol=ftol)
    message = (f"Levenberg-Marquardt: cost {cost:.3g} after {n_iter} iterations" if converged
               else f"iteration cap {max_iter} reached, cost {cost:.3g}")
    return magyc_calibration(x, samples, True, n_iter, converged, message)
