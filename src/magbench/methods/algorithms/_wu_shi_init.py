"""Wu and Shi's initial estimate, shared by ``wu_shi`` and ``wu_shi_nm``.

Review section 8, eqs. (55)-(57), Algorithm 6 steps 1-5; Wu and Shi (2015) section III.C,
eqs. (20)-(23). The unit-norm relation ``1 = ||R (y_k - h)||^2`` is the quadric
``y_k^T A y_k + b^T y_k + c = 0`` with ``A = R^T R``, ``b = -2 A h``, ``c = h^T A h - 1``,
linear in ``z = [vec(A), b, c]``; its least-squares null vector is scaled so that the quadric
is the unit-sphere image, and ``R = chol(A)``, ``h = -A^-1 b / 2``.
"""

from __future__ import annotations

import math

import numpy as np

from magbench.core.model import CalibrationFailed

__all__ = ["UPPER", "initial_estimate", "quadric_design", "quadric_null_vector", "upper_inverse"]

#: (row, column) of the six upper-triangular entries of a 3x3 matrix, in column-major (vec)
#: order: the order Wu and Shi use for vec(A), vec(R) and vec(T) "excluding the lower
#: triangular entries".
UPPER = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))
UPPER_ROWS = np.array([a for a, _ in UPPER])
UPPER_COLS = np.array([b for _, b in UPPER])


def quadric_design(y: np.ndarray) -> np.ndarray:
    """The matrix ``Y`` of eqs. (55)-(56), one row ``Y_k`` per sample, shape ``(K, 10)``.

    ``A`` is symmetric, so, as Wu and Shi state below their eq. (22), ``vec(A)`` keeps only the
    six upper-triangular entries and the columns ``y_i y_j`` and ``y_j y_i`` of
    ``y_k^T kron y_k^T`` are merged into one column ``2 y_i y_j``. (The review's eq. 55 writes
    the full Kronecker product; taken literally its nine columns hold three identical pairs, so
    ``Y^T Y`` has a three-dimensional null space of skew-symmetric ``A`` whose eigenvectors
    carry no information, and step 2 of Algorithm 6 would return one of them.)
    """
    Y = np.empty((y.shape[0], 10), order="F")   # filled in place, a column at a time
    for col, (a, b) in enumerate(UPPER):
        np.multiply(y[:, a], y[:, b], out=Y[:, col])
        if a != b:
            Y[:, col] *= 2.0
    Y[:, 6:9] = y
    Y[:, 9] = 1.0
    return Y


def quadric_null_vector(Y: np.ndarray, method: str = "svd") -> np.ndarray:
    """``z_e``: the eigenvector of ``Y^T Y`` for its smallest eigenvalue (Algorithm 6, step 2).

    Parameters
    ----------
    Y : ndarray, shape (K, 10)
        The design matrix of :func:`quadric_design`.
    method : {"svd", "eigh"}
        ``"svd"`` (default) takes the right singular vector of ``Y`` for its smallest singular
        value: the same vector, computed without squaring the condition number of ``Y``.
        ``"eigh"`` is the paper's literal form, the eigen-decomposition of ``Y^T Y``.
    """
    if method == "svd":
        # Y = Q R (Householder, backward stable) has the right singular vectors of R: the SVD
        # of the 10x10 R instead of the (K, 10) Y, whose left singular vectors numpy would
        # compute and discard (half the cost of a K = 10 000 fit).
        return np.linalg.svd(np.linalg.qr(Y, mode="r"))[2][-1]
    if method == "eigh":
        return np.linalg.eigh(Y.T @ Y)[1][:, 0]
    raise ValueError(f"method must be 'svd' or 'eigh', got {method!r}")


