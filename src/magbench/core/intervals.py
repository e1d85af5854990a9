"""Confidence intervals of the benchmark's two Monte Carlo statistics, one helper each.

* RB % of eq. (77) is a binomial proportion (``k`` meaningful runs out of ``n``): its interval
  is Wilson's score interval (Wilson 1927; Brown, Cai and DasGupta 2001 recommend it over the
  normal approximation, which collapses to a point at 0 % and 100 %, exactly where RB sits).
* The accuracy 1/rho of eq. (78) is the inverse of a mean over the meaningful runs; its
  interval is the percentile bootstrap over those runs (Efron and Tibshirani 1993, ch. 13),
  drawn from a seeded Generator (:func:`magbench.core.seeding.rng`), so the same file gives
  the same interval every time.

Two intervals that overlap do not prove equality, and two that do not overlap are a
conservative test of a difference (at 95 % each, the pair's level is above 95 %): the report
calls a difference inside the intervals "not significant" and says so.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from magbench.core.seeding import rng

__all__ = ["RESAMPLES", "Z95", "bootstrap_inverse_mean", "bootstrap_paired_ratio",
           "intervals_overlap", "wilson"]

#: Standard normal quantile of a two-sided 95 % interval.
Z95 = 1.959963984540054
#: Bootstrap resamples: enough that the 2.5 % and 97.5 % percentiles move by well under the
#: three significant figures the report prints.
RESAMPLES = 2000


def wilson(k: int | float, n: int | float, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion, in percent.

    Parameters
    ----------
    k, n : int
        Successes (meaningful runs) and trials; ``0 <= k <= n``.
    z : float
        Normal quantile (1.96 for 95 %).

    Returns
    -------
    (low, high) : tuple of float
        Bounds in percent, ``0 <= low <= 100 k / n <= high <= 100``; ``(nan, nan)`` when
        ``n == 0``.

    Notes
    -----
    With ``p = k / n``: centre ``(p + z^2 / 2n) / (1 + z^2 / n)``, half-width
    ``z sqrt(p (1 - p) / n + z^2 / 4n^2) / (1 + z^2 / n)``.
    """
    if n <= 0 or not np.isfinite(n) or not np.isfinite(k):
        return (np.nan, np.nan)
    if k < 0 or k > n:
        raise ValueError(f"need 0 <= k <= n, got k = {k}, n = {n}")
    p = k / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    # Clip rounding only; the exact interval always lies in [0, 1] and contains p.
    return (float(100.0 * max(0.0, min(p, centre - half))),
            float(100.0 * min(1.0, max(p, centre + half))))


def bootstrap_inverse_mean(values: Sequence[float] | np.ndarray, *keys: int | str,
                           seed: int = 0, resamples: int = RESAMPLES,
                           level: float = 0.95) -> tuple[float, float]:
    """Percentile-bootstrap interval of ``1 / mean(values)`` (the accuracy 1/rho of eq. 78).

    Parameters
    ----------
    values : array_like
        The per-run costs J of the meaningful runs (one per dataset).
    *keys : int or str
        Names of the stream (e.g. sweep, point, method), so every interval has its own draws
        and none depends on which other intervals are computed.
    seed : int
        Base seed of :func:`magbench.core.seeding.rng`; fixed, so a report is a pure function
        of its CSV files.
    resamples : int
        Bootstrap resamples of the runs.
    level : float
        Coverage of the interval, in (0, 1).

    Returns
    -------
    (low, high) : tuple of float
        ``(nan, nan)`` with no value; ``(x, x)`` with one value (no spread to resample).
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return (np.nan, np.nan)
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    picks = rng(seed, "bootstrap", *keys).integers(0, x.size, size=(resamples, x.size))
    means = x[picks].mean(axis=1)
    with np.errstate(divide="ignore"):
        inverse = 1.0 / means
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(inverse, [tail, 100.0 - tail])
    return (float(low), float(high))


def bootstrap_paired_ratio(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray,
                           *keys: int | str, seed: int = 0, resamples: int = RESAMPLES,
                           level: float = 0.95) -> tuple[float, float]:
    """Percentile-bootstrap interval of ``mean(a) / mean(b)`` over paired runs.

    ``a[i]`` and ``b[i]`` are two methods' costs on the same dataset ``i``; the datasets are
    resampled together, so what the datasets share (their difficulty) cancels and only the
    difference between the methods is left to vary. An interval that excludes 1 is a
    difference at the 95 % level. ``keys`` name the stream as in
    :func:`bootstrap_inverse_mean`.

    Returns
    -------
    (low, high) : tuple of float
        ``(nan, nan)`` with fewer than two pairs.
    """
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if x.size < 2:
        return (np.nan, np.nan)
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    picks = rng(seed, "paired bootstrap", *keys).integers(0, x.size, size=(resamples, x.size))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = x[picks].mean(axis=1) / y[picks].mean(axis=1)
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(ratio, [tail, 100.0 - tail])
    return (float(low), float(high))


def intervals_overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """True when the closed intervals ``a`` and ``b`` share a point (NaN bounds: True, i.e.
    no evidence of a difference)."""
    if not all(np.isfinite(v) for v in (*a, *b)):
        return True
    return a[0] <= b[1] and b[0] <= a[1]
