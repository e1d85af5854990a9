"""Dorveaux et al. (2009), review section 5, Algorithm 3, eqs. (23)-(31).

Each iteration fits the affine map ``A m~ + B`` that best sends the current field estimates to
their own normalised directions (25), applies it (26) and accumulates it into the total map
``A~, B~`` (28). The data move step by step from the ellipsoid onto the unit sphere.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._common import fit_affine, row_norms
from magbench.methods.registry import register


@register("dorveaux", label="Dorveaux", min_samples=4, paper_key="Dorveaux")
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
    m = samples.copy()                                             # (24)
    A_total, B_total = np.eye(3), np.zeros(3)
    it, J_stop = 0, np.inf
    while it < max_iter and J_stop > tol:
        it += 1
        A, B = fit_affine(m, m / row_norms(m)[:, None])            # minimise (25)
        m = m @ A.T + B                                            # (26)
        A_total, B_total = A @ A_total, A @ B_total + B            # (28)
        J_stop = float(np.linalg.norm(B) + np.linalg.norm(A - np.eye(3)))   # (29)
    T = np.linalg.inv(A_total)                                     # (31)
    h = -T @ B_total
    converged = J_stop <= tol
    note = "" if converged else f"iteration cap {max_iter} reached, "
    return Calibration(T, h, it, converged, f"{note}J_stop (29) {J_stop:.3g} after {it} "
                                            "iterations")
