"""Pieces shared by TWOSTEP (review section 3) and the Crassidis EKF (review section 4).

Both methods work on the attitude-independent effective measurement of eq. (4),
``z_k = ||y_k||^2 - ||m_k||^2``, under the measurement model of Alonso and Shuster (2002),

    y_k = (I + D)^-1 (O m_k + b + eps_k),      D symmetric,

in which the bias ``b`` is added *before* the symmetric correction ``(I + D)^-1``. The review
calls this bias ``h`` in eqs. (5b), (14b), (17) and (19)-(22); it is the ``b`` of the original
papers, not the ``h`` of the review's model (2). Writing (2) as ``y = T m + h + eps`` gives

    T = (I + D)^-1,     h = (I + D)^-1 b,

which is what :func:`calibration_from_D_b` returns by default. The review's (15) and (22) set
``h = b``; that literal reading is kept behind ``bias="review"`` (it is exact only when D = 0).
Evidence: with ``h = b`` noise-free data are not recovered (J ~ ||D b||), with ``h = T b``
they are, to rounding; and expanding ``||m||^2 = ||(I + D) y - b||^2`` gives (17) exactly,
whereas ``||(I + D)(y - h)||^2`` does not.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import CalibrationFailed

#: Row/column of each element of the packed symmetric matrix ``[M11 M22 M33 M12 M13 M23]``
#: (the order of theta' in (11) and of theta in (16)).
SYM_ROWS = np.array([0, 1, 2, 0, 0, 1])
SYM_COLS = np.array([0, 1, 2, 1, 2, 2])

BIAS_CONVENTIONS = ("model", "review")


def quadratic_features(y: np.ndarray) -> np.ndarray:
    """``S_k`` of eqs. (6a) and (20a) for every sample, shape ``(K, 6)``.

    ``S_k @ pack_symmetric(M) == y_k^T M y_k`` for any symmetric ``M``.
    """
    S = y[:, SYM_ROWS] * y[:, SYM_COLS]
    S[:, 3:] *= 2.0
    return S


def pack_symmetric(M: np.ndarray) -> np.ndarray:
    """``[M11 M22 M33 M12 M13 M23]`` of a symmetric 3x3 matrix (order of (11) and (16))."""
    return np.asarray(M)[SYM_ROWS, SYM_COLS]


def unpack_symmetric(p: np.ndarray) -> np.ndarray:
    """The symmetric 3x3 matrix whose packed form (see :func:`pack_symmetric`) is ``p``."""
    M = np.empty((3, 3))
    M[SYM_ROWS, SYM_COLS] = p
    M[SYM_COLS, SYM_ROWS] = p
    return M


def effective_measurements(y: np.ndarray, field_norm: float = 1.0) -> np.ndarray:
    """``z_k = ||y_k||^2 - ||m_k||^2`` of eq. (4), with ``||m_k||`` the constant field norm."""
    return np.einsum("ij,ij->i", y, y) - field_norm**2


def noise_mean(sigma: float) -> float:
    """``mu_k = -3 sigma^2`` of eq. (5a)."""
    return -3.0 * sigma**2


def noise_variance(sigma: float, corrected_norm2: np.ndarray | float = 1.0) -> np.ndarray | float:
    """``sigma_k^2 = 4 sigma^2 ||(I + D) y_k - b||^2 + 6 sigma^4`` of eq. (5b).

    ``corrected_norm2`` is ``||(I + D) y_k - b||^2``; its default 1 is the review's constant
    approximation ("sigma_k^2 can be assumed independent of k"): the corrected measurement is
    the field, of unit norm here.
    """
    return 4.0 * sigma**2 * corrected_norm2 + 6.0 * sigma**4


def D_from_E(E: np.ndarray) -> np.ndarray:
    """Symmetric ``D`` with ``2 D + D^2 = E`` and ``I + D`` positive definite, eqs. (13)-(14a).

    ``E = U S U^T`` (a symmetric eigendecomposition, which is the SVD of (13) with signs kept),
    ``w_j = -1 + sqrt(1 + s_j)``, ``D = U W U^T``.

    Raises
    ------
    CalibrationFailed
        If some ``s_j <= -1``: ``I + E = (I + D)^2`` is not positive definite and no real ``D``
        exists (TWOSTEP's known weak point).
    """
    s, U = np.linalg.eigh(E)
    if not np.all(s > -1.0):
        raise CalibrationFailed(
            f"I + E is not positive definite (eigenvalues of E: {', '.join(f'{v:.3g}' for v in s)};"
            " s_j <= -1 in (13)), so 2D + D^2 = E has no real solution")
    w = np.sqrt(1.0 + s) - 1.0       # written so because 1 + s_j > 0 was just checked
    return (U * w) @ U.T


def calibration_from_D_b(D: np.ndarray, b: np.ndarray,
                         bias: str = "model") -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` of model (2) from the Alonso-Shuster ``D`` and ``b``, eqs. (15)/(22).

    Parameters
    ----------
    D : ndarray, shape (3, 3)
        Symmetric correction.
    b : ndarray, shape (3,)
        The bias of (14b)/(16), added before ``(I + D)^-1``.
    bias : {"model", "review"}
        ``"model"`` returns ``h = (I + D)^-1 b``, the bias of model (2); ``"review"`` returns
        ``h = b`` as (15) and (22) are printed.
    """
    if bias not in BIAS_CONVENTIONS:
        raise ValueError(f"bias must be one of {BIAS_CONVENTIONS}, got {bias!r}")
    T = np.linalg.inv(np.eye(3) + D)
    h = T @ b if bias == "model" else np.array(b, dtype=float)
    return T, h
