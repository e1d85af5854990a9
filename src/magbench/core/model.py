"""The one result type and the one input checker.

The measurement model throughout is eq. (2) of the review,

    y = T m + h + eps,   ||m|| = 1,

with samples stored as a ``(K, 3)`` array, one measurement per row. Every method returns a
:class:`Calibration` in that convention; the calibrated field is ``T^-1 (y - h)`` (eq. 82).
What is written for others to use (:meth:`Calibration.correction`, :meth:`Calibration.safe`,
the files of :mod:`magbench.core.exports`) is in the one gauge of :mod:`magbench.core.gauge`:
``m = A (y - b)`` with ``A`` symmetric positive definite, the rotation and any mirror image
that ``T`` carries removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from magbench.core.gauge import HEADING_TRUE, SYMMETRIC, check_rotation, safe_gauge, symmetric_T

__all__ = ["Calibration", "CalibrationFailed", "as_samples", "check_magnitude"]


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
    alignment : ndarray of shape (3, 3) or None
        The rotation ``R`` (det +1) from the magnetometer's symmetric gauge to the inertial
        sensors' axes, for the methods that inertial data let fix it: the field in IMU axes is
        ``R A (y - h)`` with ``A = (T T^T)^(-1/2)``. None when the rotation is unknown.
    """

    T: np.ndarray
    h: np.ndarray
    n_iter: int = 0
    converged: bool = True
    message: str = ""
    gyro_bias: np.ndarray | None = field(default=None)
    alignment: np.ndarray | None = field(default=None)

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
        if self.alignment is not None:
            R = check_rotation(self.alignment, "alignment")
            R.setflags(write=False)
            object.__setattr__(self, "alignment", R)

    @property
    def gauge(self) -> str:
        """``"heading-true"`` when an alignment to the inertial axes is known, else
        ``"symmetric"`` (the rotation is unknown and removed)."""
        return SYMMETRIC if self.alignment is None else HEADING_TRUE

    @property
    def is_finite(self) -> bool:
        """True when T and h are finite and T is numerically invertible."""
        (a, b, c), (d, e, f), (g, p, q) = self.T.tolist()
        if not all(math.isfinite(v) for v in (a, b, c, d, e, f, g, p, q, *self.h.tolist())):
            return False
        # cond(T) = s_max / s_min <= ||T||_F^3 / |det T|, since s_min = |det T| / (s_max s_mid)
        # >= |det T| / s_max^2 and s_max <= ||T||_F: a bound from scalar arithmetic that
        # settles every well-conditioned T (cond below ~1e5) without the SVD of np.linalg.cond.
        # Its margin (1e11, not 1e12) covers the rounding of det near the threshold.
        det = a * (e * q - f * p) - b * (d * q - f * g) + c * (d * p - e * g)
        frob = math.sqrt(a * a + b * b + c * c + d * d + e * e + f * f + g * g + p * p + q * q)
        if frob ** 3 < 1e11 * abs(det):
            return True
        return bool(np.linalg.cond(self.T) < 1e12)

    def apply(self, samples: np.ndarray) -> np.ndarray:
        """Calibrated field ``T^-1 (y - h)`` (review eq. 82).

        Parameters
        ----------
        samples : array_like, shape (K, 3) or (3,)
            Samples, one per row, or a single sample.

        Returns
        -------
        ndarray, shape (K, 3) or (3,)
            The calibrated field, the same shape as the input.
        """
        single = np.ndim(samples) == 1
        y = as_samples(np.reshape(samples, (1, -1)) if single else samples, min_samples=1)
        # Solve instead of inverting: T^-1 (y - h) for all rows at once.
        m = np.linalg.solve(self.T, (y - self.h).T).T
        return m[0] if single else m

    def correction(self) -> tuple[np.ndarray, np.ndarray]:
        """The firmware form ``m = A (y - b)`` in the calibration's gauge
        (:mod:`magbench.core.gauge`).

        Returns
        -------
        A : ndarray, shape (3, 3)
            ``(T T^T)^(-1/2)``, symmetric positive definite, in the symmetric gauge; ``R (T
            T^T)^(-1/2)`` with the alignment ``R`` in the heading-true gauge, so that ``m`` is
            the field in the inertial sensors' axes.
        b : ndarray, shape (3,)
            ``h``.

        ``||A (y - b)|| = ||T^-1 (y - h)||`` for every sample; in the symmetric gauge the
        rotation (and mirror image) that the model cannot determine is removed.

        Raises
        ------
        CalibrationFailed
            If ``T`` is not finite or is singular: no correction is ever written for it.
        """
        try:
            gauge = safe_gauge(self.T, self.h, self.alignment)
        except ValueError as exc:
            raise CalibrationFailed(str(exc)) from None
        return gauge.A, gauge.b

    def safe(self) -> Calibration:
        """The same calibration in the safe gauge: ``T' = (T T^T)^(1/2)`` (symmetric), ``h``.

        ``safe().apply(y)`` equals ``A (y - b)`` of the symmetric gauge; an alignment is kept
        (it is defined relative to that gauge), so :meth:`correction` is unchanged.

        Raises
        ------
        CalibrationFailed
            If ``T`` is not finite or is singular.
        """
        try:
            T = symmetric_T(self.T)
        except ValueError as exc:
            raise CalibrationFailed(str(exc)) from None
        return Calibration(T, self.h, self.n_iter, self.converged, self.message,
                           self.gyro_bias, self.alignment)

    def to_dict(self) -> dict:
        """A JSON-ready dict (plain lists and numbers); :meth:`from_dict` reads it back exactly."""
        return {"T": self.T.tolist(), "h": self.h.tolist(), "n_iter": self.n_iter,
                "converged": self.converged, "message": self.message,
                "gyro_bias": None if self.gyro_bias is None else self.gyro_bias.tolist(),
                "alignment": None if self.alignment is None else self.alignment.tolist()}

    @classmethod
    def from_dict(cls, data: dict) -> Calibration:
        """The :class:`Calibration` of a :meth:`to_dict` dict (``gyro_bias``, ``alignment`` and
        the bookkeeping keys are optional).

        Raises
        ------
        ValueError
            If ``T`` or ``h`` is missing or has the wrong shape.
        """
        missing = [k for k in ("T", "h") if k not in data]
        if missing:
            raise ValueError(f"calibration dict lacks {', '.join(missing)}; expected keys T "
                             "(3x3), h (3) and optionally n_iter, converged, message, gyro_bias")
        return cls(np.array(data["T"], dtype=float), np.array(data["h"], dtype=float),
                   int(data.get("n_iter", 0)), bool(data.get("converged", True)),
                   str(data.get("message", "")), data.get("gyro_bias"), data.get("alignment"))


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
    # max and min propagate NaN and reach +-inf, so finite extremes prove every value finite
    # (one pass each instead of a (K, 3) mask); the mask is built only to name bad rows.
    top, bottom = (float(np.max(y)), float(np.min(y))) if y.size else (0.0, 0.0)
    if not (math.isfinite(top) and math.isfinite(bottom)):
        bad = ~np.isfinite(y).all(axis=1)
        rows = np.flatnonzero(bad)
        shown = ", ".join(str(r) for r in rows[:5]) + (", ..." if rows.size > 5 else "")
        raise ValueError(f"{name} contains NaN or infinite values in {rows.size} row(s) "
                         f"(rows {shown}); drop or repair them before calibrating")
    check_magnitude(y, name, top=max(top, -bottom))
    return y


