"""Small numerical pieces shared by several methods."""

from __future__ import annotations

import numpy as np


def fit_affine(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``A, b`` minimising ``sum_k ||A x_k + b - y_k||^2``.

    This is the normal-equation solve ``L = Y G^T (G G^T)^-1`` of review eq. (62) with
    ``G = [x_1 .. x_K; 1 .. 1]``, written for row-sample arrays ``X, Y`` of shape ``(K, 3)``.
    The 4x4 Gram matrix is formed once and solved, never inverted.
    """
    G = np.hstack([X, np.ones((X.shape[0], 1))])
    L = np.linalg.solve(G.T @ G, G.T @ Y).T  # (3, 4) = [A b]
    return L[:, :3], L[:, 3]


def row_norms(X: np.ndarray) -> np.ndarray:
    """Euclidean norm of every row of a ``(K, 3)`` array."""
    return np.sqrt(np.einsum("ij,ij->i", X, X))
