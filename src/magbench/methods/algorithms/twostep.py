"""TWOSTEP (Alonso and Shuster 2002), review section 3, Algorithm 1, eqs. (3)-(15).

Step one is the centred least-squares estimate (7)-(8) of ``theta' = [c, E]`` with
``E = 2D + D^2`` and ``c = (I + D) b``, which is linear in the data; step two refines it with
the Gauss-Newton iteration (9)-(11) on the full (centred plus centre) likelihood and stops on
the statistic eta of (12). ``E`` is then taken back to ``D`` by (13)-(14) and ``T = (I + D)^-1``.

What was checked against the original formulation (model ``y = (I + D)^-1 (O m + b + eps)``,
Alonso and Shuster 2002, J. Astronaut. Sci. 50(4); see :mod:`._twostep_model`):

* the sign of (10c) and the matrix of (9) follow from differentiating the centre term
  ``(z_bar - L_bar theta' + c^T v - mu_bar)^2 / (2 sigma_bar^2)``, since
  ``d(c^T (I + E)^-1 c) / d theta' = phi(theta')`` of (10b); both are as printed;
* the bias of (14b) is the original ``b``; the bias of model (2) is ``h = (I + D)^-1 b``
  (= ``v`` of (10a) at the solution), not ``h = b`` as (15) is printed. ``bias="review"``
  keeps the printed form.

Constant field magnitude (this benchmark's setting) makes the centred Fisher matrix (8b)
singular in one direction: data on the ellipsoid ``(y - h)^T (I + E)(y - h) = 1`` satisfy
``L_k theta_0 = const`` with ``theta_0 = [(I + E) h, I + E]``, so centring removes all
information along ``theta_0``. Only the centre term of (9) fixes it. Noise-free data make
(8b) exactly singular, and on noisy data the centred estimate slides along ``theta_0`` to
``E ~ -I`` (the noise of ``z_k`` is almost collinear with ``L_k theta_0``): the centred
estimate alone is then not usable, while Gauss-Newton recovers in a couple of iterations.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._twostep_model import (
    SYM_COLS,
    SYM_ROWS,
    D_from_E,
    calibration_from_D_b,
    effective_measurements,
    noise_mean,
    noise_variance,
    quadratic_features,
    unpack_symmetric,
)
from magbench.methods.registry import register

#: Off-diagonal elements of a symmetric matrix appear twice in a quadratic form.
_SYM_WEIGHT = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])

#: Relative singular value of the weighted centred regressors below which a direction of
#: (8b) counts as unobservable. Far below the noise level (about sigma relative), far above
#: rounding (1e-16): the constant-magnitude direction of noise-free data falls below it.
_RCOND = 1e-10


def design_rows(y: np.ndarray) -> np.ndarray:
    """``L_k = [2 y_k^T, -S_k]`` of eq. (6b) for every sample, shape ``(K, 9)``."""
    return np.hstack([2.0 * y, -quadratic_features(y)])


def split_theta(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``c`` and the symmetric ``E`` of eq. (11) from ``theta' = [c, E11 E22 E33 E12 E13 E23]``."""
    return theta[:3], unpack_symmetric(theta[3:])


def centre_gradient_row(v: np.ndarray) -> np.ndarray:
    """``phi(theta')`` of eq. (10b): the gradient of ``c^T (I + E)^-1 c`` with respect to theta'."""
    return np.concatenate([2.0 * v, -_SYM_WEIGHT * v[SYM_ROWS] * v[SYM_COLS]])


