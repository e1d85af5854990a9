"""The one result type and the one input checker.

The measurement model throughout is eq. (2) of the review,

    y = T m + h + eps,   ||m|| = 1,

with samples stored as a ``(K, 3)`` array, one measurement per row. Every method returns a
:class:`Calibration` in that convention; the calibrated field is ``T^-1 (y - h)`` (eq. 82).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Calibration", "CalibrationFailed", "as_samples"]


class CalibrationFailed(RuntimeError):
    """A method could not produce an estimate from this dataset.

    Raised for the known weak points of a method (a failed Cholesky factorisation in Wu and Shi's
    initial estimate, a non-positive-definite matrix in TWOSTEP, a singular Hessian, ...). It is a
    property of the data and the method, not of the caller's input, which is why it is not a
    ``ValueError``. The benchmark runner turns it into a row with ``ok=False`` and this message.
    """


@dataclass(frozen=True)
class Calibration:
    """Calibration parameters of ``y = T m + h + eps`` (review eq. 2).

    Attributes
    ----------
    T : ndarray, shape (3, 3)
        Combined scale-factor, cross-coupling and soft-iron matrix.
    h : ndarray, shape (3,)
        Combined bias and hard-iron offset.
    n_iter : int
        Iterations the method used (0 for closed-form methods).
    converged : bool
        Whether the method's own stopping rule was met before its iteration cap.
    message : str
        Human-readable note on how the method ended.
    gyro_bias : ndarray of shape (3,) or None
        Gyroscope bias in rad/s for the methods that estimate one, otherwise None.
    """

    T: np.ndarray
    h: np.ndarray
    n_iter: int = 0
    converged: bool = True
    message: str = ""
    gyro_bias: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        T = np.array(self.T, dtype=float)
        h = np.array(self.h, dtype=float).reshape(-1)
        if T.shape != (3, 3) or h.shape != (3,):
            raise ValueError(f"Calibration needs T of shape (3, 3) and h of shape (3,), got "
                             f"{T.shape} and {h.shape}")
        T.setflags(write=False)
        h.setflags(write=False)
        object.__setattr__(self, "T", T)
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "n_iter", int(self.n_iter))
        object.__setattr__(self, "converged", bool(self.converged))
        if self.gyro_bias is not None:
            object.__setattr__(self, "gyro_bias", np.array(self.gyro_bias, dtype=float))

    @property
    def is_finite(self) -> bool:
        """True when T and h are finite and T is numerically invertible."""
        if not (np.all(np.isfinite(self.T)) and np.all(np.isfinite(self.h))):
            return False
        return bool(np.linalg.cond(self.T) < 1e12)

    def apply(self, samples: np.ndarray) -> np.ndarray:
        """Calibrated field ``T^-1 (y - h)`` (review eq. 82) for ``(K, 3)`` samples."""
        y = as_samples(samples, min_samples=1)
        # Solve instead of inverting: T^-1 (y - h) for all rows at once.
        return np.linalg.solve(self.T, (y - self.h).T).T

    def correction(self) -> tuple[np.ndarray, np.ndarray]:
        """The firmware form ``m = A y + b`` with ``A = T^-1`` and ``b = -T^-1 h``."""
        A = np.linalg.inv(self.T)
        return A, -A @ self.h


def as_samples(samples: object, *, min_samples: int = 1, name: str = "samples") -> np.ndarray:
    """Check and convert magnetometer samples to a float ``(K, 3)`` array.

    This is the single place where input is validated; every public entry point calls it.

    Parameters
    ----------
    samples : array_like, shape (K, 3)
        One three-axis measurement per row.
    min_samples : int
        The smallest K the caller can work with.
    name : str
        What to call the input in error messages.

    Returns
    -------
    ndarray, shape (K, 3), dtype float64
        A new array (the caller's data is never modified).

    Raises
    ------
    ValueError
        If the input is not numeric, not ``(K, 3)``, has fewer than ``min_samples`` rows, or
        contains NaN or infinite values.
    """
    try:
        y = np.array(samples, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric array-like of shape (K, 3): {exc}") from None
    if y.ndim != 2 or y.shape[1] != 3:
        raise ValueError(f"{name} must have shape (K, 3) with one measurement per row, "
                         f"got shape {y.shape}")
    if y.shape[0] < min_samples:
        raise ValueError(f"{name} has K={y.shape[0]} rows; at least {min_samples} are needed")
    bad = ~np.isfinite(y).all(axis=1)
    if bad.any():
        rows = np.flatnonzero(bad)
        shown = ", ".join(str(r) for r in rows[:5]) + (", ..." if rows.size > 5 else "")
        raise ValueError(f"{name} contains NaN or infinite values in {rows.size} row(s) "
                         f"(rows {shown}); drop or repair them before calibrating")
    return y
