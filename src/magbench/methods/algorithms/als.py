"""Adjusted least squares (ALS) ellipsoid fit: a consistent estimator of the full model.

Kukush, Markovsky and Van Huffel, *Consistent estimation in an implicit quadratic measurement
error model*, Comput. Statist. Data Anal. 47 (2004) 123-147 (KMV); used for magnetometers by
Renaudin, Afzal and Lachapelle, *Complete triaxis magnetometer calibration in the magnetic
domain*, J. Sensors 2010. The model and the adjusted moments are written as in Usevich and
Markovsky, *Adjusted least squares fitting of algebraic hypersurfaces*, Linear Algebra Appl.
2016 (arXiv 1412.2291): the implicit equation ``theta^T phi(d) = 0`` of their eqs. (1)-(3),
here with ``phi`` the ten monomials of a quadric in three variables.

The samples are ``y_l = x_l + e_l`` with ``x_l`` on the quadric
``x^T A x + 2 b^T x + c = 0`` and ``e_l ~ N(0, sigma^2 I)`` independent. The algebraic (ordinary
least squares) fit minimises ``beta^T Psi_ls beta`` with ``Psi_ls = sum_l z(y_l) z(y_l)^T`` over
the ten coefficients ``beta`` (``z`` the monomials of :func:`ellipsoid.fit_unit_normalised`);
its entries are sums of monomials of degree up to four in the noisy coordinates, whose means
carry noise terms, so the fit is biased however many samples it has. ALS replaces every
monomial ``prod_k y_k^(p_k)`` by ``prod_k t_(p_k)(y_k)`` with the Hermite-type polynomials

    t_0 = 1, t_1 = y, t_2 = y^2 - s, t_3 = y^3 - 3 s y, t_4 = y^4 - 6 s y^2 + 3 s^2,

``s = sigma^2``, for which ``E t_p(x + e) = x^p`` (KMV's adjusted moments). The
adjusted matrix ``Psi_als(s)`` is then unbiased for the noise-free ``Psi_ls(x)``, which has
the true ``beta`` in its null space; ``beta`` is its eigenvector of the smallest eigenvalue
(the norm constraint ``||beta|| = 1``), consistent as K grows (KMV's consistency theorem).

An unknown noise variance is estimated as KMV do: ``Psi_als(s)`` loses its
positive definiteness at the true ``s`` in the limit, so ``s`` is the smallest root of
``lambda_min(Psi_als(s)) = 0``, and the estimator with it is consistent too.

The data are centred on their mean and scaled by their RMS distance from it before the fit,
and the estimate is mapped back. Shklyar, Kukush, Markovsky and Van Huffel (J. Multivariate
Anal. 98 (2007) 588-624) show that ALS with the estimated variance is similarity invariant, so
this changes the conditioning of the 10 x 10 eigenproblem, not the estimate.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms.ellipsoid import quadric_to_calibration
from magbench.methods.registry import register

#: Exponents (of y1, y2, y3) and coefficients of the ten monomials of the design row
#: ``[y1^2, y2^2, y3^2, 2 y1 y2, 2 y1 y3, 2 y2 y3, 2 y1, 2 y2, 2 y3, 1]``.
_EXPONENTS = np.array([[2, 0, 0], [0, 2, 0], [0, 0, 2], [1, 1, 0], [1, 0, 1], [0, 1, 1],
                       [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0]])
_COEFFICIENTS = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0, 1.0])
#: Every product of two monomials: its exponents, and where it goes in Psi.
_PAIR_EXPONENTS = (_EXPONENTS[:, None, :] + _EXPONENTS[None, :, :]).reshape(-1, 3)
_UNIQUE, _PAIR_INDEX = np.unique(_PAIR_EXPONENTS, axis=0, return_inverse=True)
_PAIR_INDEX = _PAIR_INDEX.reshape(10, 10)
_PAIR_SCALE = np.outer(_COEFFICIENTS, _COEFFICIENTS)


def _powers(y: np.ndarray) -> np.ndarray:
    """``y^p`` for p = 0..4, shape (5, K, 3)."""
    out = np.empty((5, *y.shape))
    out[0] = 1.0
    for p in range(1, 5):
        out[p] = out[p - 1] * y
    return out


def _adjusted_powers(powers: np.ndarray, s: float) -> np.ndarray:
    """``t_p(y)`` for p = 0..4 at noise variance ``s``: unbiased for the noise-free ``x^p``."""
    t = powers.copy()
    t[2] -= s
    t[3] -= 3.0 * s * powers[1]
    t[4] += -6.0 * s * powers[2] + 3.0 * s * s
    return t


def adjusted_matrix(powers: np.ndarray, s: float) -> np.ndarray:
    """``Psi_als(s)``, the 10 x 10 adjusted moment matrix (divided by K).

    Parameters
    ----------
    powers : ndarray, shape (5, K, 3)
        The samples' coordinates to the powers 0..4 (:func:`_powers`).
    s : float
        Noise variance per coordinate; 0 gives the ordinary least-squares matrix.
    """
    t = _adjusted_powers(powers, s)
    K = powers.shape[1]
    # One adjusted moment per distinct product monomial (35 of them), then scattered.
    moments = np.array([t[a, :, 0] * t[b, :, 1] @ t[c, :, 2] for a, b, c in _UNIQUE]) / K
    return _PAIR_SCALE * moments[_PAIR_INDEX]


def _adjustment_terms(powers: np.ndarray) -> list[list[tuple[int, np.ndarray]]]:
    """``t_p(y) = sum_d s^d c_pd(y)`` per power p = 0..4: the non-zero ``(d, c_pd)``, each
    ``c_pd`` of shape (K, 3) (the definitions in the module notes)."""
    return [[(0, powers[0])], [(0, powers[1])], [(0, powers[2]), (1, -powers[0])],
            [(0, powers[3]), (1, -3.0 * powers[1])],
            [(0, powers[4]), (1, -6.0 * powers[2]), (2, 3.0 * powers[0])]]


def adjusted_polynomial(powers: np.ndarray) -> np.ndarray:
    """``P`` of shape (3, 10, 10) with ``Psi_als(s) = P[0] + s P[1] + s^2 P[2]`` exactly.

    Every adjusted moment is a product of three ``t_p`` whose degrees in ``s`` are
    ``floor(p / 2)``, with ``p`` summing to at most 4: so ``Psi_als`` is exactly quadratic in
    ``s``, and the root search evaluates this polynomial instead of rebuilding the moments from
    the samples at every trial ``s``.
    """
    terms = _adjustment_terms(powers)
    K = powers.shape[1]
    moments = np.zeros((3, len(_UNIQUE)))
    for m, (a, b, c) in enumerate(_UNIQUE):
        for da, ca in terms[a]:
            for db, cb in terms[b]:
                ab = ca[:, 0] * cb[:, 1]
                for dc, cc in terms[c]:
                    if da + db + dc <= 2:
                        moments[da + db + dc, m] += ab @ cc[:, 2]
    return _PAIR_SCALE * (moments / K)[:, _PAIR_INDEX]


def _smallest_eigenvalue(P: np.ndarray, s: float) -> float:
    return float(np.linalg.eigvalsh(P[0] + s * P[1] + (s * s) * P[2])[0])


def noise_variance(powers: np.ndarray, P: np.ndarray | None = None) -> float:
    """KMV's estimate of ``sigma^2``: the smallest ``s >= 0`` where ``Psi_als(s)`` becomes
    singular (its smallest eigenvalue, positive at ``s = 0``, crosses zero).

    The root is bracketed by steps of 4x from 1e-6 of the data's per-coordinate variance (1
    after the scaling of :func:`fit`), so the first crossing is the one found, and then
    refined by Brent's method.
    """
    from scipy.optimize import brentq  # here: registering the methods must not load SciPy

    P = adjusted_polynomial(powers) if P is None else P
    f0 = _smallest_eigenvalue(P, 0.0)
    if f0 <= 1e-15:
        return 0.0            # the samples already lie on a quadric: no noise to remove
    hi = 1e-6
    while _smallest_eigenvalue(P, hi) > 0.0:
        hi *= 4.0
        if hi > 1.0:
            raise CalibrationFailed("no noise variance below the data's own variance makes "
                                    "the adjusted moment matrix singular")
    return float(brentq(lambda s: _smallest_eigenvalue(P, s), 0.0, hi,
                        xtol=1e-14, rtol=1e-12))


@register("als", label="ALS ellipsoid", min_samples=10, family="extra")
def fit(samples: np.ndarray, *, noise_std: float | None = None) -> Calibration:
    """Calibrate with the adjusted least squares ellipsoid fit (consistent in K).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k``.
    noise_std : float or None
        Standard deviation of the noise on each axis, in the samples' unit; None estimates it
        from the data (KMV's variance estimator), as Renaudin et al. do.

    Returns
    -------
    Calibration
        ``h`` the fitted ellipsoid's centre and ``T = M^{-1/2}`` (symmetric positive
        definite). Closed form but for the one-dimensional variance search: ``n_iter = 0``.

    Raises
    ------
    ValueError
        For a negative or non-finite ``noise_std``.
    CalibrationFailed
        If the fitted quadric is not an ellipsoid, or no variance makes the adjusted matrix
        singular.
    """
    if noise_std is not None and not (np.isfinite(noise_std) and noise_std >= 0):
        raise ValueError(f"noise_std must be a finite number >= 0 or None, got {noise_std!r}")
    centre = samples.mean(axis=0)
    y = samples - centre
    scale = float(np.sqrt(np.einsum("ij,ij->", y, y) / (3 * y.shape[0])))
    y = y / scale
    powers = _powers(y)
    P = adjusted_polynomial(powers)
    s = noise_variance(powers, P) if noise_std is None else (noise_std / scale) ** 2
    vectors = np.linalg.eigh(P[0] + s * P[1] + (s * s) * P[2])[1]
    v = vectors[:, 0]
    A = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    h, _, T = quadric_to_calibration(A, v[6:9], float(v[9]))
    return Calibration(scale * T, scale * h + centre, 0, True,
                       f"adjusted least squares; noise std {scale * np.sqrt(s):.3g} "
                       f"({'estimated' if noise_std is None else 'given'})")
