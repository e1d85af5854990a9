"""Time alignment of the magnetometer with the gyroscope and the attitude reference.

A magnetometer read late by ``L`` seconds turns the field by ``|w| L`` at a turn rate ``w``
(16 ms at 5 rad/s is 4.6 degrees): a heading error no calibration can remove. The lag is
measured from the motion itself. In a homogeneous field the sensor-frame field direction obeys
``dm/dt = -w x m`` (:mod:`magbench.core.direction`), so the cross-correlation of the
direction's rate ``dm/dt`` (central differences) with ``-w x m`` (from the gyro, or from the
attitude's body rate) peaks at the magnetometer's lag behind the rate stream; the peak is
refined below one sample by a parabola through the three highest correlations. Both signals
are 3-vectors, correlated by their dot product, so the sign of each turn counts, not only its
speed, and zero-mean noise does not bias the peak. :func:`shift` then resamples a stream onto
the corrected times.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from magbench.core import geometry
from magbench.core.blockwise import gradient_rows, gradient_spacing, halo, interp_rows
from magbench.core.quaternions import blocks, quat_conjugate, quat_multiply, quat_to_rotvec
from magbench.core.rotations import skew
from magbench.core.tsqr import lstsq_blocks

__all__ = ["attitude_rate", "best_lag", "direction_rate", "gyro_lag", "magnetometer_lag", "shift",
           "stream_lag"]


def _central(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``dx/dt`` by central differences (one-sided at the ends)."""
    return np.gradient(x, t, axis=0)


def direction_rate(t: np.ndarray, field: np.ndarray) -> np.ndarray:
    """``d(m/|m|)/dt`` of a ``(K, 3)`` field, central differences (``(K, 3)``)."""
    u = field / np.linalg.norm(field, axis=1, keepdims=True)
    return _central(np.asarray(t, dtype=float), u)


def attitude_rate(t: np.ndarray, attitude: np.ndarray) -> np.ndarray:
    """Body angular rate (rad/s, sensor axes) of a sensor -> world attitude, central.

    The rotation from sample ``k-1`` to ``k+1`` in body axes is ``q_{k-1}* q_{k+1}``; its
    rotation vector over ``t_{k+1} - t_{k-1}`` is the rate at ``k`` (one-sided at the ends,
    NaN where the attitude is missing).
    """
    t = np.asarray(t, dtype=float)
    q = np.asarray(attitude, dtype=float)
    out = np.empty((len(q), 3))
    # a block of rows at a time: the quaternion products of a long log are several (K, 4)
    # arrays (each row's rate depends on its two neighbours only)
    for rows in blocks(len(q)):
        k = np.arange(rows.start, rows.stop)
        lo = np.where(k == 0, 0, np.where(k == len(q) - 1, len(q) - 2, k - 1))
        hi = np.where(k == 0, 1, np.where(k == len(q) - 1, len(q) - 1, k + 1))
        d = quat_to_rotvec(quat_multiply(quat_conjugate(q[lo]), q[hi]))
        out[rows] = d / (t[hi] - t[lo])[:, None]
    return out


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised correlation of two ``(K, d)`` streams over the rows where both are finite
    (means removed; vectors by their dot product)."""
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    if ok.sum() < 2:
        return np.nan                   # no overlap at this lag (a reference with gaps)
    a, b = a[ok], b[ok]                 # copies: centred in place (a long log's rows)
    a -= a.mean(axis=0)
    b -= b.mean(axis=0)
    denom = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / denom) if denom > 0 else np.nan


def _vertex(lags: np.ndarray, c: np.ndarray) -> float:
    """The abscissa of the parabola's peak through three equally spaced points."""
    cm, c0, cp = c
    curvature = cm - 2.0 * c0 + cp
    step = lags[1] - lags[0]
    frac = 0.5 * (cm - cp) / curvature if curvature < 0 else 0.0
    return float(lags[1] + np.clip(frac, -1.0, 1.0) * step)


