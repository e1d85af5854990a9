"""Cramer-Rao bound of the calibration model ``y_k = T m_k + h + e_k`` (eq. 67).

The parameters are ``theta = (vec T, h)`` (vec row-major, 12 numbers); each sample also has an
unknown direction ``m_k`` on the unit sphere (2 nuisance degrees of freedom per sample), and
``e_k ~ N(0, sigma^2 I)``. The bound is on the mean squared error of the accuracy cost's two
parts, ``||h - h_true||^2 + ||T - T_true R||_F^2`` with R the Procrustes alignment (72-73),
i.e. on ``E[J_h^2 + J_T^2]`` of any unbiased estimator.

Derivation (what :func:`fisher_information` computes):

* The Fisher information of one sample for ``(theta, phi_k)`` is ``A^T A / sigma^2`` with
  ``A = [d y_k / d theta, T B_k]``, B_k a 3x2 basis of the tangent plane of the sphere at m_k.
  The directions touch one sample each, so eliminating them (Schur complement) leaves
  ``A_theta^T P_k A_theta / sigma^2`` with P_k the projector onto the orthogonal complement of
  the column space of ``T B_k``. That complement is one-dimensional and spanned by
  ``n_k = T^-T m_k`` (``n_k^T T B_k = m_k^T B_k = 0``), so ``P_k = n_k n_k^T / ||n_k||^2`` and
  the information is a sum of rank-one terms ``a_k a_k^T / (sigma^2 ||n_k||^2)`` with
  ``a_k = A_theta^T n_k = (vec(n_k m_k^T), n_k)``: only the radial part of each residual
  carries information about T and h.
* ``T -> T Q`` (Q orthogonal) with ``m_k -> Q^T m_k`` leaves the data unchanged (eq. 70): the
  three directions ``(vec(T Omega), 0)``, Omega skew, are in the null space of the information
  (``a_k . vec(T Omega) = m_k^T Omega m_k = 0``). The Procrustes alignment of (71) removes
  exactly these directions from an error to first order (``min_Omega ||dT - T Omega||_F`` is the
  orthogonal projection), so the bound on the aligned error is the trace of the information's
  inverse on the orthogonal complement of the gauge directions (its pseudo-inverse).

For ``T = I`` and uniformly spread directions the bound is ``9 sigma^2/K`` for h and
``(3 + 5 * 15/2) sigma^2/K = 40.5 sigma^2/K`` for T: the information of ``h`` is
``K/(3 sigma^2) I``; that of a symmetric ``dT = c I/sqrt(3) + S0`` (S0 traceless) is
``K/sigma^2 E[(m^T dT m)^2] = K/sigma^2 (c^2/3 + 2 ||S0||_F^2/15)``, and its skew part is
the gauge.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from magbench.core.rotations import skew
from magbench.core.seeding import rng

__all__ = ["CRB", "MODEL_PARAMETERS", "alignment_covariance", "alignment_rotation",
           "crb_covariance", "crb_mse", "efficient_expected_J", "fisher_information",
           "gauge_basis", "model_basis", "parameter_covariance", "rotation_covariance"]

#: Free parameters of each model of ``y = T m + h`` (``T`` modulo a rotation for ``full``):
#: the columns of :func:`model_basis`.
MODEL_PARAMETERS = {"full": 9, "diagonal": 6, "sphere": 4, "bias": 3}

#: Standard normal draws for the expected J of an efficient estimator: fresh draws for every
#: dataset, seeded by the dataset itself, so the number is a deterministic function of the
#: dataset and the draws' sampling error averages out over a sweep's datasets (one fixed set
#: reused for every dataset biased every mean by that set's error).
_N_DRAWS = 4000
_DRAW_SEED = 20210917


@dataclass(frozen=True)
class CRB:
    """Cramer-Rao bound on the mean squared error of the accuracy cost's parts.

    Attributes
    ----------
    total : float
        Bound on ``E[||h - h_true||^2 + ||T - T_true R||_F^2]``.
    h_part, T_part : float
        Bounds on ``E[||h - h_true||^2]`` and ``E[||T - T_true R||_F^2]``.
    """

    total: float
    h_part: float
    T_part: float


def fisher_information(T: np.ndarray, m: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Fisher information of ``theta = (vec T, h)`` with the directions eliminated.

    Parameters
    ----------
    T : ndarray, shape (3, 3)
        True calibration matrix (must be invertible).
    m : ndarray, shape (K, 3)
        True unit field directions.
    sigma : float
        Noise standard deviation (> 0).

    Returns
    -------
    ndarray, shape (12, 12)
        ``sum_k a_k a_k^T / (sigma^2 ||n_k||^2)`` with ``n_k = T^-T m_k`` and
        ``a_k = (vec(n_k m_k^T), n_k)``; vec is row-major (``T.ravel()``), then h.
    """
    T = np.asarray(T, dtype=float)
    m = np.asarray(m, dtype=float)
    n = np.linalg.solve(T.T, m.T).T                       # (K, 3): normals of the ellipsoid
    a = np.hstack([(n[:, :, None] * m[:, None, :]).reshape(len(m), 9), n])
    weights = 1.0 / np.einsum("ij,ij->i", n, n)
    return (a * weights[:, None]).T @ a / sigma ** 2


