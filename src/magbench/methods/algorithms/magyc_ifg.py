"""MAGYC-IFG (Rodriguez-Martinez and Troni 2025): incremental factor graph for hard iron, soft
iron and gyro bias.

The graph of MAGYC-BFG grown one window factor at a time, as an online estimator would see it:
after each new factor the single state node is re-optimised, warm-started from the previous
estimate (what iSAM2 does for a one-node graph, where every new factor touches the only
variable). The answer is the estimate after the last factor, or the mean of the last few.

Solved with the dense Levenberg-Marquardt of ``_gyro_common`` (no GTSAM/iSAM2 needed: the
graph has a single node, so its incremental update is a small dense re-solve).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._gyro_common import (
    check_gyro_inputs,
    levenberg_marquardt,
    magyc_calibration,
    magyc_residual,
    midpoint_differences,
    window_medians,
)
from magbench.methods.registry import register


@register("magyc_ifg", label="MAGYC-IFG", min_samples=10, family="extra", needs_gyro=True,
          model="full")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        window: int = 25, steps_per_update: int = 10, average_last: int = 1,
        xtol: float = 1e-12, ftol: float = 1e-15) -> Calibration:
    """Calibrate hard iron, soft iron and gyro bias with MAGYC-IFG.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate : ndarray, shape (K, 3)
        Gyro samples in rad/s, in the magnetometer's axes.
    time : ndarray, shape (K,)
        Sample times in seconds, strictly increasing.
    window : int
        Sample intervals per factor (navlib: 25).
    steps_per_update : int
        Levenberg-Marquardt iterations allowed after each new factor (the online budget).
    average_last : int
        Return the mean of the estimates after the last ``average_last`` factors (navlib
        averages a tail of its iSAM2 estimates); 1 returns the final one.
    xtol, ftol : float
        Tolerances of each update.

    Returns
    -------
    Calibration
        ``converged`` is whether the final update met its tolerance within
        ``steps_per_update``; ``n_iter`` counts every iteration of every update.
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    window, average_last = int(window), int(average_last)
    if window < 1 or average_last < 1 or steps_per_update < 1:
        raise ValueError("window, steps_per_update and average_last must be positive integers")
    y_mid, y_dot, w_mid = midpoint_differences(samples, w, t)
    ym, ydm, wm = window_medians((y_mid, y_dot, w_mid), window)
    n = ym.shape[0]
    if n < 4:
        raise ValueError(f"window={window} leaves {n} factors; at least 4 are needed for 11 "
                         "unknowns")
    x = np.zeros(11)
    history, total = [], 0
    converged = False
    # The first update waits for 4 factors (12 equations for 11 unknowns).
    for j in range(4, n + 1):
        x, it, converged, cost = levenberg_marquardt(
            lambda p, j=j: magyc_residual(p, ym[:j], ydm[:j], wm[:j], True), x,
            max_iter=steps_per_update, xtol=xtol, ftol=ftol)
        total += it
        history.append(x)
    x = np.mean(history[-average_last:], axis=0)
    message = (f"incremental factor graph, {n} factors, {total} iterations, last cost "
               f"{cost:.3g}" + ("" if converged else "; last update hit steps_per_update"))
    return magyc_calibration(x, samples, True, total, converged, message)
