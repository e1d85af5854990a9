"""MAGYC-LS (Rodriguez-Martinez and Troni 2025): hard and soft iron from angular rates, in
closed form.

With ``C`` proportional to ``T^-1`` (symmetric) and ``b = C h``, the body-frame field
``m ~ C (y - h)`` obeys ``dm/dt = -w x m``, so every sample gives the residual
``C dy/dt + w x (C y - b)``, linear in ``(C, b)`` and blind to the scale of ``C``. MAGYC-LS fixes
that scale with a unit-norm constraint on the soft-iron parameters and solves the constrained
least squares in closed form (an eigenvector). The gyro is taken as unbiased; MAGYC-NLS adds
its bias.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._gyro_common import (
    check_gyro_inputs,
    magyc_calibration,
    magyc_linear,
    midpoint_differences,
)
from magbench.methods.registry import register


@register("magyc_ls", label="MAGYC-LS", min_samples=10, family="extra", needs_gyro=True,
          model="full")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray) -> Calibration:
    """Calibrate hard and soft iron with MAGYC-LS.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate : ndarray, shape (K, 3)
        Gyro samples in rad/s, in the magnetometer's axes; assumed unbiased.
    time : ndarray, shape (K,)
        Sample times in seconds, strictly increasing.

    Returns
    -------
    Calibration
        Symmetric ``T`` (soft iron in the gyro's axes) scaled so the calibrated field has unit
        RMS norm (the residual cannot see the scale), and ``h``. ``gyro_bias`` is None.

    Notes
    -----
    navlib solves this problem iteratively (the Cholesky parametrisation of MAGYC-NLS without
    gyro bias, from a zero start); the paper's closed form is used here: for noise-free data
    both reach the same minimiser, zero residual. The derivative is the midpoint difference
    (second order) rather than navlib's one-sided one. ``T`` is symmetric: a magnetometer
    misaligned with the gyro (non-symmetric ``T``) is outside the model.
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    y_mid, y_dot, w_mid = midpoint_differences(samples, w, t)
    x = magyc_linear(y_mid, y_dot, w_mid)
    return magyc_calibration(x, samples, False, 0, True, "closed-form MAGYC least squares")
