"""Dorveaux et al. (2009), review section 5, Algorithm 3, eqs. (23)-(31).

Each iteration fits the affine map ``A m~ + B`` that best sends the current field estimates to
their own normalised directions (25), applies it (26) and accumulates it into the total map
``A~, B~`` (28). The data move step by step from the ellipsoid onto the unit sphere.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._common import fit_affine
from magbench.methods.algorithms._jit import njit
from magbench.methods.registry import register


@njit
def iterate(y: np.ndarray, max_iter: int, tol: float
            ) -> tuple[np.ndarray, np.ndarray, int, float]:
    """Algorithm 3's loop (24)-(29), compiled: the accumulated map ``A~, B~`` (28).

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        Measurements.
    max_iter, tol : int, float
        See :func:`fit`.

    Returns
    -------
    A_total, B_total : ndarray, shapes (3, 3) and (3,)
        The accumulated map (28).
    n_iter : int
        Iterations run.
    J_stop : float
        The last ``J_stop`` (29).
    """
    K = y.shape[0]
    # Coordinates as contiguous rows (3, K): the per-sample loops below then vectorise.
    m = np.ascontiguousarray(y.T)                                  # (24)
    target = np.empty_like(m)
    m0, m1, m2, t0, t1, t2 = m[0], m[1], m[2], target[0], target[1], target[2]
    A_total, B_total = np.eye(3), np.zeros(3)
    it, J_stop = 0, np.inf
    while it < max_iter and J_stop > tol:
        it += 1
        for k in range(K):
            norm = np.sqrt(m0[k] * m0[k] + m1[k] * m1[k] + m2[k] * m2[k])
            t0[k] = m0[k] / norm
            t1[k] = m1[k] / norm
            t2[k] = m2[k] / norm
        A, B = fit_affine(m, target)                               # minimise (25)
        for k in range(K):                                         # (26), in place
            a0, a1, a2 = m0[k], m1[k], m2[k]
            m0[k] = A[0, 0] * a0 + A[0, 1] * a1 + A[0, 2] * a2 + B[0]
            m1[k] = A[1, 0] * a0 + A[1, 1] * a1 + A[1, 2] * a2 + B[1]
            m2[k] = A[2, 0] * a0 + A[2, 1] * a1 + A[2, 2] * a2 + B[2]
        A_total, B_total = A @ A_total, A @ B_total + B            # (28)
        J_stop = np.sqrt(np.sum(B * B)) + np.sqrt(np.sum((A - np.eye(3)) ** 2))   # (29)
    return A_total, B_total, it, J_stop


@register("dorveaux", label="Dorveaux", min_samples=10, paper_key="Dorveaux")
def fit(samples: np.ndarray, *, max_iter: int = 5000, tol: float = 1e-12) -> Calibration:
    """Calibrate with the iterative least-squares method of Dorveaux et al. (Algorithm 3).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    max_iter : int
        Iteration cap.
    tol : float
        Stop when ``J_stop = ||B_n|| + ||A_n - I||_F`` of eq. (29) falls below this: the last
        step no longer changes the accumulated map (28). The review leaves the norm of
        ``A_n - I`` open; the Frobenius norm is used.

    Returns
    -------
    Calibration
        ``T = A~^-1`` and ``h = -A~^-1 B~`` (31); ``converged`` is False at the cap.
    """
    A_total, B_total, it, J_stop = iterate(np.ascontiguousarray(samples, dtype=np.float64),
                                           int(max_iter), float(tol))
    T = np.linalg.inv(A_total)                                     # (31)
    h = -T @ B_total
    converged = J_stop <= tol
    note = "" if converged else f"iteration cap {max_iter} reached, "
    return Calibration(T, h, it, converged, f"{note}J_stop (29) {J_stop:.3g} after {it} "
                                            "iterations")
