"""Fang et al. (2011), constrained least-squares ellipsoid fit, section III (extra method).

J. Fang, H. Sun, J. Cao, X. Zhang and Y. Tao, "A novel calibration method of magnetic compass
based on ellipsoid fitting", IEEE Trans. Instrum. Meas. 60(6), 2053-2061, 2011.

The quadric ``a x^2 + b xy + c y^2 + d xz + e yz + f z^2 + p x + q y + r z + s = 0`` is fitted
to the samples by minimising the algebraic residual ``||S a||^2`` (``S`` the ``K x 10`` design
matrix) under the constraint ``4 a c - b^2 = 1``, which makes the section of the quadric by
planes ``z = const`` an ellipse and fixes the arbitrary scale of the coefficients (the
ellipse-specific constraint of Fitzgibbon et al. 1999, applied to the ``x``-``y`` block).
With the Lagrange multiplier ``lambda`` this is the generalised eigenproblem
``S^T S a = lambda C a``. Partitioning ``a = (a1, a2)`` with ``a1 = (a, b, c)`` and
``S^T S = [[S11, S12], [S21, S22]]`` eliminates ``a2 = -S22^-1 S21 a1`` and leaves the 3x3
problem

    C11^-1 (S11 - S12 S22^-1 S21) a1 = lambda a1,   C11 = [[0, 0, 2], [0, -1, 0], [2, 0, 0]].

Exactly one eigenvalue is positive, or zero for noise-free data (``C11`` has one positive and
two negative eigenvalues and the reduced scatter matrix is positive semi-definite); its
eigenvector is the solution.

From ``A`` (the symmetric matrix of the quadratic part) and ``(p, q, r)`` the hard iron is the
centre ``h = -(2 A)^-1 (p, q, r)`` and the soft iron is ``G^-1`` with ``G = A^{1/2}``, which is
correct only up to an overall scale: ``4ac - b^2 = 1`` sets the scale of ``A`` arbitrarily.
Here ``T = s A^{-1/2}`` with ``s`` chosen so that the calibrated samples ``T^-1 (y_k - h)`` have
unit mean norm (the field magnitude is one in this harness's convention).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.registry import register

#: The constraint ``4 a c - b^2 = a1^T C11 a1`` on ``a1 = (a, b, c)``.
C11 = np.array([[0.0, 0.0, 2.0], [0.0, -1.0, 0.0], [2.0, 0.0, 0.0]])
C11_INV = np.linalg.inv(C11)


def design_matrix(y: np.ndarray) -> np.ndarray:
    """Rows ``[x^2, xy, y^2, xz, yz, z^2, x, y, z, 1]`` of Fang's quadric."""
    x1, x2, x3 = y.T
    return np.column_stack([x1 * x1, x1 * x2, x2 * x2, x1 * x3, x2 * x3, x3 * x3,
                            x1, x2, x3, np.ones_like(x1)])


def constrained_quadric(y: np.ndarray) -> np.ndarray:
    """The ten coefficients minimising ``||S a||`` subject to ``4ac - b^2 = 1``.

    Raises
    ------
    CalibrationFailed
        If no eigenvector satisfies the constraint with a positive value.
    """
    D = design_matrix(y)
    scatter = D.T @ D
    S11, S12, S22 = scatter[:3, :3], scatter[:3, 3:], scatter[3:, 3:]
    elimination = np.linalg.solve(S22, S12.T)                 # S22^-1 S21, shape (7, 3)
    reduced = S11 - S12 @ elimination
    _, vectors = np.linalg.eig(C11_INV @ reduced)
    vectors = np.real(vectors)
    # The eigenvector of the positive eigenvalue is the one with a1^T C11 a1 > 0 (their
    # signs agree because a1^T reduced a1 = lambda a1^T C11 a1 with the reduced matrix
    # positive semi-definite). Selecting by this sign rather than by the sign of lambda is
    # robust when lambda is ~0 (noise-free data), where rounding can give it either sign.
    values = np.einsum("ji,jk,ki->i", vectors, C11, vectors)
    best = int(np.argmax(values))
    if not values[best] > 0.0:
        raise CalibrationFailed("Fang: no eigenvector satisfies 4ac - b^2 > 0")
    a1 = vectors[:, best] / np.sqrt(values[best])               # 4ac - b^2 = 1
    return np.concatenate([a1, -elimination @ a1])


def quadric_parts(coefficients: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``A`` (symmetric, positive trace), ``(p, q, r)`` and ``s`` from the ten coefficients."""
    a, b, c, d, e, f, p, q, r, s = coefficients
    A = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    sign = 1.0 if a > 0 else -1.0   # 4ac - b^2 = 1 gives a and c one sign; make it positive
    return sign * A, sign * np.array([p, q, r]), sign * float(s)


def ellipsoid_square_root(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and eigenvectors of ``A``, checking it is positive definite.

    Raises
    ------
    CalibrationFailed
        If ``A`` is not positive definite (the quadric is not an ellipsoid).
    """
    eigenvalues, V = np.linalg.eigh(A)
    if not eigenvalues[0] > 0.0:
        raise CalibrationFailed("Fang: fitted quadric is not an ellipsoid: eigenvalues of A are "
                                f"{np.array2string(eigenvalues, precision=3)}, not all positive")
    return eigenvalues, V


def unit_mean_norm_scale(eigenvalues: np.ndarray, V: np.ndarray, y: np.ndarray,
                         h: np.ndarray) -> float:
    """Mean of ``||A^{1/2} (y_k - h)||``: the ``s`` for which ``T = s A^{-1/2}`` gives
    calibrated samples ``T^-1 (y_k - h) = A^{1/2} (y_k - h) / s`` of unit mean norm."""
    G = (V * np.sqrt(eigenvalues)) @ V.T                       # A^{1/2}, symmetric
    return float(np.mean(np.linalg.norm((y - h) @ G, axis=1)))


@register("fang", label="Fang", min_samples=10, family="extra")
def fit(samples: np.ndarray) -> Calibration:
    """Calibrate with the constrained ellipsoid fit of Fang et al. (2011), section III.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.

    Returns
    -------
    Calibration
        ``h`` the centre of the fitted ellipsoid and ``T = s A^{-1/2}`` (symmetric positive
        definite). The constraint ``4ac - b^2 = 1`` leaves the overall scale of ``T``
        arbitrary, so ``s`` normalises it: the calibrated samples ``T^-1 (y_k - h)`` have unit
        mean norm. Closed form: ``n_iter = 0``.

    Raises
    ------
    CalibrationFailed
        If the constrained fit is not an ellipsoid (``A`` not positive definite).
    """
    # Centring conditions the scatter matrix; the constraint involves only quadratic
    # coefficients, which translation does not change, so the minimiser is the same.
    centre = samples.mean(axis=0)
    y = samples - centre
    A, linear, _ = quadric_parts(constrained_quadric(y))
    eigenvalues, V = ellipsoid_square_root(A)
    h = -(V / (2.0 * eigenvalues)) @ (V.T @ linear)           # -(2 A)^-1 (p, q, r)
    s = unit_mean_norm_scale(eigenvalues, V, y, h)
    T = s * (V / np.sqrt(eigenvalues)) @ V.T                   # s A^{-1/2}
    T = 0.5 * (T + T.T)
    return Calibration(T, h + centre, 0, True,
                       "constrained ellipsoid fit (4ac - b^2 = 1), T scaled to unit mean norm")