def best_lag(observed: np.ndarray, expected_at, dt: float,
             max_lag_s: float) -> tuple[float, float]:
    """The lag ``L`` that best matches ``observed`` with ``expected_at(L)``, and the peak
    correlation.

    The normalised correlation is computed at whole-sample lags up to ``max_lag_s`` either
    way, the peak refined by the parabola through it and its neighbours
    (``j* = j0 + (c_- - c_+) / (2 (c_- - 2 c_0 + c_+))``), then twice more by parabolas at a
    quarter and a sixteenth of a sample about the estimate.

    Parameters
    ----------
    observed : ndarray, shape (K, d)
        The late stream's signal.
    expected_at : callable
        ``expected_at(L)``: what ``observed`` should be if it is late by ``L`` s, shape (K, d).
    dt : float
        Sample interval, s.
    max_lag_s : float
        Largest lag searched either way, s.

    Returns
    -------
    lag_s : float
        NaN if the peak is at the search's edge.
    peak : float
        The correlation at ``lag_s``.
    """
    observed = np.asarray(observed, dtype=float).reshape(len(observed), -1)

    def corr(lag: float) -> float:
        return _correlation(np.asarray(expected_at(lag)).reshape(len(observed), -1), observed)

    return _peak_lag(corr, dt, max_lag_s)


def _peak_lag(corr: Callable[[float], float], dt: float, max_lag_s: float
              ) -> tuple[float, float]:
    """:func:`best_lag`'s search on a correlation function of the lag."""
    n = max(1, round(max_lag_s / dt))
    grid = np.arange(-n, n + 1) * dt
    c = np.array([corr(L) for L in grid])
    if not np.isfinite(c).any():
        return np.nan, np.nan
    i0 = int(np.nanargmax(c))
    if i0 in (0, len(c) - 1):
        return np.nan, float(c[i0])
    lag = _vertex(grid[i0 - 1:i0 + 2], c[i0 - 1:i0 + 2])
    for step in (dt / 4, dt / 16):
        around = lag + np.array([-step, 0.0, step])
        lag = _vertex(around, np.array([corr(L) for L in around]))
    return lag, corr(lag)


def stream_lag(t: np.ndarray, reference: np.ndarray, late: np.ndarray,
               max_lag_s: float = 0.1) -> tuple[float, float]:
    """Delay ``L`` of stream ``late`` behind ``reference`` (``late(t) = reference(t - L)``),
    both sampled at ``t``; :func:`best_lag` on ``reference`` resampled at ``t - L``."""
    t = np.asarray(t, dtype=float)
    return best_lag(late, lambda L: shift(t, reference, -L), float(np.median(np.diff(t))),
                    max_lag_s)


