"""Wu and Shi (2015), the approximate ("NM") maximum likelihood of their section III.A.

The unknown field directions are eliminated through ``||m_k|| = 1``, leaving the quartic
objective (8), (11) ``f = sum_k (1 - ||R (y_k - h)||^2)^2`` over ``x = [vec(R) (6 upper
entries), h]``. It is minimised by the Newton ("Gauss-Newton") iteration (10) with the analytic
gradient (12), (14) and Hessian (13), (15), from the same initial estimate as the optimal ML
(their section III.C, review eqs. 55-57). The result is ``T = R^-1`` (their eq. 9).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._wu_shi_init import (
    UPPER_COLS,
    UPPER_ROWS,
    initial_estimate,
    upper_inverse,
)
from magbench.methods.registry import register

__all__ = ["fit", "gradient_hessian", "initial_estimate", "objective", "refine"]

#: Largest condition number of the 9x9 Hessian accepted before calling it singular.
MAX_CONDITION = 1e14


def objective(y: np.ndarray, R: np.ndarray, h: np.ndarray) -> float:
    """The NM objective (11): ``sum_k (1 - ||R u_k||^2)^2`` with ``u_k = y_k - h``."""
    v = (y - h) @ R.T
    return float(np.sum((np.einsum("ij,ij->i", v, v) - 1.0) ** 2))


def gradient_hessian(y: np.ndarray, R: np.ndarray, h: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (12), (14) and Hessian (13), (15) over ``[vec(R) (upper), h]``.

    Written through ``s_k = ||R u_k||^2``: with ``e_k = s_k - 1`` and ``g_k = ds_k/dx``,
    ``grad f = 2 sum_k e_k g_k`` and ``grad^2 f = 2 sum_k (g_k g_k^T + e_k grad^2 s_k)``, which
    expands exactly to the paper's (14)-(15) (e.g. ``H_RR = 4 sum [2 (u u^T) kron (R u u^T R^T)
    + e (u u^T) kron I]``); the sums over k are taken as matrix products.

    Returns
    -------
    grad : ndarray, shape (9,)
    hess : ndarray, shape (9, 9)
    """
    u = y - h
    v = u @ R.T                                                    # R u_k
    e = np.einsum("ij,ij->i", v, v) - 1.0
    # ds/dR_ab = 2 v_a u_b (the entry of 2 u kron R u); ds/dh = -2 R^T R u.
    G = np.hstack([2.0 * v[:, UPPER_ROWS] * u[:, UPPER_COLS], -2.0 * v @ R])
    grad = 2.0 * G.T @ e
    # sum_k e_k grad^2 s_k: RR entry (R_ab, R_cd) = 2 delta_ac sum e u_b u_d; Rh entry
    # (R_ab, h_c) = -2 (R_ac sum e u_b + delta_bc sum e v_a); hh = 2 (sum e) R^T R.
    curvature = np.zeros((9, 9))
    Ue = (u * e[:, None]).T @ u
    curvature[:6, :6] = (2.0 * (UPPER_ROWS[:, None] == UPPER_ROWS[None, :])
                         * Ue[UPPER_COLS[:, None], UPPER_COLS[None, :]])
    w, q = u.T @ e, v.T @ e
    curvature[:6, 6:] = -2.0 * (R[UPPER_ROWS, :] * w[UPPER_COLS, None]
                                + q[UPPER_ROWS, None] * np.eye(3)[UPPER_COLS])
    curvature[6:, :6] = curvature[:6, 6:].T
    curvature[6:, 6:] = 2.0 * e.sum() * (R.T @ R)
    return grad, 2.0 * (G.T @ G + curvature)


