"""Shared pieces of the gyro-aided methods (SAR, MAGYC): input checks, kinematics, solvers.

Every gyro-aided method rests on the kinematics of a field that is constant in world axes and
seen from a rotating body: ``dm/dt = -w x m`` (Troni and Whitcomb 2019, eq. 1). With the
magnetometer model ``y = T m + h`` and ``C`` proportional to ``T^-1`` this becomes, for the
samples themselves,

    C dy/dt + (g - d) x (C y - b) = 0,       b = C h,                         (MAGYC residual)

with ``g`` the gyro reading and ``d`` its bias; SAR is the case ``C = I``, ``d = 0``.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.core.rotations import cross_rows, skew

__all__ = ["check_gyro_inputs", "midpoint_differences", "skew"]


def check_gyro_inputs(samples: np.ndarray, angular_rate: object,
                      time: object) -> tuple[np.ndarray, np.ndarray]:
    """The one checker of gyro inputs: ``(K, 3)`` rates in rad/s and ``(K,)`` times in s.

    Raises
    ------
    ValueError
        Missing input, wrong shape, length different from the K magnetometer samples,
        NaN or infinite values, or times that do not strictly increase.
    """
    K = samples.shape[0]
    if angular_rate is None or time is None:
        raise ValueError("gyro-aided methods need angular_rate (K, 3) in rad/s and time (K,) "
                         "in seconds")
    try:
        w = np.array(angular_rate, dtype=float)
        t = np.array(time, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"angular_rate and time must be numeric: {exc}") from None
    if w.ndim != 2 or w.shape[1] != 3:
        raise ValueError(f"angular_rate must have shape (K, 3) in rad/s, one row per sample, "
                         f"got shape {w.shape}")
    if t.ndim != 1:
        raise ValueError(f"time must have shape (K,) in seconds, got shape {t.shape}")
    if w.shape[0] != K or t.shape[0] != K:
        raise ValueError(f"samples, angular_rate and time must have the same length, got "
                         f"{K}, {w.shape[0]} and {t.shape[0]}")
    if not (np.isfinite(w).all() and np.isfinite(t).all()):
        raise ValueError("angular_rate or time contains NaN or infinite values")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        raise ValueError(f"time must be strictly increasing; time[{k + 1}] = {t[k + 1]!r} "
                         f"follows time[{k}] = {t[k]!r}")
    return w, t


def midpoint_differences(y: np.ndarray, w: np.ndarray,
                         t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Field, its time derivative and the rate at the midpoints of successive samples.

    ``(y_{k+1} - y_k) / (t_{k+1} - t_k)`` is a second-order estimate of ``dy/dt`` at the
    midpoint, where the averages of ``y`` and ``g`` are second-order too; pairing them this way
    avoids the half-sample misalignment of a one-sided difference.

    Returns
    -------
    y_mid, y_dot, w_mid : ndarray, shape (K - 1, 3)
    """
    dt = np.diff(t)[:, None]
    return 0.5 * (y[1:] + y[:-1]), np.diff(y, axis=0) / dt, 0.5 * (w[1:] + w[:-1])


# --- MAGYC parametrisation -----------------------------------------------------------------

