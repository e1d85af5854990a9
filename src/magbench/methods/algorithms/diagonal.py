"""Offset and diagonal scale: the axis-aligned ellipsoid (extra method, 6 parameters).

The model ``y = D m + h`` with ``D = diag(s_1, s_2, s_3)``: hard iron and one scale factor per
axis, no cross-coupling or soft-iron rotation. It is the constrained model autopilots fall back
to when the field directions cover too little of the sphere for the full 9-parameter ``T``
(ArduPilot's ``COMPASS_DIA_*`` without ``COMPASS_ODI_*``); ``calibrate`` uses it that way
(:mod:`magbench.studies.calibration`).

*Start (closed form).* Noise-free samples satisfy ``sum_i (y_i - h_i)^2 / s_i^2 = 1``, i.e.
``sum_i a_i y_i^2 + sum_i d_i y_i + g = 0`` with ``a_i = 1 / s_i^2``, ``d_i = -2 a_i h_i`` and
``g = sum_i a_i h_i^2 - 1``, defined up to scale. Normalising ``a_1 + a_2 + a_3 = 3`` (the
trace constraint of the algebraic ellipsoid fit, restricted to a diagonal quadric) leaves six
unknowns and an ordinary least-squares problem. Then ``h_i = -d_i / (2 a_i)``,
``G = sum_i a_i h_i^2 - g`` and ``s_i = sqrt(G / a_i)``. A fit that is not an ellipsoid
(some ``a_i <= 0`` or ``G <= 0``) starts from the sphere fit instead.

*Refinement.* The algebraic residual weights samples unevenly (it is biased on partial
coverage), so the start is refined by Levenberg-Marquardt on the norm residuals
``r_k = ||D^-1 (y_k - h)|| - 1`` (the residuals of J_r, eq. 81, to first order), with the
Jacobian ``d r_k / d h_i = -u_ki / (s_i ||u_k||)`` and ``d r_k / d s_i = -u_ki^2 / (s_i ||u_k||)``,
``u_k = D^-1 (y_k - h)``.
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


def _sphere_start(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centred = y - y.mean(axis=0)
    sq = np.einsum("ij,ij->i", y, y)
    c = np.linalg.lstsq(2.0 * centred, sq - sq.mean(), rcond=None)[0]
    r = float(np.sqrt(np.mean(np.einsum("ij,ij->i", y - c, y - c))))
    return np.full(3, r), c


def _residuals(y: np.ndarray, s: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = (y - h) / s
    return u, np.sqrt(np.einsum("ij,ij->i", u, u))


@register("diagonal", label="Offset + diagonal scale", min_samples=6, family="extra",
          model="diagonal")
def fit(samples: np.ndarray, *, max_iter: int = 50, tol: float = 1e-12) -> Calibration:
    """Calibrate with offset and per-axis scale only (``T`` diagonal).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    max_iter : int
        Cap on Levenberg-Marquardt iterations after the closed-form start.
    tol : float
        Stop when the relative decrease of the sum of squared residuals is below ``tol``.

    Returns
    -------
    Calibration
        ``T = diag(s)`` (positive) and ``h``.

    Raises
    ------
    CalibrationFailed
        If a scale factor is not positive and finite (the data do not determine it).
    """
    start = _algebraic_start(samples)
    s, h = start if start is not None else _sphere_start(samples)
    u, rho = _residuals(samples, s, h)
    cost = float(np.sum((rho - 1.0) ** 2))
    lam, n_iter, converged = 1e-3, 0, False
    for n_iter in range(1, max_iter + 1):   # noqa: B007 (n_iter is reported)
        J = np.hstack([-(u * u) / (rho[:, None] * s), -u / (rho[:, None] * s)])   # (K, 6)
        r = rho - 1.0
        JtJ, Jtr = J.T @ J, J.T @ r
        improved = False
        while lam < 1e12:
            step = np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ) + 1e-15), -Jtr)
            s_new, h_new = s + step[:3], h + step[3:]
            if np.all(s_new > 0):
                u_new, rho_new = _residuals(samples, s_new, h_new)
                new_cost = float(np.sum((rho_new - 1.0) ** 2))
                if new_cost <= cost:
                    improved = True
                    break
            lam *= 10.0
        if not improved:
            converged = True              # no step lowers the cost: a (local) minimum
            break
        decrease = (cost - new_cost) / max(cost, 1e-300)
        s, h, u, rho, cost = s_new, h_new, u_new, rho_new, new_cost
        lam = max(lam / 10.0, 1e-12)
        if decrease < tol:
            converged = True
            break
    if not (np.all(np.isfinite(s)) and np.all(s > 0) and np.all(np.isfinite(h))):
        raise CalibrationFailed("diagonal: a scale factor is not positive and finite")
    return Calibration(np.diag(s), h, n_iter, converged,
                       f"scales {s[0]:.6g}, {s[1]:.6g}, {s[2]:.6g}")