def upper_inverse(U: np.ndarray) -> np.ndarray:
    """Inverse of an upper-triangular 3x3 matrix, exactly upper triangular.

    Back substitution ``U X = I`` column by column, written out: the LAPACK call it replaces
    (``scipy.linalg.solve_triangular``) cost more in call overhead than in arithmetic and made
    importing the methods import scipy. It raises as that call did.

    Raises
    ------
    ValueError
        If ``U`` holds NaN or infinite values.
    numpy.linalg.LinAlgError
        If a diagonal entry is zero.
    """
    (u00, u01, u02), (_, u11, u12), (_, _, u22) = np.asarray(U, dtype=float).tolist()
    if not all(math.isfinite(v) for v in (u00, u01, u02, u11, u12, u22)):
        raise ValueError("array must not contain infs or NaNs")
    for i, diagonal in enumerate((u00, u11, u22)):
        if diagonal == 0.0:
            raise np.linalg.LinAlgError(f"singular matrix: resolution failed at diagonal {i}")
    i00, i11, i22 = 1.0 / u00, 1.0 / u11, 1.0 / u22
    i12 = -(u12 * i22) / u11
    i01 = -(u01 * i11) / u00
    i02 = -(u01 * i12 + u02 * i22) / u00
    return np.array([[i00, i01, i02], [0.0, i11, i12], [0.0, 0.0, i22]])


def initial_estimate(samples: np.ndarray, *, null_vector: str = "svd", t0_form: str = "inverse",
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Wu and Shi's initial estimate ``(T_hat(0), h(0))`` of eq. (57).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k``.
    null_vector : {"svd", "eigh"}
        How ``z_e`` is computed, see :func:`quadric_null_vector`.
    t0_form : {"inverse", "chol"}
        ``"inverse"`` (default) is Wu and Shi's ``T(0) = (R(0))^-1`` with ``R(0) = chol(A)``
        (their section III.C). ``"chol"`` takes the review's eq. (57) as printed,
        ``T_hat(0) = chol(A)``, i.e. ``R(0)`` itself: a start off by about ``T^2`` (by
        ``alpha^2`` in scale at the review's nominal point), kept to reproduce the review.

    Returns
    -------
    T0 : ndarray, shape (3, 3)
        Upper triangular ``T_hat(0) = R(0)^-1`` with ``R(0) = chol(A)`` upper triangular,
        ``R(0)^T R(0) = A`` (the review's "T_hat(0) = R^-1 = chol(A)" abbreviates this).
    h0 : ndarray, shape (3,)
        ``h(0) = -A^-1 b / 2``.

    Raises
    ------
    CalibrationFailed
        When the scale ``alpha`` of step 3 is undefined or ``A`` is not positive definite
        (the fitted quadric is not an ellipsoid), the latter being the failure the review
        reports in about 1 % of its runs.
    """
    z = quadric_null_vector(quadric_design(samples), null_vector)
    A_e = np.empty((3, 3))
    A_e[UPPER_ROWS, UPPER_COLS] = z[:6]
    A_e[UPPER_COLS, UPPER_ROWS] = z[:6]
    b_e, c_e = z[6:9], z[9]
    try:
        Ainv_b = np.linalg.solve(A_e, b_e)
    except np.linalg.LinAlgError:
        raise CalibrationFailed("initial estimate: A_e is singular") from None
    denominator = float(b_e @ Ainv_b - 4.0 * c_e)
    alpha = 4.0 / denominator if denominator != 0.0 else np.inf
    if not np.isfinite(alpha):
        raise CalibrationFailed("initial estimate: scale alpha of z = alpha z_e is undefined "
                                "(b_e^T A_e^-1 b_e - 4 c_e = 0)")
    A = alpha * A_e                                                # Algorithm 6, steps 3-4
    try:
        L = np.linalg.cholesky(A)                                  # A = L L^T, R(0) = L^T
    except np.linalg.LinAlgError:
        raise CalibrationFailed("initial estimate: A is not positive definite "
                                "(Cholesky failed)") from None
    h0 = -0.5 * Ainv_b                                             # -A^-1 b / 2; alpha cancels
    if t0_form == "inverse":
        return upper_inverse(L.T), h0
    if t0_form == "chol":
        return L.T.copy(), h0
    raise ValueError(f"t0_form must be 'inverse' or 'chol', got {t0_form!r}")