def unit_volume_cholesky(l: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Lower-triangular ``L`` with ``det L = 1`` from 5 parameters, and its 5 derivatives.

    ``L = [[e^l0, 0, 0], [l1, e^l2, 0], [l3, l4, e^-(l0 + l2)]]``; ``C = L L^T`` is then
    symmetric positive definite with unit determinant, the volume constraint of MAGYC that
    removes the scale the residual cannot see.
    """
    e0, e2, e5 = np.exp(l[0]), np.exp(l[2]), np.exp(-(l[0] + l[2]))
    L = np.array([[e0, 0.0, 0.0], [l[1], e2, 0.0], [l[3], l[4], e5]])
    dL = [np.zeros((3, 3)) for _ in range(5)]
    dL[0][0, 0], dL[0][2, 2] = e0, -e5
    dL[1][1, 0] = 1.0
    dL[2][1, 1], dL[2][2, 2] = e2, -e5
    dL[3][2, 0] = 1.0
    dL[4][2, 1] = 1.0
    return L, dL


def cholesky_parameters(C: np.ndarray) -> np.ndarray:
    """The 5 parameters of :func:`unit_volume_cholesky` for a symmetric positive definite C
    (rescaled to unit determinant first)."""
    C = C / np.linalg.det(C) ** (1.0 / 3.0)
    L = np.linalg.cholesky(C)
    return np.array([np.log(L[0, 0]), L[1, 0], np.log(L[1, 1]), L[2, 0], L[2, 1]])


def magyc_residual(x: np.ndarray, y: np.ndarray, y_dot: np.ndarray, g: np.ndarray,
                   with_gyro_bias: bool) -> tuple[np.ndarray, np.ndarray]:
    """Stacked MAGYC residuals ``C y_dot + (g - d) x (C y - b)`` and their Jacobian.

    Parameters
    ----------
    x : ndarray, shape (8,) or (11,)
        5 Cholesky parameters of ``C``, then ``b`` (3), then ``d`` (3) if ``with_gyro_bias``.
    y, y_dot, g : ndarray, shape (N, 3)
        Field, field derivative and gyro reading at the residual's instants.

    Returns
    -------
    r : ndarray, shape (3N,)
    J : ndarray, shape (3N, len(x))
    """
    L, dL = unit_volume_cholesky(x[:5])
    C = L @ L.T
    b = x[5:8]
    d = x[8:11] if with_gyro_bias else np.zeros(3)
    u = g - d
    v = y @ C.T - b
    r = y_dot @ C.T + cross_rows(u, v)
    N = y.shape[0]
    J = np.empty((N, 3, x.size))
    for p in range(5):
        dC = dL[p] @ L.T + L @ dL[p].T
        J[:, :, p] = y_dot @ dC.T + cross_rows(u, y @ dC.T)
    J[:, :, 5:8] = -skew(u)                      # d/db of u x (C y - b)
    if with_gyro_bias:
        J[:, :, 8:11] = skew(v)                  # d/dd of -d x v = v x d
    return r.reshape(-1), J.reshape(3 * N, x.size)


def levenberg_marquardt(fun, x0: np.ndarray, *, max_iter: int, xtol: float,
                        ftol: float) -> tuple[np.ndarray, int, bool, float]:
    """Small dense Levenberg-Marquardt (Nielsen's damping update) for ``min ||r(x)||^2``.

    ``fun(x) -> (r, J)``. Stops when the step is below ``xtol (||x|| + xtol)`` or the cost
    falls by less than ``ftol`` of itself. Returns ``x, iterations, converged, cost``.
    """
    x = np.array(x0, dtype=float)
    r, J = fun(x)
    cost = float(r @ r)
    A, grad = J.T @ J, J.T @ r
    mu, nu = 1e-3 * float(np.max(np.diag(A))), 2.0
    for it in range(1, max_iter + 1):
        step = np.linalg.solve(A + mu * np.eye(x.size), -grad)
        x_new = x + step
        r_new, J_new = fun(x_new)
        cost_new = float(r_new @ r_new)
        predicted = float(step @ (mu * step - grad))
        rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
        if rho > 0:
            small_step = np.linalg.norm(step) <= xtol * (np.linalg.norm(x) + xtol)
            small_gain = cost - cost_new <= ftol * cost
            x, r, J, cost = x_new, r_new, J_new, cost_new
            A, grad = J.T @ J, J.T @ r
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small_step or small_gain or cost == 0.0:
                return x, it, True, cost
        else:
            mu *= nu
            nu *= 2.0
            if np.linalg.norm(step) <= xtol * (np.linalg.norm(x) + xtol):
                return x, it, True, cost
    return x, max_iter, False, cost


def magyc_calibration(x: np.ndarray, y: np.ndarray, with_gyro_bias: bool, n_iter: int,
                      converged: bool, message: str) -> Calibration:
    """Turn MAGYC parameters into ``T``, ``h`` (and ``d``) of ``y = T m + h``.

    ``h = C^-1 b``. The residual is blind to the scale of ``C``, so ``T = s C^-1`` with ``s``
    the RMS of ``||C (y_k - h)||`` over the samples: the calibrated field ``T^-1 (y - h)``
    then has unit RMS norm, the review's convention.
    """
    L, _ = unit_volume_cholesky(x[:5])
    C = L @ L.T
    h = np.linalg.solve(C, x[5:8])
    s = float(np.sqrt(np.mean(np.sum(((y - h) @ C.T) ** 2, axis=1))))
    return Calibration(s * np.linalg.inv(C), h, n_iter, converged, message,
                       gyro_bias=x[8:11].copy() if with_gyro_bias else None)


def magyc_linear(y: np.ndarray, y_dot: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Closed-form MAGYC least squares (no gyro bias): the 8 parameters of ``C`` and ``b``.

    The residual ``C y_dot + g x (C y) - g x b`` is linear in the 6 entries ``c`` of the
    symmetric ``C`` and in ``b``. ``b`` is eliminated by least squares and ``c`` minimises the
    remaining quadratic form under ``||c|| = 1`` (its smallest eigenvector).

    Raises
    ------
    CalibrationFailed
        If the motion does not determine ``C`` (two near-zero eigenvalues: too little rotation
        about too few axes) or the solution is not positive definite.
    """
    N = y.shape[0]
    basis = []
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):
        E = np.zeros((3, 3))
        E[i, j] = E[j, i] = 1.0
        basis.append(E)
    Mc = np.stack([y_dot @ E.T + np.cross(g, y @ E.T) for E in basis], axis=-1)
    Mb = -skew(g)
    Mc, Mb = Mc.reshape(3 * N, 6), Mb.reshape(3 * N, 3)
    # Normalise columns so the eigenproblem is not dominated by units.
    Q, _ = np.linalg.qr(Mb)
    Mc_perp = Mc - Q @ (Q.T @ Mc)
    _, sv, Vt = np.linalg.svd(Mc_perp, full_matrices=False)
    if sv[4] <= 1e-9 * sv[0]:
        raise CalibrationFailed(f"MAGYC-LS: the motion does not determine the soft iron "
                                f"(singular values {sv[4]:.3g}, {sv[5]:.3g} of {sv[0]:.3g}); "
                                "rotate about more axes")
    c = Vt[-1]
    C = sum(ci * E for ci, E in zip(c, basis, strict=True))
    if np.trace(C) < 0:
        C, c = -C, -c
    if np.linalg.eigvalsh(C)[0] <= 0:
        raise CalibrationFailed("MAGYC-LS: the least-squares soft-iron matrix is not positive "
                                "definite")
    b = np.linalg.lstsq(Mb, -(Mc @ c), rcond=None)[0]
    scale = np.linalg.det(C) ** (1.0 / 3.0)
    return np.concatenate([cholesky_parameters(C), b / scale])


def window_medians(arrays: tuple[np.ndarray, ...], window: int) -> tuple[np.ndarray, ...]:
    """Per-axis medians of consecutive, non-overlapping windows of ``window`` rows (a trailing
    partial window is dropped), for each array."""
    n = arrays[0].shape[0] // window
    if n < 1:
        raise ValueError(f"window={window} is longer than the {arrays[0].shape[0]} sample "
                         "intervals")
    return tuple(np.median(a[: n * window].reshape(n, window, 3), axis=1) for a in arrays)
