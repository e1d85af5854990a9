"""MAG.I.C.AL. (Papafotis and Sotiriadis 2019), review section 9, Algorithm 7, eqs. (58)-(65).

Alternates between the linear least-squares solve of ``Y = L G`` for ``L = [T h]`` (62) with the
field directions fixed, and the re-normalisation of the directions ``m_k = T^-1 (y_k - h)``
(63)-(64), which together minimise (58) block by block.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._common import fit_affine, row_norms
from magbench.methods.registry import register


def cost(m_tilde: np.ndarray) -> float:
    """J(T, h) of eq. (65): ``sum_k (||m~_k||^2 - 1)^2``."""
    return float(np.sum((np.einsum("ij,ij->i", m_tilde, m_tilde) - 1.0) ** 2))


@register("magical", label="MAG.I.C.AL", min_samples=4, paper_key="MAGICAL")
def fit(samples: np.ndarray, *, max_iter: int = 2000, tol: float = 1e-24,
        rtol: float = 1e-12) -> Calibration:
    """Calibrate with MAG.I.C.AL. (Algorithm 7).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    max_iter : int
        Iteration cap.
    tol : float
        Stop when the cost (65) is below this (noise-free data reach it).
    rtol : float
        Stop when the cost (65) changes by less than ``rtol`` times its value between two
        iterations. The paper's rule, "until J is sufficiently small", never triggers on noisy
        data, whose cost settles at a positive floor; this relative rule is what ends those runs.

    Returns
    -------
    Calibration
        ``converged`` is False when ``max_iter`` was reached.
    """
    y = samples
    m = y / row_norms(y)[:, None]                                  # (59)
    previous = np.inf
    for it in range(1, max_iter + 1):
        T, h = fit_affine(m, y)                                    # (62), (61b)
        # (64) for all k at once; one 3x3 inverse and a product beat a K-right-hand-side solve
        # (profiled: the solve was 40 % of the run time) and T is well conditioned here.
        m_tilde = (y - h) @ np.linalg.inv(T).T
        m = m_tilde / row_norms(m_tilde)[:, None]                  # (63)
        J = cost(m_tilde)                                          # (65)
        if J <= tol or (it > 1 and abs(previous - J) <= rtol * previous):
            return Calibration(T, h, it, True, f"cost (65) {J:.3g} after {it} iterations")
        previous = J
    return Calibration(T, h, max_iter, False,
                       f"iteration cap {max_iter} reached, cost (65) {J:.3g}")
