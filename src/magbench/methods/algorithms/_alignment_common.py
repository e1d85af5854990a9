"""Shared pieces of the alignment methods: accelerometer input, static rows, the dip constraint.

In a homogeneous field, at rest, the accelerometer measures the specific force ``a = Q^T g_w``
(gravity reversed, in the IMU's axes, ``Q`` the attitude) and the calibrated magnetometer the
field direction ``m = R^T Q^T m_w`` in its own axes, ``R`` the rotation from the magnetometer to
the IMU. Whatever the attitude,

    a_k^T R m_k / (|a_k| |m_k|) = cos(angle between g_w and m_w) = c,        (dip constraint)

the invariance of the dip angle: Liu et al.'s "constant intersection angle" (Sensors,
2014; confirmed from the abstract only, its equations unread, so no numbers are cited). With
``X = R / s`` it is linear in the nine entries of ``X``: the solution is a null vector of the
centred products ``a_k m_k^T``, and ``R`` the rotation nearest ``X``. It determines all of
``R`` once the attitudes differ in more than one axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.core.rotations import rotation_exp
from magbench.methods.algorithms.magical import iterate

__all__ = ["StaticFit", "check_acceleration", "check_spread", "dip_rotation", "magical_at_rest",
           "nearest_rotation", "refine_dip_rotation", "static_rows", "symmetric_directions",
           "unit_rows"]


def check_acceleration(samples: np.ndarray, acceleration: object) -> np.ndarray:
    """The one checker of accelerometer input: ``(K, 3)`` finite, beside the K samples.

    Raises
    ------
    ValueError
        Missing, wrong shape or length, non-finite values, or all-zero rows.
    """
    if acceleration is None:
        raise ValueError("alignment methods need acceleration (K, 3), the accelerometer's "
                         "samples in the IMU's axes")
    try:
        a = np.array(acceleration, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"acceleration must be numeric: {exc}") from None
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] != samples.shape[0]:
        raise ValueError(f"acceleration must have shape ({samples.shape[0]}, 3), one row per "
                         f"magnetometer sample, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("acceleration contains NaN or infinite values")
    if not np.all(np.einsum("ij,ij->i", a, a) > 0):
        raise ValueError("acceleration has all-zero rows; a specific force is expected")
    return a


def unit_rows(x: np.ndarray) -> np.ndarray:
    """Rows of ``x`` scaled to unit norm."""
    return x / np.sqrt(np.einsum("ij,ij->i", x, x))[:, None]


def static_rows(a: np.ndarray, tol: float, window: int = 5) -> np.ndarray:
    """Indices of the rows at rest: the specific-force norm within ``tol`` (relative) of the
    median, and the row inside a run of ``window`` rows whose every component is steady
    (standard deviation below ``tol`` times the median norm). A moving device can pass the
    first test by chance; the second asks that gravity alone is seen for a while."""
    if not tol > 0:
        raise ValueError(f"static_tol must be > 0, got {tol}")
    norm = np.sqrt(np.einsum("ij,ij->i", a, a))
    scale = float(np.median(norm))
    steady = np.abs(norm / scale - 1.0) <= tol
    if a.shape[0] >= window > 1:
        view = np.lib.stride_tricks.sliding_window_view(a, window, axis=0)   # (K-w+1, 3, w)
        calm = np.sqrt(np.max(np.var(view, axis=2), axis=1)) <= tol * scale
        # A row is still when some calm window covers it.
        steady &= np.convolve(calm.astype(float), np.ones(window))[:a.shape[0]] > 0
    return np.flatnonzero(steady)


def check_spread(up: np.ndarray, min_spread: float) -> None:
    """Refuse static gravity directions that turn about too few axes to fix a rotation.

    The middle eigenvalue of the directions' covariance must reach ``min_spread`` (0.02:
    about 8 degrees of spread in a second axis); one pose, or poses about one axis, leave a
    rotation that the dip constraint cannot see.

    Raises
    ------
    CalibrationFailed
        Naming the spread found.
    """
    if up.shape[0] < 4:
        raise CalibrationFailed(f"alignment: {up.shape[0]} rows at rest are too few (4 "
                                "needed); hold the device still in several orientations")
    ev = np.linalg.eigvalsh(np.cov(up.T))
    if ev[1] < min_spread:
        raise CalibrationFailed(f"alignment: the {up.shape[0]} rows at rest see gravity from "
                                f"too few directions (spread eigenvalues {ev[1]:.3g}, "
                                f"{ev[2]:.3g}; {min_spread:g} needed); too alike to fix the "
                                "rotation: rest the device in more orientations")


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The proper rotation nearest ``M`` in the Frobenius norm (SVD, det forced to +1)."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return (U * np.array([1.0, 1.0, d])) @ Vt


def symmetric_directions(y: np.ndarray, T: np.ndarray, h: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """The symmetric-gauge ``T_s = (T T^T)^(1/2)`` and the unit field directions
    ``A (y - h)``, ``A = T_s^-1``, that an alignment is defined against."""
    T_s = Calibration(T, h).safe().T
    return T_s, unit_rows(np.linalg.solve(T_s, (y - h).T).T)


def dip_rotation(m: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, float]:
    """``R`` and ``c`` of the dip constraint by linear least squares and projection.

    Parameters
    ----------
    m, a : ndarray, shape (N, 3)
        Unit field directions (magnetometer axes) and unit specific forces (IMU axes).

    Returns
    -------
    R : ndarray, shape (3, 3)
        The rotation nearest the null vector ``X`` of the centred products.
    c : float
        Mean of ``a_k^T R m_k``.

    Raises
    ------
    CalibrationFailed
        If the attitudes are too alike for the null vector to be unique.
    """
    Z = np.einsum("ki,kj->kij", a, m).reshape(-1, 9)
    _, s, Vt = np.linalg.svd(Z - Z.mean(axis=0), full_matrices=False)
    if s.size < 9 or s[-2] <= 1e-8 * s[0]:
        raise CalibrationFailed("alignment: the static attitudes are too alike to fix the "
                                "rotation (turn the device about more axes between rests)")
    X = Vt[-1].reshape(3, 3)
    R = nearest_rotation(X if np.linalg.det(X) > 0 else -X)
    return R, float(np.mean(np.einsum("ki,ki->k", a, m @ R.T)))


def refine_dip_rotation(m: np.ndarray, a: np.ndarray, R: np.ndarray, max_iter: int = 20,
                        tol: float = 1e-12) -> tuple[np.ndarray, float, int]:
    """Gauss-Newton on ``sum_k (a_k^T R m_k - c)^2`` over a rotation ``R`` and ``c``.

    ``R <- exp([d]x) R``: the residual's derivative in ``d`` is ``(R m_k) x a_k``, so each step
    is a 4-unknown linear least squares. Returns ``R``, ``c`` and the iterations used.
    """
    c = float(np.mean(np.einsum("ki,ki->k", a, m @ R.T)))
    for it in range(1, max_iter + 1):
        u = m @ R.T
        r = np.einsum("ki,ki->k", a, u) - c
        J = np.column_stack([np.cross(u, a), -np.ones(len(a))])
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        R = rotation_exp(step[:3]) @ R
        c += step[3]
        if np.max(np.abs(step)) <= tol:
            return R, c, it
    return R, c, max_iter



@dataclass(frozen=True)
class StaticFit:
    """MAG.I.C.AL.'s magnetometer fit and the rests an alignment is solved on.

    ``T`` (symmetric gauge), ``h``, ``n_iter`` and ``converged`` of the fit; ``rows`` the
    static rows; ``m`` the unit field directions and ``a`` the specific force at them.
    """

    T: np.ndarray
    h: np.ndarray
    n_iter: int
    converged: bool
    rows: np.ndarray
    m: np.ndarray
    a: np.ndarray


def magical_at_rest(samples: np.ndarray, acceleration: object, static_tol: float,
                    min_spread: float, max_iter: int, tol: float, rtol: float) -> StaticFit:
    """The first step of both MAG.I.C.AL.-based alignments: check the accelerometer, fit the
    magnetometer by Algorithm 7 (eqs. 58-65), keep the static rows (:func:`static_rows`) and
    refuse rests too alike (:func:`check_spread`)."""
    a = check_acceleration(samples, acceleration)
    T, h, n_iter, converged, _ = iterate(np.ascontiguousarray(samples, dtype=np.float64),
                                         int(max_iter), float(tol), float(rtol), np.inf)
    T_s, m = symmetric_directions(samples, T, h)
    rows = static_rows(a, static_tol)
    check_spread(unit_rows(a[rows]), min_spread)
    return StaticFit(T_s, h, n_iter, converged, rows, m[rows], a[rows])
