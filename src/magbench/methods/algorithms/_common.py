"""Small numerical pieces shared by several methods.

The iterative methods run their loops compiled with numba, as
``@njit(cache=True, error_model="numpy")``: the machine code is cached on disk next to the source,
so a process compiles, or loads, each loop once, and a division by zero gives inf or NaN as in
NumPy (the methods' failure checks expect that) instead of raising ZeroDivisionError.
:func:`fit_affine` is written as explicit loops so that it can be called from those compiled
loops as well as from Python.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def fit_affine(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``A, b`` minimising ``sum_k ||A x_k + b - y_k||^2``.

    This is the normal-equation solve ``L = Y G^T (G G^T)^-1`` of review eq. (62) with
    ``G = [x_1 .. x_K; 1 .. 1]``, written for row-sample arrays ``X, Y`` of shape ``(K, 3)``.
    The 4x4 Gram matrix ``G G^T`` and the 4x3 ``G Y^T`` are accumulated in one pass over the
    samples (no ``(K, 4)`` copy of the data) and solved, never inverted.

    Parameters
    ----------
    X, Y : ndarray, shape (K, 3)
        Inputs ``x_k`` and targets ``y_k``, one per row.

    Returns
    -------
    A : ndarray, shape (3, 3)
    b : ndarray, shape (3,)
    """
    gram = np.zeros((4, 4))
    rhs = np.zeros((4, 3))
    for k in range(X.shape[0]):
        x0, x1, x2 = X[k, 0], X[k, 1], X[k, 2]
        gram[0, 0] += x0 * x0
        gram[0, 1] += x0 * x1
        gram[0, 2] += x0 * x2
        gram[0, 3] += x0
        gram[1, 1] += x1 * x1
        gram[1, 2] += x1 * x2
        gram[1, 3] += x1
        gram[2, 2] += x2 * x2
        gram[2, 3] += x2
        for j in range(3):
            yj = Y[k, j]
            rhs[0, j] += x0 * yj
            rhs[1, j] += x1 * yj
            rhs[2, j] += x2 * yj
            rhs[3, j] += yj
    gram[3, 3] = X.shape[0]
    for i in range(4):
        for j in range(i):
            gram[i, j] = gram[j, i]
    L = np.linalg.solve(gram, rhs).T  # (3, 4) = [A b]
    return L[:, :3].copy(), L[:, 3].copy()


def row_norms(X: np.ndarray) -> np.ndarray:
    """Euclidean norm of every row of a ``(K, 3)`` array."""
    return np.sqrt(np.einsum("ij,ij->i", X, X))