def gauge_basis(T: np.ndarray) -> np.ndarray:
    """Orthonormal basis (12, 3) of the rotation directions ``(vec(T Omega), 0)``, Omega skew."""
    T = np.asarray(T, dtype=float)
    generators = np.zeros((3, 3, 3))
    for k, (i, j) in enumerate([(1, 2), (2, 0), (0, 1)]):
        generators[k, i, j], generators[k, j, i] = -1.0, 1.0
    G = np.zeros((12, 3))
    G[:9] = np.stack([(T @ W).ravel() for W in generators], axis=1)
    return np.linalg.qr(G)[0]


def model_basis(T: np.ndarray, model: str = "full") -> np.ndarray:
    """Orthonormal basis (12, p) of the directions of ``(vec T, h)`` a model lets vary.

    ``full``: the complement of :func:`gauge_basis` (p = 9; the rotation is not estimable);
    ``diagonal``: ``T_00, T_11, T_22`` and h (p = 6); ``sphere``: ``vec(I) / sqrt(3)`` and h
    (p = 4); ``bias``: h alone (p = 3). The restricted models have no rotation gauge.
    """
    if model == "full":
        return np.linalg.qr(gauge_basis(T), mode="complete")[0][:, 3:]
    cols = {"diagonal": [0, 4, 8], "sphere": [], "bias": []}
    if model not in cols:
        raise ValueError(f"model must be full, diagonal, sphere or bias, got {model!r}")
    Q = np.zeros((12, len(cols[model]) + 3 + (model == "sphere")))
    for k, i in enumerate(cols[model]):
        Q[i, k] = 1.0
    if model == "sphere":
        Q[[0, 4, 8], 0] = 1.0 / np.sqrt(3.0)
    Q[9:, -3:] = np.eye(3)
    return Q


def parameter_covariance(T: np.ndarray, m: np.ndarray, sigma: float,
                         model: str = "full") -> np.ndarray:
    """Inverse Fisher information of ``(vec T, h)`` within a model, shape (12, 12).

    The information of :func:`fisher_information` restricted to :func:`model_basis` and
    inverted there: ``sigma^2 Q (Q^T F Q)^-1 Q^T``. For ``full`` this is the Cramer-Rao bound on
    the aligned error (the pseudo-inverse; the gauge is the information's null space). ``inf``
    on the diagonal when the directions do not determine the parameters (e.g. all samples on
    one great circle); zeros when ``sigma == 0``.
    """
    if sigma == 0:
        return np.zeros((12, 12))
    Q = model_basis(T, model)
    F = Q.T @ fisher_information(T, m, 1.0) @ Q
    eig = np.linalg.eigvalsh(F)
    if eig[0] <= 1e-12 * eig[-1]:
        return np.diag(np.full(12, np.inf))
    return sigma ** 2 * (Q @ np.linalg.solve(F, Q.T))


