"""Whole-array NumPy operations on rows taken a block at a time, with the same numbers.

A long recording's ``(K, 3)`` temporaries (its unit directions, their time derivative, a
stream resampled at shifted times) are each as large as its samples. The functions here give
rows ``start:stop`` of what :func:`numpy.gradient` and :func:`numpy.interp` give for the whole
array, from a few rows around them only, by the same formulas in the same order: each row is
bit for bit the whole array's.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from magbench.core.direction import _unit
from magbench.core.quaternions import blocks

__all__ = ["affine_rows", "column_sums", "gradient_rows", "gradient_spacing", "halo",
           "interp_rows", "mean_direction_rows"]


def gradient_spacing(t: np.ndarray) -> float | None:
    """:func:`numpy.gradient`'s choice for coordinates ``t``: the common step when every
    difference equals the first (it then uses the uniform formula), else None."""
    t = np.asarray(t, dtype=float)
    if len(t) < 2:
        return None
    first = t[1] - t[0]
    for rows in blocks(len(t) - 1):                       # no (K,) array of differences
        if not (t[rows.start + 1:rows.stop + 1] - t[rows] == first).all():
            return None
    return float(first)


def halo(rows: slice, K: int) -> slice:
    """``rows`` widened by one row either way within ``0..K`` (what a central difference
    of those rows reads)."""
    return slice(max(rows.start - 1, 0), min(rows.stop + 1, K))


def gradient_rows(t: np.ndarray, f: np.ndarray, rows: slice, spacing: float | None
                  ) -> np.ndarray:
    """Rows ``rows`` of ``np.gradient(F, t, axis=0)`` (``edge_order=1``) for a ``(K, d)``
    array ``F`` of which ``f`` is rows :func:`halo` ``(rows, K)``.

    Parameters
    ----------
    t : ndarray, shape (K,)
        Every coordinate (at least two).
    f : ndarray, shape (n, d)
        ``F[halo(rows, K)]``.
    rows : slice
        Consecutive rows ``start:stop`` (step 1) within ``0..K``.
    spacing : float or None
        :func:`gradient_spacing` of the whole ``t``.
    """
    t = np.asarray(t, dtype=float)
    K = len(t)
    lo = halo(rows, K).start
    out = np.empty((rows.stop - rows.start,) + f.shape[1:])
    # interior rows i (1 <= i <= K - 2) of the block, as numpy writes out[1:-1]
    first, last = max(rows.start, 1), min(rows.stop, K - 1)
    if last > first:
        i = np.arange(first, last)
        f2, f3, f4 = f[i - 1 - lo], f[i - lo], f[i + 1 - lo]
        o = slice(first - rows.start, last - rows.start)
        if spacing is not None:
            out[o] = (f4 - f2) / (2. * spacing)
        else:
            dx1 = t[first:last] - t[first - 1:last - 1]
            dx2 = t[first + 1:last + 1] - t[first:last]
            a = (-(dx2) / (dx1 * (dx1 + dx2)))[:, None]
            b = ((dx2 - dx1) / (dx1 * dx2))[:, None]
            c = (dx1 / (dx2 * (dx1 + dx2)))[:, None]
            out[o] = a * f2 + b * f3 + c * f4
    if rows.start == 0:
        dx_0 = spacing if spacing is not None else t[1] - t[0]
        out[0] = (f[1 - lo] - f[0 - lo]) / dx_0
    if rows.stop == K:
        dx_n = spacing if spacing is not None else t[K - 1] - t[K - 2]
        out[-1] = (f[K - 1 - lo] - f[K - 2 - lo]) / dx_n
    return out


def interp_rows(xp: np.ndarray, fp: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``np.interp(x, xp, fp[:, j], left=nan, right=nan)`` for every column ``j`` of a
    ``(K, d)`` ``fp``, reading only the rows of ``xp`` around ``x``.

    ``xp`` must be strictly increasing and ``x`` non-decreasing (a block of shifted times):
    each value then comes from the same two samples, by the same formula, as with the whole
    ``xp``, so it is the same number.
    """
    xp = np.asarray(xp, dtype=float)
    x = np.asarray(x, dtype=float)
    fp = np.asarray(fp, dtype=float).reshape(len(xp), -1)
    if not len(x):
        return np.empty((0, fp.shape[1]))
    # one sample more either way than the bracketing ones; at the ends the whole stream's
    # first and last sample, so values outside it are NaN as they are for the whole
    lo = max(int(np.searchsorted(xp, x[0], side="left")) - 2, 0)
    hi = min(int(np.searchsorted(xp, x[-1], side="right")) + 2, len(xp))
    part = xp[lo:hi]
    return np.column_stack([np.interp(x, part, col, left=np.nan, right=np.nan)
                            for col in fp[lo:hi].T])


def affine_rows(y: np.ndarray, A: np.ndarray, b: np.ndarray, size: int) -> np.ndarray:
    """``(y - b) @ A.T`` for ``(K, 3)`` rows ``y``, made ``size`` rows at a time into one
    result: no ``(K, 3)`` temporary beside it. With no more than ``size`` rows, one product,
    the whole array's numbers; else each chunk's product, whose rows BLAS may round in the
    last bit otherwise than the whole array's (another kernel for another row count)."""
    A = np.asarray(A)
    if len(y) <= size:
        return (y - b) @ A.T
    out = np.empty((len(y), A.shape[0]))
    for rows in blocks(len(y), size):
        out[rows] = (y[rows] - b) @ A.T
    return out


def column_sums(parts: Iterable[np.ndarray]) -> np.ndarray:
    """``np.sum(np.concatenate(parts), axis=0)`` of C-contiguous 2-D blocks, to the last bit.

    NumPy sums the rows of a C-contiguous 2-D array one after another along axis 0, so each
    block's rows are added to the sum so far in that order (not the blocks' own sums added:
    that is another order)."""
    total: np.ndarray | None = None
    for part in parts:
        part = np.ascontiguousarray(part)
        if total is not None:
            part = np.concatenate([total[None], part])
        if len(part):
            total = part.sum(axis=0)
    if total is None:
        raise ValueError("a sum over no rows")
    return total


def mean_direction_rows(parts: Iterable[np.ndarray]) -> np.ndarray:
    """:func:`magbench.core.direction.mean_direction` of the rows of ``(n, 3)`` blocks
    stacked, to the last bit, one block held at a time: each block made unit, its NaN
    counted out, the rows summed in order (:func:`column_sums`)."""
    count = np.zeros(3, dtype=np.intp)

    def units() -> Iterator[np.ndarray]:
        for part in parts:
            u = _unit(part)
            nan = np.isnan(u)
            u[nan] = 0.0
            count[:] += (~nan).sum(axis=0)
            yield u

    total = column_sums(units())
    return _unit(total / count)