def _rate_design(u: np.ndarray, rate: np.ndarray, observed: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The design ``(K, 3, 9)`` of ``[u]x A w`` in the entries of ``A``, and its finite rows."""
    design = np.einsum("kij,kl->kijl", skew(u), rate).reshape(len(u), 3, 9)
    return design, np.isfinite(design).all(axis=(1, 2)) & np.isfinite(observed).all(axis=1)


def _rate_fit(u: np.ndarray, rate: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """``[u]x A w`` with the 3x3 ``A`` that best fits ``observed`` (least squares over the
    finite rows; NaN elsewhere).

    Up to :data:`~magbench.core.geometry.BLOCK_ROWS` samples by ``lstsq`` on the whole design
    (216 bytes a sample, and LAPACK's copy); more a block at a time by TSQR
    (:func:`magbench.core.tsqr.lstsq_blocks`), equal to round-off in memory of one block."""
    out = np.full(observed.shape, np.nan)
    step = geometry.BLOCK_ROWS
    if len(u) <= step:
        design, ok = _rate_design(u, rate, observed)
        if ok.sum() < 4:
            return out
        a = np.linalg.lstsq(design[ok].reshape(-1, 9), observed[ok].reshape(-1),
                            rcond=None)[0]
        out[ok] = design[ok] @ a
        return out
    count = 0

    def rows():
        nonlocal count
        for start in range(0, len(u), step):
            block = slice(start, start + step)
            design, ok = _rate_design(u[block], rate[block], observed[block])
            count += int(ok.sum())
            yield design[ok].reshape(-1, 9), observed[block][ok].reshape(-1)

    try:
        a = lstsq_blocks(rows())[0]
    except ValueError:              # no finite row
        return out
    if count < 4:
        return out
    for start in range(0, len(u), step):
        block = slice(start, start + step)
        design, ok = _rate_design(u[block], rate[block], observed[block])
        out[block][ok] = design[ok] @ a
    return out


def magnetometer_lag(t: np.ndarray, field: np.ndarray, angular_rate: np.ndarray,
                     max_lag_s: float = 0.1, *, centre: np.ndarray | None = None
                     ) -> tuple[float, float]:
    """Lag (s) of the magnetometer behind a rate stream (gyro or :func:`attitude_rate`).

    A field read ``L`` late obeys ``dm/dt (t) = m(t) x A w(t - L)``, with ``A`` the rotation
    from the rate's axes to the magnetometer's (identity when they agree; any fixed matrix
    absorbs a mounting rotation and the distortion left in a rough calibration, either of
    which biased the lag by tens of ms when ``A = I`` was assumed). For each candidate lag the
    rate is resampled at ``t - L`` and ``A`` fitted by linear least squares; the lag whose fit
    correlates best with the direction's rate (central differences) wins (:func:`best_lag`).
    Only the rate stream is shifted: ``m`` stays at its own times, so the match does not
    depend on how fast the field turns. ``field`` should be centred (a sphere fit will do, or
    pass its centre as ``centre``: ``field - centre`` is then used, a block at a time). A
    positive lag means the magnetometer sample at ``t`` shows the field of ``t - L``.

    More than :data:`~magbench.core.geometry.BLOCK_ROWS` samples with increasing times are
    worked a block at a time (:func:`_long_lag`): no ``(K, 3)`` array beside the inputs.
    """
    t = np.asarray(t, dtype=float)
    rate = np.asarray(angular_rate, dtype=float)
    if len(t) > geometry.BLOCK_ROWS and _increasing(t):
        return _long_lag(t, field, centre, rate, max_lag_s)
    field = np.asarray(field, dtype=float) if centre is None else field - centre
    u = field / np.linalg.norm(field, axis=1, keepdims=True)
    observed = direction_rate(t, field)
    return best_lag(observed, lambda L: _rate_fit(u, shift(t, rate, -L), observed),
                    float(np.median(np.diff(t))), max_lag_s)


def _increasing(t: np.ndarray) -> bool:
    """Whether ``t`` is strictly increasing (checked a block at a time)."""
    return all((t[b.start + 1:b.stop + 1] > t[b]).all() for b in blocks(len(t) - 1))


def _lag_blocks(t: np.ndarray, field: np.ndarray, centre: np.ndarray | None,
                rate: np.ndarray, lag: float
                ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per block of :data:`~magbench.core.geometry.BLOCK_ROWS` rows: the unit field, the rate
    resampled at ``t - lag`` and the direction's rate, each row the number the whole arrays
    of :func:`magnetometer_lag`'s short path hold (:mod:`magbench.core.blockwise`)."""
    K = len(t)
    spacing = gradient_spacing(t)
    for rows in blocks(K, geometry.BLOCK_ROWS):
        near = halo(rows, K)
        f = field[near] if centre is None else field[near] - centre
        u = f / np.linalg.norm(f, axis=1, keepdims=True)
        inner = slice(rows.start - near.start, rows.stop - near.start)
        yield (u[inner], interp_rows(t, rate, t[rows] + -lag),
               gradient_rows(t, u, rows, spacing))


def _long_lag(t: np.ndarray, field: np.ndarray, centre: np.ndarray | None, rate: np.ndarray,
              max_lag_s: float) -> tuple[float, float]:
    """:func:`magnetometer_lag` a block at a time: for each candidate lag, ``A`` by TSQR over
    the blocks (as :func:`_rate_fit` fits a long recording: the same ``A``), then the
    correlation of its fit with the direction's rate from sums over the blocks (the whole
    arrays' correlation to round-off: the sums run in another order)."""
    dt = float(np.median(t[1:] - t[:-1]))

    def corr(lag: float) -> float:
        count = 0

        def design_rows() -> Iterator[tuple[np.ndarray, np.ndarray]]:
            nonlocal count
            for u, w, observed in _lag_blocks(t, field, centre, rate, lag):
                design, ok = _rate_design(u, w, observed)
                count += int(ok.sum())
                every = ok.all()        # every row finite: the block itself, not a copy
                yield ((design if every else design[ok]).reshape(-1, 9),
                       (observed if every else observed[ok]).reshape(-1))
                del design, ok          # not held while the next block's is built

        try:
            a = lstsq_blocks(design_rows())[0]
        except ValueError:              # no finite row
            return np.nan
        if count < 4:
            return np.nan
        # one pass of sums about a provisional mean (the first block's): the centred sums
        # are then exact in exact arithmetic and stable in floating point
        n, shift_a, shift_b = 0, None, None
        s_a, s_b = np.zeros(3), np.zeros(3)
        s_aa = s_bb = s_ab = 0.0
        for u, w, observed in _lag_blocks(t, field, centre, rate, lag):
            design, ok = _rate_design(u, w, observed)
            every = ok.all()
            fitted = (design if every else design[ok]) @ a
            del design
            both = np.isfinite(fitted).all(axis=1)
            fa, fb = fitted[both], (observed if every else observed[ok])[both]
            if not len(fa):
                continue
            if shift_a is None:
                shift_a, shift_b = fa.mean(axis=0), fb.mean(axis=0)
            fa -= shift_a
            fb -= shift_b
            n += len(fa)
            s_a += fa.sum(axis=0)
            s_b += fb.sum(axis=0)
            s_aa += float(np.sum(fa * fa))
            s_bb += float(np.sum(fb * fb))
            s_ab += float(np.sum(fa * fb))
        if n < 2:
            return np.nan               # no overlap at this lag (a reference with gaps)
        m_a, m_b = s_a / n, s_b / n
        var_a = s_aa - n * float(m_a @ m_a)
        var_b = s_bb - n * float(m_b @ m_b)
        cov = s_ab - n * float(m_a @ m_b)
        denom = np.sqrt(var_a * var_b) if var_a > 0 and var_b > 0 else 0.0
        return float(cov / denom) if denom > 0 else np.nan

    return _peak_lag(corr, dt, max_lag_s)


def gyro_lag(t: np.ndarray, angular_rate: np.ndarray, attitude: np.ndarray,
             max_lag_s: float = 0.1) -> tuple[float, float]:
    """Lag (s) of the gyro behind the attitude reference's body rate (:func:`stream_lag`)."""
    return stream_lag(t, attitude_rate(t, attitude), angular_rate, max_lag_s)


def shift(t: np.ndarray, values: np.ndarray, lag_s: float) -> np.ndarray:
    """A stream resampled at ``t + lag_s`` (linear interpolation per column; NaN outside).

    For a stream late by ``lag_s`` (:func:`magnetometer_lag`), ``shift(t, m, lag_s)`` is the
    field at the times ``t`` of the other streams.
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(values, dtype=float)
    flat = v.reshape(len(v), -1)
    out = np.empty(flat.shape)
    if len(t) > geometry.BLOCK_ROWS and _increasing(t):
        # a block of times at a time from the samples around them (the same numbers): no
        # (K,) arrays of times and values beside the result
        for rows in blocks(len(t), geometry.BLOCK_ROWS):
            out[rows] = interp_rows(t, flat, t[rows] + lag_s)
        return out.reshape(v.shape)
    # one column at a time into the result (column_stack held every column twice)
    at = t + lag_s
    for j, col in enumerate(flat.T):
        out[:, j] = np.interp(at, t, col, left=np.nan, right=np.nan)
    return out.reshape(v.shape)