def refine(samples: np.ndarray, T0: np.ndarray, h0: np.ndarray, *, max_iter: int = 50,
           xtol: float = 1e-10, rtol: float = 1e-12) -> tuple[Calibration, np.ndarray]:
    """Newton iterations (10) on the quartic objective (11) from a given ``(T(0), h(0))``.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k``.
    T0 : ndarray, shape (3, 3)
        Upper-triangular starting ``T``; the iteration runs on ``R = T^-1`` (so pass
        ``T0 = inv(R0)`` to start from a given ``R0``).
    h0 : ndarray, shape (3,)
        Starting ``h``.
    max_iter : int
        Iteration cap.
    xtol : float
        Stop when ``max|d(R, h)| <= xtol * max(1, max|(R, h)|)``. 0 disables the rule.
    rtol : float
        Stop when the objective (11) changes by at most ``rtol`` times its previous value
        (on noise-free data it reaches exactly zero, which also stops). 0 disables the rule.

    Returns
    -------
    Calibration
        ``T = R^-1`` (upper triangular) and ``h``; ``converged`` is False at the cap.
    history : ndarray, shape (n_iter + 1,)
        The objective (11) at x(0), x(1), ... (Wu and Shi's Figure 3, NM curves).

    Raises
    ------
    CalibrationFailed
        A singular Hessian, or a non-finite iterate (divergence).
    """
    y = samples
    T0 = np.array(T0, dtype=float)
    if T0.shape != (3, 3) or np.any(np.tril(T0, -1) != 0.0):
        raise ValueError("T0 must be an upper-triangular 3x3 matrix")
    R, h = upper_inverse(T0), np.array(h0, dtype=float).reshape(3)
    history = [objective(y, R, h)]
    for it in range(1, max_iter + 1):
        grad, hess = gradient_hessian(y, R, h)
        if not np.all(np.isfinite(hess)) or np.linalg.cond(hess) > MAX_CONDITION:
            raise CalibrationFailed(f"Gauss-Newton: the Hessian (13) is singular at "
                                    f"iteration {it}")
        step = np.linalg.solve(hess, grad)
        R = R.copy()
        R[UPPER_ROWS, UPPER_COLS] -= step[:6]
        h = h - step[6:]
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(h))):
            raise CalibrationFailed(f"Gauss-Newton diverged (non-finite iterate at "
                                    f"iteration {it})")
        history.append(objective(y, R, h))
        size = max(1.0, float(np.max(np.abs(np.concatenate([R.ravel(), h])))))
        step_small = float(np.max(np.abs(step))) <= xtol * size
        cost_flat = abs(history[-1] - history[-2]) <= rtol * history[-2]
        if step_small or cost_flat:
            rule = "step" if step_small else "relative change of f (11)"
            return (Calibration(upper_inverse(R), h, it, True,
                                f"{rule} rule met after {it} iterations, objective (11) "
                                f"{history[-1]:.3g}"),
                    np.array(history))
    return (Calibration(upper_inverse(R), h, max_iter, False,
                        f"iteration cap {max_iter} reached, objective (11) {history[-1]:.3g}"),
            np.array(history))


@register("wu_shi_nm", label="Wu-Shi NM", min_samples=10, family="extra")
def fit(samples: np.ndarray, *, max_iter: int = 50, xtol: float = 1e-10, rtol: float = 1e-12,
        null_vector: str = "svd") -> Calibration:
    """Calibrate with Wu and Shi's approximate ML (NM) estimator, their eqs. (8), (11)-(15).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    max_iter, xtol, rtol : see :func:`refine`.
    null_vector : {"svd", "eigh"}
        How the initial estimate's null vector is computed (see ``wu_shi.fit``).

    Returns
    -------
    Calibration
        ``T = R^-1`` upper triangular and ``h``.

    Raises
    ------
    CalibrationFailed
        ``A`` not positive definite in the initial estimate, a singular Hessian, or divergence.
    """
    T0, h0 = initial_estimate(samples, null_vector=null_vector)
    return refine(samples, T0, h0, max_iter=max_iter, xtol=xtol, rtol=rtol)[0]