def crb_covariance(T: np.ndarray, m: np.ndarray, sigma: float) -> np.ndarray:
    """Bound on the covariance of the aligned error of ``(vec T, h)``, shape (12, 12).

    The information restricted to the orthogonal complement of :func:`gauge_basis` and
    inverted there (the pseudo-inverse, since the gauge is the information's null space):
    :func:`parameter_covariance` of the full model.
    ``inf`` on the diagonal when the directions do not determine the parameters (e.g. all
    samples on one great circle); zeros when ``sigma == 0``.
    """
    return parameter_covariance(T, m, sigma, "full")


def crb_mse(T_true: np.ndarray, h_true: np.ndarray, m: np.ndarray, sigma: float, *,
            covariance: np.ndarray | None = None) -> CRB:
    """Cramer-Rao bound on ``E[||dh||^2 + ||dT||_F^2]`` (the squared parts of J, eq. 74).

    Parameters
    ----------
    T_true : ndarray, shape (3, 3)
    h_true : ndarray, shape (3,)
        Unused: the information does not depend on the offset. Kept so the call names the
        whole truth.
    m : ndarray, shape (K, 3)
        The dataset's true unit directions.
    sigma : float
        Noise standard deviation.
    covariance : ndarray, shape (12, 12), optional
        :func:`crb_covariance` of these arguments, if the caller has it already (a sweep's
        trial needs it twice).

    Returns
    -------
    CRB
        ``total = h_part + T_part``, the traces of the h and T blocks of
        :func:`crb_covariance`.
    """
    del h_true
    C = crb_covariance(T_true, m, sigma) if covariance is None else covariance
    diag = np.diag(C)
    T_part, h_part = float(diag[:9].sum()), float(diag[9:].sum())
    return CRB(T_part + h_part, h_part, T_part)


