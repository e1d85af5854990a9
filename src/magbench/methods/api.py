"""The one way the harness calls a method: :func:`calibrate`.

A method is a plain function ``fit(samples, **options) -> Calibration`` registered under a
name with :func:`register`. :func:`calibrate` is the only way the harness calls it: it validates
the input once, brings the data to unit scale by an exact power of two, calls the method, maps
numerical failures to :class:`~magbench.core.model.CalibrationFailed` and checks the answer:
a fit that claims convergence while fitting the data worse than no fit at all (J_r of eq. 81
above the trivial estimate's) is returned with ``converged=False`` and the reason.

What it hands back is in the safe gauge of :mod:`magbench.core.gauge` (``T`` symmetric
positive definite, never rotated or mirrored: ``T = (T_m T_m^T)^(1/2)`` of the method's own
``T_m``, the same ``h``), so a user who applies ``T^-1 (y - h)`` gets the field the written
files give. ``raw=True`` returns the method's own ``T_m`` instead: the benchmark engine and
the studies ask for it, because the review's metric (eq. 74) aligns ``T_m`` itself and the
sweeps record it, and ``calibrate``'s report names the rotation and mirror image removed.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence

import numpy as np

from magbench.core.gauge import symmetric_T
from magbench.core.metrics import real_cost, sample_mean, trivial_estimate
from magbench.core.model import Calibration, CalibrationFailed, as_samples
from magbench.methods.registry import get_method

__all__ = ["CheckedSamples", "calibrate", "unit_scale"]

def unit_scale(y: np.ndarray) -> float:
    """Power of two nearest the RMS sample norm: what :func:`calibrate` divides samples by.

    Public so that code calling a method's internals directly (e.g. the Wu-Shi study's
    ``refine``) normalises exactly as :func:`calibrate` does.

    Dividing by a power of two is exact in floating point, so data already near unit norm (the
    review's setting) pass through bit for bit, and data in any unit (counts, nT, gauss) reach
    the methods at the scale their tolerances and initial guesses assume.
    """
    flat = np.ravel(y)
    rms = math.sqrt(float(flat @ flat) / y.shape[0]) if y.shape[0] else 0.0
    if not rms > 0.0 or not math.isfinite(rms):
        raise ValueError("samples are all zero (or overflow); a magnetic field of non-zero "
                         "magnitude is expected")
    return 2.0 ** round(math.log2(rms))


def _distinct_rows(y: np.ndarray, enough: int | None = None) -> int:
    """Number of distinct rows of ``y``, as ``np.unique(y, axis=0).shape[0]`` counts them.

    Sorting the rows lexicographically and comparing neighbours by value is the same count
    (0.0 equals -0.0 in both) at a tenth of the cost of ``np.unique(axis=0)``, which every
    call paid (0.19 ms at K = 300, a third of a fast method's time).

    With ``enough``, the count may stop once ``enough`` distinct rows are certain: the result
    is then the number of distinct first coordinates, a lower bound that is at least
    ``enough``. That is all the geometry check asks, and it spares data with repeated rows
    (the bootstrap's resamples) the lexicographic sort: 0.3 instead of 2.4 ms at K = 10 000.
    """
    if y.shape[0] == 0:
        return 0
    first = np.sort(y[:, 0])
    firsts = 1 + int(np.count_nonzero(first[1:] != first[:-1]))
    if firsts == y.shape[0] or (enough is not None and firsts >= enough):
        return firsts  # measured data: the first coordinates alone tell enough rows apart
    rows = y[np.lexsort(y.T[::-1])]
    return 1 + int(np.count_nonzero(np.any(rows[1:] != rows[:-1], axis=1)))


def _check_geometry(y: np.ndarray, min_samples: int, centred: np.ndarray) -> None:
    """Reject data from which no 3-D ellipsoid can be determined (one clear line each).

    ``centred`` is ``y`` minus its mean (:func:`calibrate` has it for the trivial estimate too).
    """
    distinct = _distinct_rows(y, enough=min_samples)
    if distinct < min_samples:
        raise ValueError(f"samples hold only {distinct} distinct measurements; at least "
                         f"{min_samples} are needed")
    # Screen first: the eigenvalues of the Gram matrix G = Yc^T Yc are the squared singular
    # values, and lambda_min / lambda_max >= det G / (trace G)^3 (lambda_min >= det / trace^2,
    # lambda_max <= trace). Above 1e-6 the smallest singular value is at least 1e-3 of the
    # largest, far from the 1e-9 thresholds below, whatever the rounding of G (~1e-13 of
    # trace^3), so the SVD is needed only for nearly flat data and keeps its exact meaning.
    (g00, g01, g02), (_, g11, g12), (_, _, g22) = (centred.T @ centred).tolist()
    det = (g00 * (g11 * g22 - g12 * g12) - g01 * (g01 * g22 - g12 * g02)
           + g02 * (g01 * g12 - g11 * g02))
    if det >= 1e-6 * (g00 + g11 + g22) ** 3 > 0.0:
        return
    spread = np.linalg.svd(centred, compute_uv=False)
    if spread[2] <= 1e-9 * spread[0]:
        shape = "collinear" if spread[1] <= 1e-9 * spread[0] else "coplanar"
        raise ValueError(f"samples are {shape} (singular values of the centred data "
                         f"{spread[0]:.3g}, {spread[1]:.3g}, {spread[2]:.3g}); rotate the sensor "
                         "through more directions")


def _checked(samples: object, min_samples: int, bias: bool
             ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """The per-dataset part of :func:`calibrate`: the samples checked for a method that needs
    ``min_samples`` of them, scaled (by one for a ``bias`` model), their mean and the centred
    samples; ValueError for bad input."""
    y = as_samples(samples, min_samples=min_samples)
    scale = unit_scale(y)
    if bias:
        # A bias-only method takes the field magnitude as an input in the samples' unit, so
        # its data must reach it unscaled.
        scale = 1.0
    y = y / scale
    # The centred samples serve both the geometry check and the trivial estimate's J_r.
    mean = sample_mean(y)
    centred = y - mean
    _check_geometry(y, min_samples, centred)
    return y, scale, mean, centred


class CheckedSamples:
    """Samples that many methods are called on: :func:`calibrate` checks and scales them once
    per kind of method (its ``min_samples`` and whether it fits a bias only) instead of once
    per call, with the same answers and the same errors.

    Each call hands its method a fresh copy of the checked samples (a copy costs far less than
    the checks), so a method that writes into its input cannot change another's; the arrays
    stay writeable, as numba compiles a read-only array's loops anew.

    Parameters
    ----------
    samples : array_like, shape (K, 3)
        As :func:`calibrate` takes them.
    """

    def __init__(self, samples: object) -> None:
        self.samples = samples
        self._done: dict[tuple[int, bool], tuple | str] = {}

    def prepare_for(self, methods: Sequence[str]) -> CheckedSamples:
        """Check the samples now for each of ``methods`` (a bad input's error is kept for
        their calls), so that no method's timed call pays it; returns self."""
        for name in methods:
            spec = get_method(name)
            with contextlib.suppress(ValueError):
                self.checked(spec.min_samples, spec.model == "bias")
        return self

    def checked(self, min_samples: int, bias: bool
                ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """What :func:`calibrate` computes from the samples for such a method (cached)."""
        key = (min_samples, bias)
        if key not in self._done:
            try:
                out = _checked(self.samples, min_samples, bias)
            except ValueError as exc:
                self._done[key] = str(exc)
            else:
                self._done[key] = out
        found = self._done[key]
        if isinstance(found, str):
            raise ValueError(found)
        y, scale, mean, centred = found
        return y.copy(), scale, mean, centred


def calibrate(samples: object, method: str, *, angular_rate: object = None,
              time: object = None, acceleration: object = None, raw: bool = False,
              **options: object) -> Calibration:
    """Estimate ``T`` and ``h`` of ``y = T m + h + eps`` from magnetometer samples.

    Parameters
    ----------
    samples : array_like, shape (K, 3), or CheckedSamples
        Magnetometer measurements, one per row, in any unit. The result is in the same unit;
        the field magnitude is normalised to one, so ``T`` absorbs the field strength. Wrapped
        in :class:`CheckedSamples`, they are checked once for all the methods called on them.
    method : str
        A name from :func:`methods`.
    angular_rate, time : array_like, optional
        Gyroscope samples ``(K, 3)`` in rad/s and their timestamps ``(K,)`` in seconds, for the
        gyro-aided methods; other methods ignore them.
    acceleration : array_like, optional
        Accelerometer samples ``(K, 3)`` (specific force in the IMU's axes, any unit), for the
        alignment methods; other methods ignore them.
    raw : bool
        Return the method's own ``T`` (any rotation or mirror image it carries) instead of the
        safe gauge (module notes). The benchmark's rows use it.
    **options
        The method's tuning values (iteration caps, tolerances, ``rng`` for randomised methods).

    Returns
    -------
    Calibration
        Finite ``T`` (invertible) and ``h``, with the method's iteration count and message;
        ``T`` symmetric positive definite unless ``raw``; an alignment method also gives the
        rotation to the IMU (``alignment``, relative to the symmetric gauge).

    Raises
    ------
    ValueError
        Bad input: unknown method or option, wrong shape, too few samples, NaN or infinite
        values, degenerate (collinear or coplanar) data.
    CalibrationFailed
        The method could not produce a finite, invertible estimate from these data.
    """
    spec = get_method(method)
    unknown = sorted(set(options) - set(spec.option_names()))
    if unknown:
        raise ValueError(f"unknown option(s) {', '.join(unknown)} for method {method!r}; it "
                         f"accepts: {', '.join(spec.option_names()) or 'no options'}")
    if isinstance(samples, CheckedSamples):
        y, scale, mean, centred = samples.checked(spec.min_samples, spec.model == "bias")
    else:
        y, scale, mean, centred = _checked(samples, spec.min_samples, spec.model == "bias")
    if spec.randomized and not isinstance(options.get("rng"), np.random.Generator):
        options["rng"] = np.random.default_rng(options.get("rng", 0))
    extra: dict[str, object] = {}
    if spec.needs_gyro:
        if angular_rate is None or time is None:
            raise ValueError(f"method {method!r} needs angular_rate (K, 3) in rad/s and "
                             "time (K,) in seconds")
        extra = {"angular_rate": angular_rate, "time": time}
    if spec.needs_accel:
        if acceleration is None:
            raise ValueError(f"method {method!r} needs acceleration (K, 3), the accelerometer's "
                             "samples in the IMU's axes")
        extra["acceleration"] = acceleration
    try:
        with np.errstate(all="ignore"):
            cal = spec.fit(y, **extra, **options)
    except np.linalg.LinAlgError as exc:
        raise CalibrationFailed(f"{method}: linear algebra failed ({exc})") from exc
    if not cal.is_finite:
        raise CalibrationFailed(f"{method}: estimate is not finite or T is singular "
                                f"({cal.message or 'no message'})")
    converged, message = cal.converged, cal.message
    if converged:
        fit_cost, trivial = _residual_against_trivial(y, cal, spec.model, mean, centred)
        if fit_cost > trivial * (1 + 1e-9) + 1e-12:
            converged = False
            message = (f"{method}: residual J_r (81) {fit_cost:.3g} is above the trivial "
                       f"estimate's {trivial:.3g} (h = mean, T = r I): not a calibration "
                       f"({message or 'no message'})")
    T = cal.T * scale
    return Calibration(T if raw else symmetric_T(T), cal.h * scale, cal.n_iter, converged,
                       message, cal.gyro_bias, cal.alignment)


def _residual_against_trivial(y: np.ndarray, cal: Calibration, model: str, mean: np.ndarray,
                              centred: np.ndarray) -> tuple[float, float]:
    """J_r (81) of ``cal`` and of the trivial estimate on the same samples.

    A method that claims convergence must fit the data at least as well as no fit at all
    (:func:`magbench.core.metrics.trivial_estimate`); a bias-only method, whose scale is an
    input, is held to the trivial centre at its own scale. The tolerance (1e-9 relative,
    1e-12 absolute: a field error of 1e-6) keeps exact fits of noise-free data, whose costs
    are both rounding, from being flagged. ``mean`` and ``centred`` (``y - mean``) are passed
    on to the trivial estimate.
    """
    _, h0, trivial = trivial_estimate(y, mean, centred)
    if model == "bias":
        trivial = real_cost(y, cal.T, h0)
    return real_cost(y, cal.T, cal.h), trivial
