"""Time-varying terms: ``y = T m + h + C u(t)``, after a static calibration.

``u(t)`` holds p known regressors (the battery current or throttle, the temperature), ``C``
their 3 x p field per unit. These are Springmann and Cutler's linear time-varying bias terms
(attitude-independent calibration with the currents as regressors, J. Guid. Control Dyn. 2012);
ArduPilot's ``COMPASS_MOT`` is the current case (``COMPASS_MOTCT=2``), PX4's
``CAL_MAG_COMP_TYP`` current or throttle, its thermal calibration the temperature case.

The fit starts from the static calibration ``m = A (y - b)`` of any method (``A`` symmetric,
the safe gauge), then minimises the norm residuals ``|A (y - b - C u)| - 1`` by Gauss-Newton:
``b`` and ``C`` with ``A`` fixed first, then ``A``, ``b`` and ``C`` together. ``u`` is centred
and scaled inside (the bias at the mean ``u`` and ``C`` per standard deviation are well
conditioned however large the mean temperature is), and the result is given back for ``u``
as recorded: ``b`` is the bias at ``u = 0``.

Whether the terms are kept is decided out of sample (:func:`held_out_choice`): the samples are
cut into interleaved time blocks; the static and the time-varying fits are made on the even
blocks and scored on the odd ones, and the other way round; the terms are kept only when they
lower the held-out mean squared norm residual.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from magbench.core.model import CalibrationFailed

#: What a static fit or the time-varying fit may raise on data it cannot fit.
_FIT_ERRORS = (ValueError, np.linalg.LinAlgError, ArithmeticError, CalibrationFailed)

__all__ = ["BLOCKS", "HeldOutChoice", "StaticFit", "TimeVarying", "fit_time_varying",
           "held_out_choice", "norm_residuals"]

#: Interleaved time blocks of the held-out choice (half train, half test, then swapped).
BLOCKS = 10

#: A static method as the fit sees it: samples -> (A, b) of ``m = A (y - b)``.
StaticFit = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class TimeVarying:
    """``m = A (y - b - C u)``: the correction with its time-varying terms."""

    A: np.ndarray
    b: np.ndarray
    C: np.ndarray

    def apply(self, y: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Corrected samples ``A (y - b - C u)``, one row per sample."""
        return (np.asarray(y) - self.b - np.asarray(u) @ self.C.T) @ self.A.T


def norm_residuals(m: np.ndarray) -> np.ndarray:
    """``|m_k| - 1`` of corrected samples."""
    return np.linalg.norm(m, axis=1) - 1.0


#: Entries of a symmetric 3 x 3 matrix as parameters: the diagonal, then (0,1), (0,2), (1,2).
_SYM = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]


def _symmetric(a: np.ndarray) -> np.ndarray:
    A = np.empty((3, 3))
    for value, (i, j) in zip(a, _SYM, strict=True):
        A[i, j] = A[j, i] = value
    return A


def _cost(y: np.ndarray, v: np.ndarray, a: np.ndarray, b: np.ndarray, C: np.ndarray) -> float:
    r = np.linalg.norm((y - b - v @ C.T) @ _symmetric(a).T, axis=1) - 1.0
    return float(r @ r)