def _standard_draws(T_true: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The dataset's own (N, 12) standard normal draws: a stream of :func:`rng` keyed by a
    hash of the true matrix and the field directions."""
    key = zlib.crc32(np.ascontiguousarray(T_true, float).tobytes()
                     + np.ascontiguousarray(m, float).tobytes())
    return rng(_DRAW_SEED, "efficient_expected_J", key).standard_normal((_N_DRAWS, 12))


def efficient_expected_J(T_true: np.ndarray, m: np.ndarray, sigma: float, *,
                         covariance: np.ndarray | None = None) -> float:
    """``E[J] = E[||dh|| + ||dT||_F]`` (eq. 74) of an efficient unbiased estimator.

    The error of an estimator that attains the bound is Gaussian with covariance
    :func:`crb_covariance` (asymptotically, as maximum likelihood is); the expectation is
    computed over 4000 draws of the dataset's own (relative error about 0.3 % per dataset,
    independent between datasets, so a sweep's mean is unbiased). This is the
    number to set beside the review's rho (78), a mean of J, not of J squared.
    ``covariance``: :func:`crb_covariance` of these arguments, if the caller has it already.
    """
    C = crb_covariance(T_true, m, sigma) if covariance is None else covariance
    if not np.all(np.isfinite(C)):
        return float("inf")
    w, V = np.linalg.eigh(C)
    z = _standard_draws(T_true, m) @ (V * np.sqrt(np.clip(w, 0.0, None))).T
    return float(np.mean(np.linalg.norm(z[:, :9], axis=1) + np.linalg.norm(z[:, 9:], axis=1)))


def alignment_rotation(M: np.ndarray) -> np.ndarray:
    """The alignment ``R = M^-1 (M M^T)^(1/2)`` of a magnetometer ``y = M m_imu + h`` whose
    field ``m_imu`` is in the IMU's axes: ``m_imu = R A (y - h)``, ``A = (M M^T)^(-1/2)``."""
    U, s, _ = np.linalg.svd(M)
    return np.linalg.solve(M, (U * s) @ U.T)


def alignment_covariance(M: np.ndarray, m_w: np.ndarray, g_w: np.ndarray, Q: np.ndarray,
                         sigma_m: float, sigma_a: float) -> np.ndarray:
    """Cramer-Rao bound on the alignment rotation, from static magnetometer and accelerometer.

    Model: ``y_k = M Q_k^T m_w + h + e_k``, ``a_k = Q_k^T g_w + n_k`` with ``e ~ N(0,
    sigma_m^2 I)``, ``n ~ N(0, sigma_a^2 I)``, unknown ``M`` (9), ``h`` (3), the field's
    inclination (1; ``m_w`` turns in the plane of ``g_w`` and ``m_w``) and each attitude
    ``Q_k`` (3 nuisance parameters per sample, eliminated by the Schur complement of its
    block, as the directions are in :func:`fisher_information`). The bound on the rotation
    vector of ``R_hat R^T`` follows from the bound on ``M`` through the Jacobian of
    :func:`alignment_rotation` (central differences).

    Parameters
    ----------
    M : ndarray, shape (3, 3)
        The magnetometer matrix in the IMU's axes (``T R^T`` for a method's ``T``, ``R``).
    m_w, g_w : ndarray, shape (3,)
        Field and specific force in world axes (their norms set the units of the noise).
    Q : ndarray, shape (K, 3, 3)
        Attitudes, IMU to world.
    sigma_m, sigma_a : float
        Noise standard deviations of the magnetometer and accelerometer samples.

    Returns
    -------
    ndarray, shape (3, 3)
        Covariance bound of the rotation error vector (radians); its trace bounds the mean
        squared rotation angle.
    """
    e = np.cross(np.cross(g_w, m_w), m_w)            # d m_w / d inclination, in their plane
    e *= np.linalg.norm(m_w) / np.linalg.norm(e)
    v, u = np.einsum("kji,j->ki", Q, m_w), np.einsum("kji,j->ki", Q, g_w)
    dv = np.einsum("kji,j->ki", Q, e)
    K = Q.shape[0]
    Jt = np.zeros((K, 6, 13))
    Jt[:, :3, :9] = np.einsum("ij,kl->kijl", np.eye(3), v).reshape(K, 3, 9)
    Jt[:, :3, 9:12] = np.eye(3)
    Jt[:, :3, 12] = dv @ M.T
    Jd = np.concatenate([M @ skew(v), skew(u)], axis=1)
    w = np.array([1 / sigma_m**2] * 3 + [1 / sigma_a**2] * 3)
    A = np.einsum("kai,a,kaj->kij", Jt, w, Jt)
    B = np.einsum("kai,a,kaj->kij", Jt, w, Jd)
    C = np.einsum("kai,a,kaj->kij", Jd, w, Jd)
    info = (A - B @ np.linalg.solve(C, np.swapaxes(B, 1, 2))).sum(axis=0)
    return rotation_covariance(M, np.linalg.inv(info)[:9, :9])


def rotation_covariance(M: np.ndarray, cov_M: np.ndarray) -> np.ndarray:
    """Covariance of the rotation vector of :func:`alignment_rotation` given the covariance
    ``cov_M`` (9x9, row-major) of ``M``: ``G cov_M G^T`` with ``G`` its Jacobian (central
    differences)."""
    R0 = alignment_rotation(M)
    G = np.zeros((3, 9))
    for j in range(9):
        d = np.zeros(9)
        d[j] = 1e-6
        plus = alignment_rotation(M + d.reshape(3, 3)) @ R0.T
        minus = alignment_rotation(M - d.reshape(3, 3)) @ R0.T
        G[:, j] = (_rotvec(plus) - _rotvec(minus)) / 2e-6
    return G @ cov_M @ G.T


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation near the identity (first order is enough here)."""
    return 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
