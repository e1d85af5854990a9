"""Confidence intervals of the benchmark's two Monte Carlo statistics, one helper each.

* RB % of eq. (77) is a binomial proportion (``k`` meaningful runs out of ``n``): its interval
  is Wilson's score interval (Wilson 1927; Brown, Cai and DasGupta 2001 recommend it over the
  normal approximation, which collapses to a point at 0 % and 100 %, exactly where RB sits).
* The accuracy 1/rho of eq. (78) is the inverse of a mean over the meaningful runs; its
  interval is the percentile bootstrap over those runs (Efron and Tibshirani 1993, ch. 13),
  drawn from a seeded Generator (:func:`magbench.core.seeding.rng`), so the same file gives
  the same interval every time.

* A median over units (the heading study's) gets the distribution-free order-statistic
  interval (:func:`median_interval`: the ranks that the binomial distribution with p = 1/2
  gives), which needs no resampling.

Two intervals that overlap do not prove equality, and two that do not overlap are a
conservative test of a difference (at 95 % each, the pair's level is above 95 %): the report
calls a difference inside the intervals "not significant" and says so.
"""

from __future__ import annotations

import hashlib
import json
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from magbench.core.seeding import rng

__all__ = ["CHUNK_VALUES", "RESAMPLES", "Z95", "bootstrap_inverse_mean", "bootstrap_mean",
           "bootstrap_paired_ratio", "intervals_overlap", "median_interval", "resampled_means",
           "wilson"]

#: Standard normal quantile of a two-sided 95 % interval.
Z95 = 1.959963984540054
#: Bootstrap resamples: enough that the 2.5 % and 97.5 % percentiles move by well under the
#: three significant figures the report prints.
RESAMPLES = 2000
#: Resampled values held at once (indices and gathered values, 8 bytes each): the bootstrap's
#: memory is about 16 times this in bytes, whatever the number of runs.
CHUNK_VALUES = 1 << 21


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


def median_interval(values: Sequence[float] | np.ndarray, level: float = 0.95
                    ) -> tuple[float, float]:
    """Distribution-free interval of the median: the order statistics ``x_(k)`` and
    ``x_(n+1-k)`` (1-based) with ``k`` the ``(1 - level) / 2`` quantile of Binomial(n, 1/2),
    so that each bound misses the median with probability at most ``(1 - level) / 2``
    (n = 100 gives ranks 40 and 61). Non-finite values are dropped; with fewer than 6 values
    the interval is the range, and covers less than ``level``; NaN without values."""
    from scipy.stats import binom

    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    x = np.sort(np.asarray(values, dtype=float))
    x = x[np.isfinite(x)]
    n = x.size
    if n == 0:
        return np.nan, np.nan
    k = max(1, int(binom.ppf((1.0 - level) / 2.0, n, 0.5)))
    return float(x[k - 1]), float(x[n - k])


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
    means = resampled_means(x, rng(seed, "bootstrap", *keys), resamples)
    with np.errstate(divide="ignore"):
        inverse = 1.0 / means
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(inverse, [tail, 100.0 - tail])
    return (float(low), float(high))


