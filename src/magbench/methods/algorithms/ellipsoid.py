"""Algebraic ellipsoid fit: the general quadric by linear least squares (extra method).

The classic calibration of the MATLAB ``ellipsoid_fit`` family (Petrov's File Exchange 24693,
the Merayo et al. 2000 algebraic fit). Noise-free measurements ``y = T m + h`` with
``||m|| = 1`` lie on the quadric

    (y - h)^T M (y - h) = 1,   M = (T T^T)^-1,

which, expanded, is ``y^T A y + 2 b^T y + c = 0`` with ten coefficients defined up to scale.
The coefficients are fitted by linear least squares on the algebraic residual, under one of
two normalisations (option ``constraint``):

* ``"trace"`` (default, the MATLAB ``ellipsoid_fit`` default): ``trace(A) = 3``, leaving nine
  unknowns and an ordinary least-squares problem. The trace is invariant under rotation and
  translation, so the fitted ellipsoid moves rigidly with the data.
* ``"unit"``: ``||(A, b, c)|| = 1`` over the ten coefficients, solved by the smallest right
  singular vector of the design matrix (the total-least-squares algebraic fit).

The centre of the quadric is the hard iron ``h = -A^-1 b``; dividing ``A`` by
``k = h^T A h - c`` gives ``M``, and the soft-iron matrix of ``y = T m + h`` is its inverse
symmetric square root ``T = M^{-1/2}``. Any ``T O`` with ``O`` orthogonal fits the data
equally; the symmetric root is the one closest to a pure scaling.

Algebraic fits are not unbiased under noise (the residual is not the geometric distance) and
do not enforce that the quadric is an ellipsoid: a fit that is not one raises
:class:`~magbench.core.model.CalibrationFailed`.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.registry import register

CONSTRAINTS = ("trace", "unit")


def quadric_to_calibration(A: np.ndarray, b: np.ndarray, c: float,
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre, ``M`` and ``T = M^{-1/2}`` of the quadric ``y^T A y + 2 b^T y + c = 0``.

    Parameters
    ----------
    A : ndarray, shape (3, 3)
        Symmetric quadratic part (any overall scale and sign).
    b : ndarray, shape (3,)
        Half the linear part.
    c : float
        Constant term.

    Returns
    -------
    h, M, T : ndarray
        Centre ``h = -A^-1 b``, shape matrix ``M = A / (h^T A h - c)`` with
        ``(y - h)^T M (y - h) = 1`` on the surface, and ``T = M^{-1/2}`` (symmetric).

    Raises
    ------
    CalibrationFailed
        If ``A`` is singular or ``M`` is not positive definite (the quadric is not a real
        ellipsoid: a hyperboloid, a cylinder, an imaginary ellipsoid, ...).
    """
    A = 0.5 * (A + A.T)
    try:
        h = -np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        raise CalibrationFailed("fitted quadric has a singular quadratic part (no centre); "
                                "it is not an ellipsoid") from None
    k = float(h @ A @ h - c)
    M = A / k
    eigenvalues, V = np.linalg.eigh(M)
    if not (np.all(np.isfinite(eigenvalues)) and eigenvalues[0] > 0.0):
        raise CalibrationFailed("fitted quadric is not an ellipsoid: eigenvalues of its shape "
                                f"matrix are {np.array2string(eigenvalues, precision=3)}, "
                                "not all positive")
    T = (V / np.sqrt(eigenvalues)) @ V.T
    return h, M, 0.5 * (T + T.T)


def fit_trace_normalised(y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares quadric with ``trace(A) = 3`` (nine unknowns).

    Writing ``A = I + A0`` with ``trace(A0) = 0``, the quadric equation becomes the linear
    model ``y^T A0 y + 2 b^T y + c = -||y||^2`` in the five free entries of ``A0``, ``b`` and
    ``c``, solved by ordinary least squares.
    """
    x1, x2, x3 = y.T
    design = np.column_stack([x1 * x1 - x3 * x3, x2 * x2 - x3 * x3,
                              2 * x1 * x2, 2 * x1 * x3, 2 * x2 * x3,
                              2 * x1, 2 * x2, 2 * x3, np.ones_like(x1)])
    u = np.linalg.lstsq(design, -np.einsum("ij,ij->i", y, y), rcond=None)[0]
    A = np.eye(3) + np.array([[u[0], u[2], u[3]],
                              [u[2], u[1], u[4]],
                              [u[3], u[4], -u[0] - u[1]]])
    return A, u[5:8], float(u[8])


def fit_unit_normalised(y: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares quadric with unit-norm coefficient vector (ten unknowns).

    The minimiser of ``||D v||`` over ``||v|| = 1`` is the right singular vector of the design
    matrix ``D`` for its smallest singular value.
    """
    x1, x2, x3 = y.T
    design = np.column_stack([x1 * x1, x2 * x2, x3 * x3, 2 * x1 * x2, 2 * x1 * x3, 2 * x2 * x3,
                              2 * x1, 2 * x2, 2 * x3, np.ones_like(x1)])
    v = np.linalg.svd(design, full_matrices=False)[2][-1]
    A = np.array([[v[0], v[3], v[4]],
                  [v[3], v[1], v[5]],
                  [v[4], v[5], v[2]]])
    return A, v[6:9], float(v[9])


@register("ellipsoid", label="Ellipsoid fit", min_samples=10, family="extra")
def fit(samples: np.ndarray, *, constraint: str = "trace") -> Calibration:
    """Calibrate with the algebraic (general quadric) ellipsoid fit.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    constraint : {"trace", "unit"}
        Normalisation of the quadric coefficients: ``trace(A) = 3`` (default, as in MATLAB's
        ``ellipsoid_fit``; rigid-motion invariant) or unit norm of all ten coefficients.

    Returns
    -------
    Calibration
        ``h`` the quadric's centre and ``T = M^{-1/2}`` (symmetric positive definite), so that
        ``T^-1 (y - h)`` lies on the unit sphere for noise-free data. Closed form:
        ``n_iter = 0``.

    Raises
    ------
    ValueError
        For an unknown ``constraint``.
    CalibrationFailed
        If the fitted quadric is not an ellipsoid.
    """
    if constraint not in CONSTRAINTS:
        raise ValueError(f"constraint must be one of {CONSTRAINTS}, got {constraint!r}")
    # Centring first conditions the design matrix (the linear and constant columns are then
    # nearly orthogonal to the quadratic ones). The trace-constrained minimiser is translation
    # invariant, so only rounding changes; the unit-norm one depends on the origin, and the
    # data mean is a better-defined origin than the sensor's. Undone on h below.
    centre = samples.mean(axis=0)
    y = samples - centre
    A, b, c = fit_trace_normalised(y) if constraint == "trace" else fit_unit_normalised(y)
    h, M, T = quadric_to_calibration(A, b, c)
    # (y - h) M as one product, then row sums: a three-operand einsum loops in C over all
    # index triples (0.8 of 4.7 ms at K = 10 000, for the message alone).
    d = y - h
    residual = np.einsum("ij,ij->i", d @ M, d) - 1.0
    return Calibration(T, h + centre, 0, True,
                       f"{constraint}-normalised quadric; RMS of (y-h)^T M (y-h) - 1: "
                       f"{np.sqrt(np.mean(residual ** 2)):.3g}")