#: The largest absolute sample value must lie in this range: its square (and a sum of squares
#: over many samples) then stays a finite, normal float64, which every fit needs.
MAGNITUDE_RANGE = (1e-150, 1e150)


def check_magnitude(y: np.ndarray, name: str = "samples", *, top: float | None = None) -> None:
    """Refuse samples whose magnitude no fit can square in float64 (one clear line).

    All-zero samples pass here; :func:`magbench.methods.api.unit_scale` names them.

    Parameters
    ----------
    y : ndarray
        The samples.
    name : str
        What to call them in the error message.
    top : float, optional
        The largest absolute value of ``y``, if the caller has it already (:func:`as_samples`).

    Raises
    ------
    ValueError
        If the largest absolute value is above 1e150 or below 1e-150 (but not zero).
    """
    low, high = MAGNITUDE_RANGE
    if top is None:
        # max and -min instead of abs: no temporary copy of a long recording.
        top = max(float(np.max(y)), -float(np.min(y))) if y.size else 0.0
    if top > high or 0.0 < top < low:
        raise ValueError(f"{name} reach a largest magnitude of {top:.3g}, outside the range "
                         f"magbench can calibrate ({low:g} to {high:g}, where squares stay "
                         "finite floats); rescale the values first (any unit works: T and h "
                         "come out in the unit of the samples)")