def bootstrap_mean(values: Sequence[float] | np.ndarray, *keys: int | str, seed: int = 0,
                   resamples: int = RESAMPLES, level: float = 0.95) -> tuple[float, float]:
    """Percentile-bootstrap interval of ``mean(values)`` (non-finite values dropped).

    Same stream, resamples and conventions as :func:`bootstrap_inverse_mean`; ``(nan, nan)``
    with no value.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return (np.nan, np.nan)
    return _percentile_interval(resampled_means(x, rng(seed, "bootstrap", *keys), resamples),
                                level)


def _percentile_interval(statistic: np.ndarray, level: float) -> tuple[float, float]:
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(statistic, [tail, 100.0 - tail])
    return (float(low), float(high))


#: Bootstrap means drawn before in this process, by everything that determines them (the
#: values, the generator's type and state, the resamples): the report asks for the same
#: interval in several sections. Oldest first; at most :data:`MEMO_BYTES` of means kept.
_MEMO: OrderedDict[bytes, tuple[np.ndarray, dict]] = OrderedDict()
#: Largest size (bytes) of the means :func:`resampled_means` keeps for reuse.
MEMO_BYTES = 32 << 20
_MEMO_SIZE = [0]                # bytes of the means in _MEMO


def _memo_key(x: np.ndarray, generator: np.random.Generator, resamples: int,
              chunk_values: int) -> bytes | None:
    """The digest of :func:`resampled_means`' inputs (None for values that are not plain
    numbers, whose bytes would not say what they are)."""
    if x.dtype.kind not in "fiub":
        return None
    digest = hashlib.sha256(repr((x.dtype.str, x.shape, resamples, chunk_values,
                                  type(generator.bit_generator).__name__)).encode())
    digest.update(json.dumps(generator.bit_generator.state, sort_keys=True,
                             default=str).encode())
    digest.update(np.ascontiguousarray(x).tobytes())
    return digest.digest()


def resampled_means(x: np.ndarray, generator: np.random.Generator, resamples: int,
                    chunk_values: int = CHUNK_VALUES) -> np.ndarray:
    """Means of ``resamples`` bootstrap resamples of the rows of ``x``, drawn in chunks.

    Draws exactly what one ``generator.integers(0, n, size=(resamples, n))`` call draws, row
    after row: a bounded integer takes one 32-bit draw from the generator's own stream (Lemire's
    method keeps no buffer between calls), so consecutive calls of ``c`` rows each continue the
    same sequence, and each row's mean is reduced on its own. The result equals the one-call
    version's to the bit while holding at most ``chunk_values`` indices (and their gathered
    values) at a time.

    Parameters
    ----------
    x : ndarray, shape (n,) or (n, m)
        The values to resample (rows are resampled together: a paired bootstrap for ``m > 1``).
    generator : numpy.random.Generator
        The stream of the resampling indices (advanced by the draws).
    resamples : int
        Number of resamples.
    chunk_values : int
        Indices drawn per chunk; at least one row per chunk.

    Returns
    -------
    ndarray, shape (resamples,) or (resamples, m)
        The mean of each resample. The same inputs (values and generator state) asked again
        in this process give the means drawn the first time, and leave the generator where
        drawing them again would (:data:`MEMO_BYTES`).
    """
    x = np.asarray(x)
    key = _memo_key(x, generator, resamples, chunk_values)
    if key is not None and key in _MEMO:
        _MEMO.move_to_end(key)
        out, state = _MEMO[key]
        generator.bit_generator.state = state
        return out.copy()
    n = x.shape[0]
    rows = max(1, chunk_values // max(n, 1))
    out = np.empty((resamples, *x.shape[1:]))
    for start in range(0, resamples, rows):
        stop = min(start + rows, resamples)
        picks = generator.integers(0, n, size=(stop - start, n))
        out[start:stop] = x[picks].mean(axis=1)
    if key is not None and out.nbytes <= MEMO_BYTES:
        _MEMO[key] = (out.copy(), generator.bit_generator.state)
        _MEMO_SIZE[0] += out.nbytes
        while _MEMO_SIZE[0] > MEMO_BYTES:
            _MEMO_SIZE[0] -= _MEMO.popitem(last=False)[1][0].nbytes
    return out


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
    means = resampled_means(np.column_stack([x, y]), rng(seed, "paired bootstrap", *keys),
                            resamples)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _percentile_interval(means[:, 0] / means[:, 1], level)


def intervals_overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """True when the closed intervals ``a`` and ``b`` share a point (NaN bounds: True, i.e.
    no evidence of a difference)."""
    if not all(np.isfinite(v) for v in (*a, *b)):
        return True
    return a[0] <= b[1] and b[0] <= a[1]
