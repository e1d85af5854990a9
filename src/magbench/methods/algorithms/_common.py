"""Small numerical pieces shared by several methods.

The iterative methods run their loops compiled with numba, declared with
:func:`magbench.methods.algorithms._jit.njit` (numba's ``njit(cache=True, error_model="numpy")``,
with numba imported on the first call of a compiled loop, not on import).
:func:`fit_affine` is written as explicit loops so that it can be called from those compiled
loops as well as from Python.
"""

from __future__ import annotations

import numpy as np

from magbench.methods.algorithms._jit import njit


@njit
def fit_affine(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``A, b`` minimising ``sum_k ||A x_k + b - y_k||^2``.

    This is the normal-equation solve ``L = Y G^T (G G^T)^-1`` of review eq. (62) with
    ``G = [x_1 .. x_K; 1 .. 1]``. ``X`` and ``Y`` hold the samples as columns, shape ``(3, K)``
    (the compiled loops keep their data so: each coordinate contiguous, which lets LLVM
    vectorise their per-sample arithmetic). The 4x4 Gram matrix ``G G^T`` and the 4x3
    ``G Y^T`` are accumulated in one pass over the samples (no ``(K, 4)`` copy of the data) and
    solved, never inverted.

    Parameters
    ----------
    X, Y : ndarray, shape (3, K)
        Inputs ``x_k`` and targets ``y_k``, one per column.

    Returns
    -------
    A : ndarray, shape (3, 3)
    b : ndarray, shape (3,)
    """
    # The sums live in local scalars, not in the arrays: LLVM cannot prove that ``gram`` and
    # ``rhs`` do not alias X and Y, so array accumulators cost a store and a reload per term.
    # Same terms added in the same order (k ascending): the same sums, bit for bit.
    x0, x1, x2, y0, y1, y2 = X[0], X[1], X[2], Y[0], Y[1], Y[2]
    g00 = g01 = g02 = g03 = g11 = g12 = g13 = g22 = g23 = 0.0
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = r30 = r31 = r32 = 0.0
    for k in range(X.shape[1]):
        a0, a1, a2, b0, b1, b2 = x0[k], x1[k], x2[k], y0[k], y1[k], y2[k]
        g00 += a0 * a0
        g01 += a0 * a1
        g02 += a0 * a2
        g03 += a0
        g11 += a1 * a1
        g12 += a1 * a2
        g13 += a1
        g22 += a2 * a2
        g23 += a2
        r00 += a0 * b0
        r01 += a0 * b1
        r02 += a0 * b2
        r10 += a1 * b0
        r11 += a1 * b1
        r12 += a1 * b2
        r20 += a2 * b0
        r21 += a2 * b1
        r22 += a2 * b2
        r30 += b0
        r31 += b1
        r32 += b2
    gram = np.array([[g00, g01, g02, g03],
                     [g01, g11, g12, g13],
                     [g02, g12, g22, g23],
                     [g03, g13, g23, float(X.shape[1])]])
    rhs = np.array([[r00, r01, r02], [r10, r11, r12], [r20, r21, r22], [r30, r31, r32]])
    L = np.linalg.solve(gram, rhs).T  # (3, 4) = [A b]
    return L[:, :3].copy(), L[:, 3].copy()


def row_norms(X: np.ndarray) -> np.ndarray:
    """Euclidean norm of every row of a ``(K, 3)`` array."""
    return np.sqrt(np.einsum("ij,ij->i", X, X))