def centred_estimate(L_tilde: np.ndarray, z_tilde: np.ndarray,
                     weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Centred estimate and Fisher matrix, eqs. (8a)-(8b), with uniform weights ``1/sigma_k^2``.

    (8a) is the weighted least-squares solution of ``L~_k theta' = z~_k - mu~_k``; it is
    computed from the SVD of the weighted regressors, which equals ``P~ sum(...)`` whenever
    ``F~`` is invertible and gives the minimum-norm solution when ``F~`` has the one null
    direction of constant-magnitude data (which the Gauss-Newton step then resolves).

    Raises
    ------
    CalibrationFailed
        If ``F~`` is singular in more than that one direction: the data do not determine the
        quadric even up to scale.
    """
    A = np.sqrt(weight) * L_tilde
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    keep = s > _RCOND * s[0]
    if np.count_nonzero(~keep) > 1:
        raise CalibrationFailed(
            f"centred Fisher matrix (8b) is singular in {np.count_nonzero(~keep)} directions "
            f"(singular values {', '.join(f'{v:.2g}' for v in s)}); the samples do not "
            "determine the ellipsoid")
    rhs = U[:, keep].T @ (np.sqrt(weight) * z_tilde)
    theta = Vt[keep].T @ (rhs / s[keep])
    F = (Vt.T * s**2) @ Vt                                          # (8b)
    return theta, F


@register("twostep", label="TWOSTEP", min_samples=10, paper_key="TWOSTEP")
def fit(samples: np.ndarray, *, sigma: float = 0.005, tol: float = 1e-10, max_iter: int = 50,
        refine: bool = True, bias: str = "model") -> Calibration:
    """Calibrate with TWOSTEP (Algorithm 1).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    sigma : float
        Assumed standard deviation of the measurement noise, used by (5): the mean
        ``mu = -3 sigma^2`` corrects the centre term, and the constant variance
        ``sigma_k^2 = 4 sigma^2 + 6 sigma^4`` ((5b) with the corrected measurement of unit norm,
        the review's "independent of k") scales eta. The Gauss-Newton steps themselves do not
        depend on it (uniform weights). Must be positive. Default: the review's nominal 0.005.
    tol : float
        Stop when eta of (12) falls below this. eta is the step's squared length in units of
        its standard deviation, so 1e-10 means a step 1e-5 of a standard deviation long; the
        review leaves the threshold open.
    max_iter : int
        Gauss-Newton iteration cap.
    refine : bool
        False returns the centred estimate (8) without Gauss-Newton (Algorithm 1 steps 1-3 and
        9-10), to show what the second step contributes.
    bias : {"model", "review"}
        ``"model"`` (default) returns the bias of model (2), ``h = (I + D)^-1 b``; ``"review"``
        returns ``h = b`` of (14b) as (15) is printed.

    Returns
    -------
    Calibration
        Symmetric positive definite ``T = (I + D*)^-1`` (the orthogonal factor of the true T
        is unobservable and absorbed in the field directions, eq. 3), ``n_iter`` Gauss-Newton
        iterations; ``converged`` is False when ``max_iter`` was reached.

    Raises
    ------
    CalibrationFailed
        ``I + E`` not positive definite (some ``s_j <= -1`` in (13)), a centred Fisher matrix
        singular in more than the constant-magnitude direction, or a singular Gauss-Newton
        matrix (9).
    """
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    y = samples
    K = y.shape[0]
    z = effective_measurements(y)                                  # (4)
    L = design_rows(y)                                             # (6)
    weight = 1.0 / noise_variance(sigma)                           # 1 / sigma_k^2, (5b)
    inv_sigma_bar2 = K * weight                                    # 1 / sigma_bar^2, (7)
    z_bar, L_bar, mu_bar = z.mean(), L.mean(axis=0), noise_mean(sigma)   # (7), uniform weights
    # mu~_k = 0: with a constant mu_k (5a) the centred noise mean vanishes.
    theta_c, F = centred_estimate(L - L_bar, z - z_bar, weight)    # (8)
    theta, it, eta, converged = theta_c, 0, np.inf, True
    if refine:
        converged = False
        eye = np.eye(3)
        while it < max_iter:
            it += 1
            c, E = split_theta(theta)                              # (11)
            v = np.linalg.solve(eye + E, c)                        # (10a)
            a = L_bar - centre_gradient_row(v)                     # L_bar - phi, (10b)
            r = z_bar - L_bar @ theta + c @ v - mu_bar
            g = F @ (theta - theta_c) - inv_sigma_bar2 * r * a     # (10c)
            H = F + inv_sigma_bar2 * np.outer(a, a)                # matrix of (9)
            step = -np.linalg.solve(H, g)                          # (9)
            theta = theta + step
            eta = float(step @ H @ step)                           # (12)
            if not np.all(np.isfinite(theta)):
                raise CalibrationFailed(f"Gauss-Newton (9) diverged at iteration {it}")
            if eta < tol:
                converged = True
                break
    c, E = split_theta(theta)
    D = D_from_E(E)                                                # (13)-(14a)
    b = np.linalg.solve(np.eye(3) + D, c)                          # (14b)
    T, h = calibration_from_D_b(D, b, bias)                        # (15)
    if not refine:
        message = "centred estimate (8) only"
    elif converged:
        message = f"eta (12) {eta:.3g} after {it} Gauss-Newton iterations"
    else:
        message = f"iteration cap {max_iter} reached, eta (12) {eta:.3g}"
    return Calibration(T, h, it, converged, message)
