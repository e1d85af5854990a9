"""SAR-KF (Troni and Whitcomb 2019, section IV.B): hard iron by a Kalman filter, no derivative.

State ``z = [x; b]`` (field as measured, and bias) with ``dx/dt = -w x (x - b)``,
``db/dt = 0``. Over a sample interval with the (midpoint) rate ``w`` held constant the exact
transition is ``x+ = R x + (I - R) b`` with ``R = exp(-[w]x dt)``; the measurement is ``x``
itself. The filter is sequential by nature (a loop over samples).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.core.rotations import rotation_exp
from magbench.methods.algorithms._gyro_common import check_gyro_inputs
from magbench.methods.algorithms.sar_ls import scale_of
from magbench.methods.registry import register


def noise_from_second_differences(y: np.ndarray) -> float:
    """Magnetometer noise std from second differences (variance ``6 sigma^2`` for white noise;
    the signal's own curvature makes this an over-estimate at low sample rates)."""
    d2 = np.diff(y, n=2, axis=0)
    return float(np.sqrt(np.mean(d2**2) / 6.0))


@register("sar_kf", label="SAR-KF", min_samples=5, family="extra", needs_gyro=True,
          model="sphere")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        mag_noise: float | None = None, rate_noise: float = 1e-3,
        initial_bias_std: float | None = None, estimate_scale: bool = True) -> Calibration:
    """Calibrate the hard iron with SAR-KF.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples; :func:`magbench.calibrate` passes them divided by the power of
        two nearest their RMS norm (a field magnitude near 1), as for every method.
    angular_rate : ndarray, shape (K, 3)
        Gyro samples in rad/s, in the magnetometer's axes; assumed unbiased.
    time : ndarray, shape (K,)
        Sample times in seconds, strictly increasing.
    mag_noise : float, optional
        Measurement noise std in the unit the method sees (field magnitude near 1, see
        ``samples``); estimated from second differences when None
        (floored at ``1e-9`` times the RMS sample norm so noise-free data do not make the
        filter singular).
    rate_noise : float
        Gyro noise std (rad/s) driving the process noise of ``x``:
        ``Q_x = (rate_noise dt ||x - b||)^2 I`` per step.
    initial_bias_std : float, optional
        Prior std of each bias component, in the same unit; the RMS sample norm when None.
        The prior mean is zero.
    estimate_scale : bool
        ``T = r I`` with ``r`` the RMS of ``||y - b||`` (default; scale in, scale out), or
        the paper's ``T = I`` when False (see :func:`magbench.methods.algorithms.sar_ls.fit`).

    Returns
    -------
    Calibration
        ``h`` the filter's final bias estimate; ``n_iter`` the number of filter steps.

    Notes
    -----
    The transition is discretised exactly for a piecewise-constant rate, using the average
    of the two gyro samples bounding each interval. navlib returns the mean of the last 20 %
    of the estimates; the final (filtered) estimate is returned here.
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    y = samples
    sigma = noise_from_second_differences(y) if mag_noise is None else float(mag_noise)
    size = float(np.sqrt(np.mean(np.sum(y**2, axis=1))))
    r2 = max(sigma, 1e-9 * size) ** 2
    p_b = size if initial_bias_std is None else float(initial_bias_std)
    dt = np.diff(t)
    Rs = rotation_exp(-0.5 * (w[1:] + w[:-1]) * dt[:, None])
    z = np.concatenate([y[0], np.zeros(3)])
    P = np.diag([r2] * 3 + [p_b**2] * 3)
    I3 = np.eye(3)
    F = np.block([[I3, np.zeros((3, 3))], [np.zeros((3, 3)), I3]])    # [[R, I - R], [0, I]]
    for k in range(len(dt)):
        F[:3, :3], F[:3, 3:] = Rs[k], I3 - Rs[k]
        v = z[:3] - z[3:]
        z = F @ z
        P = F @ P @ F.T
        P[:3, :3] += (rate_noise * dt[k]) ** 2 * float(v @ v) * I3
        # Update with H = [I 0]: the gain only needs the first three columns of P.
        S = P[:3, :3] + r2 * I3
        G = np.linalg.solve(S, P[:3, :]).T
        z = z + G @ (y[k + 1] - z[:3])
        P = P - G @ P[:3, :]
        P = 0.5 * (P + P.T)
    b = z[3:]
    r = scale_of(y, b) if estimate_scale else 1.0
    return Calibration(r * np.eye(3), b, len(dt), True,
                       f"Kalman filter over {len(dt)} steps, bias std "
                       f"{np.sqrt(np.max(np.diag(P)[3:])):.3g}")
