"""Vasconcelos et al. (2011), review section 6, Algorithm 4, eqs. (32)-(44) and Appendix A.1.

A pseudo-linear least-squares ellipsoid fit (36)-(39) and its closed-form factorisation
(40)-(44) give the initial ``T^ = T^-1`` (lower triangular) and ``h``; Newton's method (35) on
the maximum-likelihood cost (33) over ``x = [vec(T^); h]`` (34) refines them, with the
analytic gradient (A1) and Hessian (A2)-(A3).

Four printed expressions of the initial estimate are wrong; the corrected forms are used and
marked where they appear (derivation in the comments, numerical evidence in the tests):

* (42) ``tan(rho)``: the extra factor ``1 / alpha_1`` is dropped,
  ``tan(rho) = -(2B + EC) / (2 alpha_1^(1/2))``.
* (42) ``tan(phi)``: a factor ``(-(4D + E^2))^(-1/2)`` is missing,
  ``tan(phi) = (BE - 2CD) / (-(4D + E^2) alpha_1)^(1/2)``.
* (40) entry (3, 1): ``-(tan(rho) tan(lambda) sec(phi) + tan(phi)) / a`` (the review has
  ``+ tan(rho) ... - tan(phi)``).
* (43) ``beta_2``: every term but ``-2AEI`` has the wrong sign,
  ``beta_2 = 2BG + CEG - 4AH - C^2 H + BCI - 2AEI``.

The cost (33) is invariant under ``T^ -> R T^`` for any orthogonal ``R``, so its Hessian is
singular at the minimum (rank 9 of 12) and ill-conditioned near it. Plain Newton (35) is the
default (``safeguard="none"``); ``safeguard="lm"`` adds Levenberg-Marquardt damping.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._common import row_norms
from magbench.methods.algorithms._jit import njit
from magbench.methods.registry import register

SAFEGUARDS = ("none", "lm")
INITIALS = ("corrected", "printed")


def pseudo_linear_fit(y: np.ndarray) -> np.ndarray:
    """``p = [A B C D E G H I J]`` of eqs. (36)-(39).

    The quadric ``z^2 = A x^2 + B xy + C xz + D y^2 + E yz + G x + H y + I z + J`` fitted to the
    samples by least squares (39). ``lstsq`` solves the same problem as the normal equations
    ``(L^T L)^-1 L^T b`` without squaring the condition number of ``L``.
    """
    x, yy, z = y.T
    L = np.column_stack([x * x, x * yy, x * z, yy * yy, yy * z, x, yy, z, np.ones_like(x)])  # (37)
    b = z * z                                                                                 # (38)
    return np.linalg.lstsq(L, b, rcond=None)[0]                                               # (39)


def _checked_sqrt(value: float, what: str) -> float:
    """Square root of a quantity that is positive when the fitted quadric is an ellipsoid."""
    if not value > 0.0:
        raise CalibrationFailed(f"vasconcelos: the pseudo-linear fit (39) is not an ellipsoid "
                                f"({what} = {value:.3g} is not positive), so the initial "
                                "estimate (40)-(44) does not exist")
    return float(np.sqrt(value))


def initial_estimate(p: np.ndarray, *,
                     printed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``T^(0)`` (40) and ``h(0)`` (41) from the quadric coefficients, with eqs. (42)-(44).

    ``printed=True`` uses the four expressions exactly as the review prints them (wrong; kept
    to measure what they do); the default uses the corrected ones.

    Writing the quadric as ``(y - h)^T Q (y - h) = 1``, the coefficients give
    ``Q ~ M = -[[A, B/2, C/2], [B/2, D, E/2], [C/2, E/2, -1]]``; ``M`` is positive definite
    exactly when ``-(4D + E^2) > 0`` and ``alpha_1 = 4 det(M) > 0`` (Sylvester, from the
    bottom-right corner), and the radius is real when also ``alpha_2 > 0``. ``T = T^-1`` is the
    lower-triangular Cholesky factor of ``Q^-1``: its rows are the sensor axes with lengths
    ``a, b, c`` and ``T = [[a, 0, 0], [-b sin(rho), -b cos(rho), 0],
    [c cos(lambda) sin(phi), -c sin(lambda), c cos(lambda) cos(phi)]]``, whose inverse is (40).

    Raises
    ------
    CalibrationFailed
        If a square root of a non-positive number arises (the fitted quadric is no ellipsoid).
    """
    A, B, C, D, E, G, H, I, J = (float(v) for v in p)
    alpha1 = -B**2 + D * C**2 + 4 * D * A + A * E**2 - B * E * C                       # (44)
    alpha2 = (4 * A * E**2 * J - E**2 * G**2 - 4 * B * E * C * J + 2 * E * C * H * G
              + 2 * B * E * I * G - 4 * E * H * A * I - 4 * D * I * C * G - C**2 * H**2
              + 4 * D * A * I**2 + 2 * C * B * H * I - 4 * D * G**2 + 4 * D * C**2 * J
              + 4 * B * H * G - 4 * A * H**2 - B**2 * I**2 - 4 * B**2 * J + 16 * D * A * J)
    alpha3 = (E**4 * A - C * B * E**3 + E**2 * C**2 * D - 2 * B**2 * E**2 + 8 * D * A * E**2
              - 4 * D * B**2 + 16 * D**2 * A)
    minor_yz = -(4 * D + E**2)        # 4 x the lower-right 2x2 minor of M
    root1 = _checked_sqrt(alpha1, "alpha_1 (44)")
    root_yz = _checked_sqrt(minor_yz, "-(4D + E^2)")
    _checked_sqrt(alpha2, "alpha_2 (44)")
    a = _checked_sqrt(minor_yz * alpha2, "-(4D + E^2) alpha_2") / (2 * alpha1)         # (42)
    b = _checked_sqrt(-(4 * A + C**2) * alpha2, "-(4A + C^2) alpha_2") / (2 * alpha1)
    c = _checked_sqrt((4 * D * A - B**2) * alpha2, "(4DA - B^2) alpha_2") / (2 * alpha1)
    # (42) corrected: the review's tan(rho) carries an extra 1/alpha_1. From T T^T = Q^-1,
    # sin(rho) = -(Q^-1)_12/(ab) and (4D + E^2)(4A + C^2) - (2B + CE)^2 = 4 alpha_1.
    tan_rho = -(2 * B + E * C) / (2 * root1)
    if printed:
        tan_rho /= alpha1
    # (42) corrected: tan(phi) = t31/t33 = (BE - 2CD)/(-(4D + E^2) alpha_1)^(1/2); the review
    # omits the factor (-(4D + E^2))^(-1/2) (about 1/2 for near-unit data, hence a 2x error).
    tan_phi = (B * E - 2 * C * D) / (root1 if printed else root_yz * root1)
    tan_lambda = E * _checked_sqrt(-alpha1 / alpha3, "-alpha_1/alpha_3")                # (42)
    sec_rho, sec_phi, sec_lambda = (np.hypot(1.0, t) for t in (tan_rho, tan_phi, tan_lambda))
    T_hat = np.array([                                                                   # (40)
        [1 / a, 0.0, 0.0],
        [-tan_rho / a, -sec_rho / b, 0.0],
        # (40) corrected: the review's (3, 1) entry (tan(rho) tan(lambda) sec(phi) - tan(phi))/a
        # is not the inverse of the T above; solving (T^ T)_31 = 0 gives this one.
        [(tan_rho * tan_lambda * sec_phi - tan_phi) / a if printed else
         -(tan_rho * tan_lambda * sec_phi + tan_phi) / a,
         -sec_rho * tan_lambda * sec_phi / b, sec_lambda * sec_phi / c],
    ])
    beta1 = 2 * B * H + B * E * I - 2 * C * D * I - 4 * D * G + E * C * H - E**2 * G      # (43)
    # (43) corrected: h = M^-1 [G H I]^T / 2 = adj(-4M) [G H I]^T / (8 alpha_1); its second row
    # is this; the review flips the sign of every term except -2AEI.
    beta2 = 2 * B * G + C * E * G - 4 * A * H - C**2 * H + B * C * I - 2 * A * E * I
    if printed:
        beta2 = -beta2 - 4 * A * E * I
    beta3 = 4 * D * I * A - 2 * D * G * C + E * G * B - I * B**2 - 2 * E * H * A + C * B * H
    h = np.array([beta1, beta2, beta3]) / (2 * alpha1)                                   # (41)
    return T_hat, h


