"""MAGYC-BFG (Rodriguez-Martinez and Troni 2025): batch factor graph for hard iron, soft iron
and gyro bias.

One state node holds ``(L, b, d)`` (unit-volume Cholesky factor of ``C = L L^T``, ``b = C h``,
gyro bias ``d``); every window of ``window`` samples adds one unary factor, the MAGYC residual
``C dy/dt + (g - d) x (C y - b)`` at the window's per-axis medians of ``dy/dt``, ``y`` and ``g``
(isotropic noise model). The batch problem is solved from ``L = I, b = d = 0``.

Backends: ``"scipy"`` (default) solves this graph's nonlinear least squares directly - with a
single state node the graph's normal equations are one dense 11 x 11 system, so the
Levenberg-Marquardt of ``_gyro_common`` is the whole optimiser (the same minimiser GTSAM's
Levenberg-Marquardt or dogleg reaches); ``"gtsam"`` builds the graph with GTSAM
``CustomFactor``s and its Levenberg-Marquardt optimiser, if ``gtsam`` is installed (optional).
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


def solve_with_gtsam(y: np.ndarray, y_dot: np.ndarray, g: np.ndarray, x0: np.ndarray,
                     max_iter: int, tol: float) -> tuple[np.ndarray, int, bool, float]:
    """The same single-node graph with GTSAM CustomFactors (optional dependency)."""
    try:
        import gtsam
    except ImportError:
        raise ValueError("backend='gtsam' needs the optional package gtsam "
                         "(pip install gtsam)") from None
    keys = [gtsam.symbol("s", 0), gtsam.symbol("b", 0), gtsam.symbol("w", 0)]
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)

    def factor(k: int):
        def error(this, values, H):
            x = np.concatenate([values.atVector(keys[0]), values.atVector(keys[1]),
                                values.atVector(keys[2])])
            r, J = magyc_residual(x, y[k:k + 1], y_dot[k:k + 1], g[k:k + 1], True)
            if H is not None:
                H[0], H[1], H[2] = J[:, :5], J[:, 5:8], J[:, 8:11]
            return r
        return error

    graph = gtsam.NonlinearFactorGraph()
    for k in range(y.shape[0]):
        graph.add(gtsam.CustomFactor(noise, keys, factor(k)))
    initial = gtsam.Values()
    initial.insert(keys[0], x0[:5])
    initial.insert(keys[1], x0[5:8])
    initial.insert(keys[2], x0[8:11])
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iter)
    params.setRelativeErrorTol(tol)
    params.setAbsoluteErrorTol(0.0)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = opt.optimize()
    x = np.concatenate([result.atVector(keys[0]), result.atVector(keys[1]),
                        result.atVector(keys[2])])
    n = int(opt.iterations())
    return x, n, n < max_iter, 2.0 * float(graph.error(result))


@register("magyc_bfg", label="MAGYC-BFG", min_samples=10, family="extra", needs_gyro=True,
          model="full")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        window: int = 25, backend: str = "scipy", max_iter: int = 200, xtol: float = 1e-12,
        ftol: float = 1e-15) -> Calibration:
    """Calibrate hard iron, soft iron and gyro bias with MAGYC-BFG.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate : ndarray, shape (K, 3)
        Gyro samples in rad/s, in the magnetometer's axes.
    time : ndarray, shape (K,)
        Sample times in seconds, strictly increasing.
    window : int
        Sample intervals per factor (navlib: 25). At least 4 windows are needed (11
        unknowns, 3 equations each); ``window=1`` makes every interval a factor.
    backend : {"scipy", "gtsam"}
        Solver of the factor graph (see the module docstring).
    max_iter : int
        Optimiser iteration cap.
    xtol, ftol : float
        Step and relative cost-decrease tolerances (``ftol`` is GTSAM's relative error
        tolerance with ``backend="gtsam"``).

    Returns
    -------
    Calibration
        Symmetric ``T`` scaled to unit RMS calibrated norm, ``h`` and ``gyro_bias`` (rad/s).

    Notes
    -----
    Medians over a window commute with the residual only if the motion is steady within it:
    on noise-free data the windowing itself leaves an error that grows with the window's
    span of rotation. That is the price of the method's fixed-size graph.
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    window = int(window)
    if window < 1:
        raise ValueError(f"window must be a positive integer, got {window}")
    y_mid, y_dot, w_mid = midpoint_differences(samples, w, t)
    ym, ydm, wm = window_medians((y_mid, y_dot, w_mid), window)
    if ym.shape[0] < 4:
        raise ValueError(f"window={window} leaves {ym.shape[0]} factors; at least 4 are "
                         "needed for 11 unknowns")
    x0 = np.zeros(11)
    if backend == "scipy":
        x, n_iter, converged, cost = levenberg_marquardt(
            lambda p: magyc_residual(p, ym, ydm, wm, True), x0,
            max_iter=max_iter, xtol=xtol, ftol=ftol)
    elif backend == "gtsam":
        x, n_iter, converged, cost = solve_with_gtsam(ym, ydm, wm, x0, max_iter, ftol)
    else:
        raise ValueError(f"backend must be 'scipy' or 'gtsam', got {backend!r}")
    message = (f"batch factor graph ({backend}), {ym.shape[0]} factors: cost {cost:.3g} after "
               f"{n_iter} iterations" if converged
               else f"iteration cap {max_iter} reached, cost {cost:.3g}")
    return magyc_calibration(x, samples, True, n_iter, converged, message)