def _gauss_newton(y: np.ndarray, v: np.ndarray, A: np.ndarray, b: np.ndarray,
                  C: np.ndarray, iterations: int, *, with_A: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton on ``sum (|A (y - b - C v)| - 1)^2``: ``b`` and ``C``, and the symmetric
    ``A`` too when ``with_A``. A step that does not lower the sum is halved (up to 30 times),
    so a poor start cannot throw the estimate away."""
    K, p = v.shape
    a = np.array([A[i, j] for i, j in _SYM])
    cost = _cost(y, v, a, b, C)
    for _ in range(iterations):
        A = _symmetric(a)
        w = y - b - v @ C.T
        z = w @ A.T
        norm = np.linalg.norm(z, axis=1)
        n = z / norm[:, None]
        g = n @ A                                       # d|z| / dw, row by row
        # d r / d b = -g; d r / d C_ij = -g_i v_j; d r / d A_ij = n_i w_j + n_j w_i (i != j).
        parts = [-g, -(g[:, :, None] * v[:, None, :]).reshape(K, 3 * p)]
        if with_A:
            parts.append(np.column_stack([n[:, i] * w[:, j] + (n[:, j] * w[:, i] if i != j
                                                               else 0.0) for i, j in _SYM]))
        step, *_ = np.linalg.lstsq(np.hstack(parts), -(norm - 1.0), rcond=None)
        for _ in range(30):
            trial_b = b + step[:3]
            trial_C = C + step[3:3 + 3 * p].reshape(3, p)
            trial_a = a + step[3 + 3 * p:] if with_A else a
            trial = _cost(y, v, trial_a, trial_b, trial_C)
            if trial <= cost:
                break
            step = step / 2
        else:
            break                                       # no step lowers the cost: converged
        a, b, C = trial_a, trial_b, trial_C
        converged = cost - trial <= 1e-14 * max(cost, 1e-300)
        cost = trial
        if converged:
            break
    return _symmetric(a), b, C


def _algebraic_start(y: np.ndarray, v: np.ndarray) -> np.ndarray | None:
    """``C`` of the quadric through ``(y, v)``: a start that needs no static fit.

    ``(y - b - C v)^T Q (y - b - C v) = 1`` is a quadric in ``(y, v)`` whose ``y y`` block is
    ``Q``, ``y v`` block ``-2 Q C`` and ``y`` term ``-2 Q b``; the general quadric fitted by
    the smallest singular vector of its monomials (the ``v v`` block left free) gives
    ``C = -Q^-1 (y v block) / 2``. None when its ``Q`` is not definite.
    """
    K, p = v.shape
    ii, jj = np.triu_indices(3)
    kk, ll = np.triu_indices(p)
    design = np.hstack([y[:, ii] * y[:, jj], (y[:, :, None] * v[:, None, :]).reshape(K, 3 * p),
                        v[:, kk] * v[:, ll], y, v, np.ones((K, 1))])
    norms = np.linalg.norm(design, axis=0).clip(1e-300)     # equilibrated columns
    try:
        coef = np.linalg.svd(design / norms, full_matrices=False)[2][-1] / norms
    except np.linalg.LinAlgError:
        return None
    Q = np.zeros((3, 3))
    Q[ii, jj] = coef[:6]
    Q = (Q + Q.T) / 2                     # off-diagonal monomials carry 2 Q_ij
    cross = coef[6:6 + 3 * p].reshape(3, p)
    eig = np.linalg.eigvalsh(Q)
    if not (eig.min() > 0 or eig.max() < 0):
        return None
    return -np.linalg.solve(Q, cross) / 2


def fit_time_varying(y: np.ndarray, u: np.ndarray, static_fit: StaticFit, *,
                     iterations: int = 20) -> TimeVarying:
    """Fit ``y = T m + h + C u`` from a static method (module notes).

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        Magnetometer samples.
    u : ndarray, shape (K, p)
        Regressors at the same times (finite).
    static_fit : callable
        ``static_fit(samples) -> (A, b)``: the static method's correction ``m = A (y - b)``,
        ``A`` symmetric (the safe gauge).
    iterations : int
        Gauss-Newton steps of each stage.

    Returns
    -------
    TimeVarying
        ``A``, ``b`` (the bias at ``u = 0``) and ``C`` (3 x p, field units per unit of u).

    Raises
    ------
    ValueError
        If a regressor does not vary (its term cannot be told from the bias) or shapes differ.
    """
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(y), -1)
    mean, scale = u.mean(axis=0), u.std(axis=0)
    if not (scale > 0).all():
        raise ValueError("a regressor does not vary over the recording, so its term cannot be "
                         "told from the bias")
    v = (u - mean) / scale
    # Two starts, the better kept: no terms (the static fit as it is), and the terms of the
    # algebraic quadric with the static fit redone on the samples they correct (a large
    # disturbance bends the static fit so far that Gauss-Newton from it can stall).
    best, failed = None, None
    for C in (np.zeros((3, u.shape[1])), _algebraic_start(y, v)):
        if C is None or not np.isfinite(C).all():
            continue
        try:
            A, b = static_fit(y - v @ C.T)
        except _FIT_ERRORS as exc:          # this start only: the other may still fit
            failed = exc
            continue
        # A method of fixed scale (T = field_norm I) starts at the data's own field strength.
        A = A / float(np.median(np.linalg.norm((y - b - v @ C.T) @ A.T, axis=1)))
        # First b and C with the static A (a safe start), then every parameter together.
        A, b, C = _gauss_newton(y, v, A, b, C, iterations, with_A=False)
        A, b, C = _gauss_newton(y, v, A, b, C, iterations, with_A=True)
        a = np.array([A[i, j] for i, j in _SYM])
        cost = _cost(y, v, a, b, C) if np.isfinite(A).all() and np.isfinite(C).all() else np.inf
        if best is None or cost < best[0]:
            best = (cost, A, b, C)
    if best is None:
        raise failed if failed is not None else ValueError("no start of the time-varying fit")
    cost, A, b, C = best
    if not np.isfinite(cost):
        raise ValueError("the time-varying fit diverged")
    C_u = C / scale
    return TimeVarying(A, b - C_u @ mean, C_u)


@dataclass(frozen=True)
class HeldOutChoice:
    """The held-out comparison of the static and the time-varying fits.

    ``static_out`` and ``varying_out`` are mean squared norm residuals on the held-out blocks
    (both halves pooled); ``kept`` says whether the terms lowered it; ``fit`` is the
    time-varying fit on every sample (None if it could not be made, ``reason`` says why).
    """

    kept: bool
    static_out: float
    varying_out: float
    fit: TimeVarying | None
    reason: str = ""

    def to_dict(self, regressors: list[str]) -> dict:
        return {"regressors": regressors, "kept": self.kept,
                "held_out_static": self.static_out, "held_out_time_varying": self.varying_out,
                "blocks": BLOCKS, "reason": self.reason or None,
                **({"A": self.fit.A.tolist(), "b": self.fit.b.tolist(),
                    "C": self.fit.C.tolist()} if self.fit is not None else {})}


def held_out_choice(y: np.ndarray, u: np.ndarray, static_fit: StaticFit, *,
                    blocks: int = BLOCKS) -> HeldOutChoice:
    """Fit the time-varying terms and keep them only if they lower the held-out error.

    The samples (in time order) are cut into ``blocks`` consecutive blocks; even blocks train
    and odd ones test, then the reverse. A fit that fails (a regressor constant on a half, a
    static fit that raises) is not kept, with the reason.
    """
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(y), -1)
    block = np.minimum(np.arange(len(y)) * blocks // max(len(y), 1), blocks - 1)
    even = block % 2 == 0
    static_sq, varying_sq = [], []
    try:
        for train in (even, ~even):
            A, b = static_fit(y[train])
            static_sq.append(norm_residuals((y[~train] - b) @ A.T) ** 2)
            tv = fit_time_varying(y[train], u[train], static_fit)
            varying_sq.append(norm_residuals(tv.apply(y[~train], u[~train])) ** 2)
        fit = fit_time_varying(y, u, static_fit)
    except _FIT_ERRORS as exc:
        return HeldOutChoice(False, np.nan, np.nan, None, f"not fitted: {exc}")
    s_out = float(np.mean(np.concatenate(static_sq)))
    v_out = float(np.mean(np.concatenate(varying_sq)))
    kept = bool(np.isfinite(v_out) and v_out < s_out)
    return HeldOutChoice(kept, s_out, v_out, fit,
                         "" if kept else "the terms did not lower the held-out error")