def pack(T_hat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``x = [vec(T^); h]`` of eq. (34), vec stacking columns (column-major)."""
    return np.concatenate([T_hat.ravel(order="F"), h])


def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack`."""
    return x[:9].reshape(3, 3, order="F"), x[9:]


def cost(x: np.ndarray, y: np.ndarray, sigma: float) -> float:
    """J(x) of eq. (33) with ``sigma_k = sigma`` for all k."""
    T_hat, h = unpack(x)
    r = row_norms((y - h) @ T_hat.T)
    return float(np.sum((r - 1.0) ** 2)) / sigma**2


def gradient_hessian(x: np.ndarray, y: np.ndarray,
                     sigma: float) -> tuple[float, np.ndarray, np.ndarray]:
    """J (33), its gradient (A1) and Hessian (A2)-(A3) at ``x``, summed over samples.

    With ``u_k = y_k - h``, ``v_k = T^ u_k``, ``r_k = ||v_k||`` and ``c_k = 1 - 1/r_k``:
    ``d r_k / d vec(T^) = (u_k kron v_k) / r_k`` because ``vec(v_k u_k^T) = u_k kron v_k`` for the
    column-major vec of (34); this is the ``u_k kron T^ u_k`` of (A1a), so (A1)-(A3) hold as
    printed with that convention.

    Returns
    -------
    J : float
    gradient : ndarray, shape (12,)
    hessian : ndarray, shape (12, 12)
    """
    T_hat, h = unpack(np.asarray(x, dtype=np.float64))
    return _gradient_hessian(np.ascontiguousarray(T_hat), np.ascontiguousarray(h),
                             np.ascontiguousarray(y, dtype=np.float64), float(sigma))


@njit
def _gradient_hessian(T_hat: np.ndarray, h: np.ndarray, y: np.ndarray,
                      sigma: float) -> tuple[float, np.ndarray, np.ndarray]:
    # One compiled pass over the samples accumulates the sums that (A1)-(A3) need, with
    # w_k = u_k kron v_k (w[3a + b] = u_a v_b): sum c w, sum c v, sum c u, sum c u u^T,
    # sum w w^T / r^3, sum w v^T / r^3, sum v v^T / r^3, sum c and sum (r - 1)^2.
    cw = np.zeros(9)
    cv = np.zeros(3)
    cu = np.zeros(3)
    cuu = np.zeros((3, 3))
    ww = np.zeros((9, 9))
    wv = np.zeros((9, 3))
    vv = np.zeros((3, 3))
    c_sum, sq = 0.0, 0.0
    u = np.empty(3)
    v = np.empty(3)
    w = np.empty(9)
    for k in range(y.shape[0]):
        for a in range(3):
            u[a] = y[k, a] - h[a]
        for a in range(3):
            v[a] = T_hat[a, 0] * u[0] + T_hat[a, 1] * u[1] + T_hat[a, 2] * u[2]
        r = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        c = 1.0 - 1.0 / r
        inv_r3 = 1.0 / r**3
        for a in range(3):
            for b in range(3):
                w[3 * a + b] = u[a] * v[b]
        for i in range(9):
            cw[i] += c * w[i]
            for j in range(i, 9):
                ww[i, j] += w[i] * inv_r3 * w[j]
            for b in range(3):
                wv[i, b] += w[i] * inv_r3 * v[b]
        for a in range(3):
            cv[a] += c * v[a]
            cu[a] += c * u[a]
            for b in range(a, 3):
                cuu[a, b] += u[a] * c * u[b]
                vv[a, b] += v[a] * inv_r3 * v[b]
        c_sum += c
        sq += (r - 1.0) ** 2
    for i in range(9):
        for j in range(i):
            ww[i, j] = ww[j, i]
    for a in range(3):
        for b in range(a):
            cuu[a, b] = cuu[b, a]
            vv[a, b] = vv[b, a]
    scale = 2.0 / sigma**2
    gradient = np.empty(12)
    gradient[:9] = scale * cw                                   # (A1a)
    gradient[9:] = -scale * (T_hat.T @ cv)                      # (A1b)
    hessian = np.empty((12, 12))
    TtT = T_hat.T @ T_hat
    wvT = wv @ T_hat
    vvT = T_hat.T @ vv @ T_hat
    for a in range(3):
        for b in range(3):
            i = 3 * a + b
            for c2 in range(3):
                for d2 in range(3):
                    # (A3a): kron(sum c u u^T, I) has cuu[a, c2] at (3a + b, 3c2 + b)
                    kron = cuu[a, c2] if b == d2 else 0.0
                    hessian[i, 3 * c2 + d2] = scale * (ww[i, 3 * c2 + d2] + kron)
            for c2 in range(3):
                # (A3b): kron(cu, T^) has cu_a T^[b, c2]; kron(I, c v) has delta_a,c2 cv_b
                hessian[i, 9 + c2] = -scale * (wvT[i, c2] + cu[a] * T_hat[b, c2]
                                               + (cv[b] if a == c2 else 0.0))
                hessian[9 + c2, i] = hessian[i, 9 + c2]
    for a in range(3):
        for b in range(3):
            hessian[9 + a, 9 + b] = scale * (vvT[a, b] + c_sum * TtT[a, b])   # (A3c)
    return sq / sigma**2, gradient, hessian                     # (A2) assembled above


def _newton_step(g: np.ndarray, H: np.ndarray) -> np.ndarray:
    """``H^-1 g`` of (35); a singular Hessian is a known weak point of (33)."""
    try:
        return np.linalg.solve(H, g)
    except np.linalg.LinAlgError:
        raise CalibrationFailed("vasconcelos: the Hessian (A2) is singular; Newton's step (35) "
                                "is undefined") from None


@register("vasconcelos", label="Vasconcelos", min_samples=10, paper_key="Vasconcelos")
def fit(samples: np.ndarray, *, max_iter: int = 50, rtol: float = 1e-10, tol: float = 1e-24,
        sigma: float = 0.005, safeguard: str = "none", lm_init: float = 1e-3,
        initial: str = "corrected") -> Calibration:
    """Calibrate with the method of Vasconcelos et al. (Algorithm 4).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    max_iter : int
        Cap on Newton iterations.
    rtol : float
        Stop when J (33) changes by at most ``rtol`` times its value in one iteration, or when
        the Newton decrement predicts a decrease ``g^T H^-1 g / 2`` below ``rtol J``. The
        paper's rule, "until J is sufficiently small", never triggers on noisy data.
    tol : float
        The paper's rule: stop when ``sigma^2 J`` (the unweighted sum of squares) is below this;
        noise-free data reach it.
    sigma : float
        The assumed noise standard deviation ``sigma_k`` of (32)-(33); it only scales J.
    safeguard : {"none", "lm"}
        ``"none"`` (default): plain Newton (35), as in the paper. ``"lm"``: Levenberg-Marquardt
        damping, ``(H + mu diag(H)) d = g`` with ``mu`` multiplied by 10 until J decreases and
        divided by 10 after each accepted step.
    lm_init : float
        Initial ``mu`` for ``safeguard="lm"``.
    initial : {"corrected", "printed"}
        ``"corrected"`` (default): eqs. (40)-(43) with the four corrections listed in the
        module docstring, exact on noise-free data. ``"printed"``: the expressions exactly as
        the review prints them, to measure their effect.

    Returns
    -------
    Calibration
        ``T = T^-1`` (Step 8); ``converged`` is False at the iteration cap.

    Raises
    ------
    CalibrationFailed
        If the quadric fit (39) is not an ellipsoid (no real initial estimate), the Hessian is
        singular, or the iterate leaves the finite domain.
    """
    if safeguard not in SAFEGUARDS:
        raise ValueError(f"safeguard must be one of {SAFEGUARDS}, got {safeguard!r}")
    if initial not in INITIALS:
        raise ValueError(f"initial must be one of {INITIALS}, got {initial!r}")
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    y = samples
    x = pack(*initial_estimate(pseudo_linear_fit(y),          # Steps 1-4
                               printed=initial == "printed"))
    J, g, H = gradient_hessian(x, y, sigma)
    mu = lm_init
    converged, reason = False, ""
    it = 0
    while it < max_iter:
        if sigma**2 * J <= tol:
            converged, reason = True, "cost below tol"
            break
        it += 1
        if safeguard == "none":
            step = _newton_step(g, H)                          # (35)
            decrement = float(g @ step)
            x_new = x - step
            J_new, g_new, H_new = gradient_hessian(x_new, y, sigma)
        else:
            diag = np.diag(np.diag(H))
            for _ in range(30):
                step = _newton_step(g, H + mu * diag)
                x_new = x - step
                J_new = cost(x_new, y, sigma)
                if J_new <= J:
                    break
                mu *= 10.0
            else:
                raise CalibrationFailed("vasconcelos: Levenberg-Marquardt damping found no "
                                        "step that decreases J (33)")
            mu = max(mu / 10.0, 1e-12)
            decrement = float(g @ step)
            J_new, g_new, H_new = gradient_hessian(x_new, y, sigma)
        if not np.isfinite(J_new):
            raise CalibrationFailed(f"vasconcelos: Newton's iterate diverged at iteration {it}")
        small_change = abs(J - J_new) <= rtol * J
        small_decrement = 0.0 <= decrement <= 2.0 * rtol * J
        x, J, g, H = x_new, J_new, g_new, H_new
        if sigma**2 * J <= tol or small_change or small_decrement:
            converged = True
            reason = ("cost below tol" if sigma**2 * J <= tol else
                      "relative change of J" if small_change else "Newton decrement")
            break
    T_hat, h = unpack(x)
    T = np.linalg.inv(T_hat)                                   # Step 8
    if converged:
        message = f"J (33) {J:.6g} after {it} Newton iterations ({reason})"
    else:
        message = f"iteration cap {max_iter} reached, J (33) {J:.6g}"
    return Calibration(T, h, it, converged, message)


# The review's printed initial estimate (40)-(43), four formulas of which are wrong (see the
# comments at each): registered as its own method so every sweep shows what those formulas do
# beside the corrected method. It reproduces the review's Figure 3 finding that Vasconcelos
# "succeeds only for small to moderate" beta.
register("vasconcelos_printed", label="Vasconcelos (review's printed (40)-(43))",
         min_samples=10, family="variant")(partial(fit, initial="printed"))
