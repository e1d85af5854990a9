"""TWOSTEP for the bias only: Alonso and Shuster (2002a) (extra method).

R. Alonso and M. D. Shuster, "TWOSTEP: a fast robust algorithm for attitude-independent
magnetometer-bias determination", J. Astronaut. Sci. 50(4), 433-452, 2002. The review's
Algorithm 1 is the later extension of the same two steps to the full ``(D, h)``; this is the
original bias-only method, with model ``y_k = A_k H_k + b + eps_k`` (``A_k`` the unknown
attitude), i.e. ``T = I`` and ``h = b``, and a known field magnitude ``||H_k||`` (the option
``field_norm``; 1 in the review's normalised data).

The effective scalar measurements (review eq. 4, with ``D = 0``)

    z_k = ||y_k||^2 - ||H_k||^2 = 2 y_k^T b - ||b||^2 + v_k,

have noise of mean ``mu_k = -3 sigma^2`` and variance
``sigma_k^2 = 4 sigma^2 ||y_k - b||^2 + 6 sigma^4 = 4 sigma^2 + 6 sigma^4`` (eq. 5 with
``||y_k - b|| = ||H_k|| = 1``), the same for every k, so all weighted means are plain means.

Step 1 (centred estimate): subtracting the means removes the quadratic term ``||b||^2``,

    z~_k - mu~_k = 2 y~_k^T b,   b~ = F~^-1 sum_k (2 / sigma_k^2) (z~_k - mu~_k) y~_k,
    F~ = sum_k (4 / sigma_k^2) y~_k y~_k^T.

Step 2 (centre correction): Gauss-Newton on the full cost, split exactly into the centred part
``(b - b~)^T F~ (b - b~) / 2`` and the centre part
``(z_bar - 2 y_bar^T b + ||b||^2 - mu_bar)^2 / (2 sigma_bar^2)``, ``sigma_bar^2 = sigma_k^2/K``:

    g(b) = F~ (b - b~) - (2 / sigma_bar^2) (z_bar - 2 y_bar^T b + ||b||^2 - mu_bar) (y_bar - b)
    F(b) = F~ + (4 / sigma_bar^2) (y_bar - b) (y_bar - b)^T
    b_{i+1} = b_i - F(b_i)^-1 g(b_i),

until ``eta_i = (b_{i+1} - b_i)^T F(b_i) (b_{i+1} - b_i)`` falls below a threshold (as in the
review's eq. 12 for the full method).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.registry import register


def effective_measurements(y: np.ndarray) -> np.ndarray:
    """``z_k = ||y_k||^2 - ||H_k||^2`` with ``||H_k|| = 1`` (review eq. 4 with ``D = 0``)."""
    return np.einsum("ij,ij->i", y, y) - 1.0


def centred_estimate(y: np.ndarray, z: np.ndarray, variance: float,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Step 1: ``b~`` and the centred Fisher information ``F~`` (constant weights).

    Raises
    ------
    CalibrationFailed
        If ``F~`` is not positive definite (samples do not span three dimensions).
    """
    y_c = y - y.mean(axis=0)
    z_c = z - z.mean()                      # mu~_k = 0: mu_k is the same for every k
    F_c = (4.0 / variance) * (y_c.T @ y_c)
    try:
        L = np.linalg.cholesky(F_c)
    except np.linalg.LinAlgError:
        raise CalibrationFailed("TWOSTEP: centred Fisher information is not positive definite "
                                "(samples do not span three dimensions)") from None
    rhs = (2.0 / variance) * (y_c.T @ z_c)
    b = np.linalg.solve(L.T, np.linalg.solve(L, rhs))
    return b, F_c


@register("twostep_hi", label="TWOSTEP (bias only)", min_samples=4, family="extra", model="bias")
def fit(samples: np.ndarray, *, field_norm: float = 1.0, sigma: float = 0.005,
        max_iter: int = 200, tol: float = 1e-3) -> Calibration:
    """Estimate the bias with TWOSTEP (Alonso and Shuster 2002a); ``T = field_norm * I``.

    Unlike the full methods, a bias-only method does not estimate the field magnitude: it is
    an input (``field_norm``, e.g. from a geomagnetic model), which is why :func:`calibrate`
    hands this method the samples in their own units.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k``, in the same unit as ``field_norm``.
    field_norm : float
        The known magnitude ``||H_k||`` of the field, in the samples' unit (1 in the review's
        normalised data).
    sigma : float
        Measurement noise standard deviation per axis, in units of the field magnitude
        (default: the review's nominal 0.005, eq. 80). It sets the noise mean
        ``mu = -3 sigma^2`` of ``z_k`` and the scale of ``eta``; with constant weights the
        Gauss-Newton steps do not otherwise depend on it.
    max_iter : int
        Cap on Gauss-Newton iterations of step 2.
    tol : float
        Stop when ``eta_i`` (the step's squared length in the Fisher metric, a chi-square-like
        quantity) falls below this.

    Returns
    -------
    Calibration
        ``T = field_norm * I`` and ``h = b``; ``n_iter`` Gauss-Newton iterations, ``converged``
        False at the cap.

    Raises
    ------
    ValueError
        If ``sigma`` or ``field_norm`` is not positive.
    CalibrationFailed
        If the centred Fisher information is singular, or a Gauss-Newton step fails.
    """
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0, got {sigma}")
    if not field_norm > 0:
        raise ValueError(f"field_norm must be > 0, got {field_norm}")
    y = samples / field_norm       # the algorithm is written for a unit field
    K = y.shape[0]
    variance = 4.0 * sigma ** 2 + 6.0 * sigma ** 4           # sigma_k^2, eq. (5b)
    mu = -3.0 * sigma ** 2                                   # mu_k, eq. (5a)
    z = effective_measurements(y)
    b_tilde, F_c = centred_estimate(y, z, variance)
    y_bar, z_bar = y.mean(axis=0), float(z.mean())
    variance_bar = variance / K                              # sigma_bar^2
    b = b_tilde
    eta = np.inf
    for it in range(1, max_iter + 1):
        d = y_bar - b
        centre_residual = z_bar - 2.0 * y_bar @ b + b @ b - mu
        g = F_c @ (b - b_tilde) - (2.0 / variance_bar) * centre_residual * d
        F = F_c + (4.0 / variance_bar) * np.outer(d, d)
        step = np.linalg.solve(F, g)
        if not np.all(np.isfinite(step)):
            raise CalibrationFailed(f"TWOSTEP: Gauss-Newton step {it} is not finite")
        b = b - step
        eta = float(step @ F @ step)
        if eta < tol:
            return Calibration(field_norm * np.eye(3), field_norm * b, it, True,
                               f"eta {eta:.3g} after {it} Gauss-Newton iterations")
    return Calibration(field_norm * np.eye(3), field_norm * b, max_iter, False,
                       f"iteration cap {max_iter} reached, eta {eta:.3g}")
