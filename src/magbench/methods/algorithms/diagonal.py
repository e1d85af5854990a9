"""Offset and diagonal scale: the axis-aligned ellipsoid (extra method, 6 parameters).

The model ``y = D m + h`` with ``D = diag(s_1, s_2, s_3)``: hard iron and one scale factor per
axis, no cross-coupling or soft-iron rotation. It is the constrained model autopilots fall back
to when the field directions cover too little of the sphere for the full 9-parameter ``T``
(ArduPilot's ``COMPASS_DIA_*`` without ``COMPASS_ODI_*``); ``calibrate`` uses it that way
(:mod:`magbench.pipeline.calibration`).

*Closed form.* Noise-free samples satisfy ``sum_i (y_i - h_i)^2 / s_i^2 = 1``, i.e.
``sum_i a_i y_i^2 + sum_i d_i y_i + g = 0`` with ``a_i = 1 / s_i^2``, ``d_i = -2 a_i h_i`` and
``g = sum_i a_i h_i^2 - 1``, defined up to scale. Normalising ``a_1 + a_2 + a_3 = 3`` (the
trace constraint of the algebraic ellipsoid fit, restricted to a diagonal quadric) leaves six
unknowns and an ordinary least-squares problem. Then ``h_i = -d_i / (2 a_i)``,
``G = sum_i a_i h_i^2 - g`` and ``s_i = sqrt(G / a_i)``. A fit that is not an ellipsoid
(some ``a_i <= 0`` or ``G <= 0``) raises :class:`~magbench.core.model.CalibrationFailed`.

*No refinement.* Levenberg-Marquardt on the norm residuals ``||D^-1 (y_k - h)|| - 1`` was
tried and dropped: on partial coverage it walks into J_r's degenerate minimiser (``h`` far
away, ``D`` large; :mod:`magbench.pipeline.fitting`), J 1e5 on 60 and 45 degree caps, while on
full spheres it gained nothing over the closed form (median J 0.046 both, 40 datasets at the
review's nominal point).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.registry import register


def _algebraic_start(y: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(s, h)`` of the trace-constrained diagonal quadric, or None if it is no ellipsoid."""
    x2 = y * y
    # a_3 = 3 - a_1 - a_2: columns for a_1, a_2, d_1..d_3, g; right side -3 y_3^2.
    design = np.column_stack([x2[:, 0] - x2[:, 2], x2[:, 1] - x2[:, 2], y,
                              np.ones(len(y))])
    sol, *_ = np.linalg.lstsq(design, -3.0 * x2[:, 2], rcond=None)
    a = np.array([sol[0], sol[1], 3.0 - sol[0] - sol[1]])
    d, g = sol[2:5], sol[5]
    if not np.all(a > 0):
        return None
    h = -d / (2.0 * a)
    G = float(a @ (h * h) - g)
    if not G > 0:
        return None
    return np.sqrt(G / a), h


@register("diagonal", label="Offset + diagonal scale", min_samples=7, family="extra",
          model="diagonal")
def fit(samples: np.ndarray) -> Calibration:
    """Calibrate with offset and per-axis scale only (``T`` diagonal).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.

    Returns
    -------
    Calibration
        ``T = diag(s)`` (positive) and ``h``; closed form, ``n_iter = 0``.

    Raises
    ------
    CalibrationFailed
        If the fitted quadric is not an ellipsoid.
    """
    start = _algebraic_start(samples)
    if start is None:
        raise CalibrationFailed("diagonal: the fitted axis-aligned quadric is not an ellipsoid "
                                "(a scale factor is not positive)")
    s, h = start
    return Calibration(np.diag(s), h, 0, True, f"scales {s[0]:.6g}, {s[1]:.6g}, {s[2]:.6g}")
