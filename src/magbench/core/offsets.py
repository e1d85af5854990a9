"""A hard-iron offset that changes within a recording: windows, their offsets, segments.

One calibration ``m = A (y - h)`` assumes one offset ``h``. A magnet attached to the board, a
battery swapped or a tool clipped on changes it part-way, and a fit over the whole recording
is then a compromise that fits neither part (its rotation to the IMU is off by degrees too).

In a homogeneous field the sensor-frame field of a calibrated magnetometer that carries an
extra constant offset ``c`` obeys ``m_j - c = P (m_k - c)``, ``P = Q_j^T Q_k`` the body
rotation from row ``k`` to row ``j`` (``Q`` sensor -> world, from a reference attitude or the
integrated gyro: a constant world rotation or a slow drift cancels over a short pair). So

    (I - P) c = m_j - P m_k

is linear in ``c`` (:func:`window_offsets`): each window's pairs give its offset when the
sensor turns about two axes or more within it. With the chosen calibration's field ``c`` is
near zero wherever the offset is the fitted one; it jumps where the offset changes.
:func:`offset_segments` cuts the windows where a new offset persists (a short excursion, the
sensor passing a magnet in the room, is set aside, not a change), or where the field jumps at
rest (``m_j != m_k`` while ``P = I``), and :func:`consistent_rows` keeps the segment that holds
most turning windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magbench.core.rotations import cumulative_product, rotation_exp

__all__ = ["OffsetSegment", "OffsetWindows", "consistent_rows", "gyro_orientation",
           "offset_segments", "window_offsets"]


def gyro_orientation(t: np.ndarray, angular_rate: np.ndarray) -> np.ndarray:
    """Body orientations ``Q_k`` (sensor -> an arbitrary start frame) integrated from the rate
    by the trapezoid rule; ``Q_0 = I``. Drift does not matter over the short pairs of
    :func:`window_offsets`.

    Parameters
    ----------
    t : ndarray, shape (K,)
        Times, s.
    angular_rate : ndarray, shape (K, 3)
        Body rate, rad/s.

    Returns
    -------
    ndarray, shape (K, 3, 3)
    """
    t = np.asarray(t, dtype=float)
    w = np.asarray(angular_rate, dtype=float)
    steps = rotation_exp(0.5 * (w[:-1] + w[1:]) * np.diff(t)[:, None])
    return cumulative_product(np.concatenate([np.eye(3)[None], steps]))


@dataclass(frozen=True)
class OffsetWindows:
    """Consecutive windows of a recording and the extra offset each one shows.

    Attributes
    ----------
    start, stop : ndarray of int, shape (W,)
        Row range of each window (``stop`` exclusive).
    offset : ndarray, shape (W, 3)
        Extra sensor-frame offset (units of ``field``); NaN where the window does not turn.
    turning : ndarray of bool, shape (W,)
        The window's pairs turn enough to fix the offset (every direction).
    jump : ndarray, shape (W,)
        Largest ``|m_j - P m_k|`` over the window's pairs (a change at rest shows here).
    turn_deg : ndarray, shape (W,)
        Largest turn of the window's pairs, deg.
    """

    start: np.ndarray
    stop: np.ndarray
    offset: np.ndarray
    turning: np.ndarray
    jump: np.ndarray
    turn_deg: np.ndarray


def window_offsets(t: np.ndarray, field: np.ndarray, orientation: np.ndarray, *,
                   window_s: float = 2.0, pair_s: float = 0.5,
                   min_turn_deg: float = 10.0) -> OffsetWindows:
    """Each window's extra offset ``c`` from ``(I - P) c = m_j - P m_k`` (module notes).

    Parameters
    ----------
    t : ndarray, shape (K,)
        Times, s.
    field : ndarray, shape (K, 3)
        Calibrated sensor-frame field (NaN rows allowed).
    orientation : ndarray, shape (K, 3, 3)
        Sensor -> world rotations (reference attitude or :func:`gyro_orientation`; NaN rows
        allowed).
    window_s, pair_s : float
        Window length, and the time between the two rows of a pair.
    min_turn_deg : float
        A window fixes ``c`` when the smallest singular value of its stacked ``I - P``, per
        pair, is at least that of a turn by this angle.

    Returns
    -------
    OffsetWindows
    """
    t = np.asarray(t, dtype=float)
    field = np.asarray(field, dtype=float)
    dt = float(np.median(np.diff(t)))
    n = max(1, round(pair_s / dt))
    size = max(2, round(window_s / dt))
    K = len(t)
    pairs = max(K - n, 0)
    floor = 2.0 * np.sin(np.radians(min_turn_deg) / 2.0)
    start = np.arange(0, max(K - n, 1), size)
    stop = np.minimum(start + size, K)
    offset = np.full((len(start), 3), np.nan)
    turning = np.zeros(len(start), dtype=bool)
    jump = np.full(len(start), np.nan)
    turn = np.full(len(start), np.nan)
    for i, s in enumerate(start):
        # One window's pairs at a time: a long log never holds (K, 3, 3) products.
        k = np.arange(s, min(s + size, pairs))
        P = np.einsum("kji,kjl->kil", orientation[k + n], orientation[k])    # Q_j^T Q_k
        lhs = np.eye(3) - P
        rhs = field[k + n] - np.einsum("kil,kl->ki", P, field[k])
        good = np.isfinite(lhs).all(axis=(1, 2)) & np.isfinite(rhs).all(axis=1)
        if good.sum() < 3:
            continue
        A, b = lhs[good], rhs[good]
        cos_turn = np.clip((np.trace(P[good], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        jump[i] = float(np.linalg.norm(b, axis=1).max())
        turn[i] = float(np.degrees(np.arccos(cos_turn.min())))
        A2, b2 = A.reshape(-1, 3), b.reshape(-1)
        if np.linalg.svd(A2, compute_uv=False)[-1] >= floor * np.sqrt(good.sum()):
            turning[i] = True
            offset[i] = np.linalg.lstsq(A2, b2, rcond=None)[0]
    return OffsetWindows(start, stop, offset, turning, jump, turn)


@dataclass(frozen=True)
class OffsetSegment:
    """Windows ``first..last`` (inclusive) that share one offset.

    Attributes
    ----------
    first, last : int
        Window indices.
    offset : ndarray, shape (3,)
        Median offset of its turning windows (NaN when none turns).
    turning : int
        Its turning windows that agree with ``offset``.
    outliers : tuple of int
        Turning windows inside it whose offset departs from it for less than ``persist``
        windows (set aside, not a change).
    """

    first: int
    last: int
    offset: np.ndarray
    turning: int
    outliers: tuple


def offset_segments(windows: OffsetWindows, tol: float, *, persist: int = 2,
                    jump_tol: float | None = None,
                    still_deg: float = 2.5) -> list[OffsetSegment]:
    """Cut the windows into segments of one offset.

    A segment ends where ``persist`` consecutive turning windows agree with one another and
    differ from the segment's offset by more than ``tol`` (the new offset starts the next
    segment), or where a still window (no pair turns more than ``still_deg``, so that an
    offset hardly shows) has a jump above ``jump_tol`` (default ``tol``): a field that changes
    while the sensor is still. Fewer departing windows are outliers of the segment. Other
    windows belong to the segment they lie in. Neighbouring segments whose offsets agree
    within ``tol`` are joined (a jump at rest that came back).

    Parameters
    ----------
    windows : OffsetWindows
        From :func:`window_offsets`.
    tol : float
        Largest offset difference within a segment (units of the field).
    persist : int
        Consecutive departing windows that make a change.
    jump_tol : float, optional
        The jump at rest that makes a change.
    """
    jump_tol = tol if jump_tol is None else jump_tol
    W = len(windows.start)
    segments: list[OffsetSegment] = []
    first, members, outliers = 0, [], []
    pending: list[int] = []

    def close(last: int) -> None:
        ref = (np.median(windows.offset[members], axis=0) if members
               else np.full(3, np.nan))
        segments.append(OffsetSegment(first, last, ref, len(members), tuple(outliers)))

    i = 0
    while i < W:
        if windows.turning[i]:
            c = windows.offset[i]
            ref = np.median(windows.offset[members], axis=0) if members else None
            if ref is None or np.linalg.norm(c - ref) <= tol:
                outliers.extend(pending)
                pending = []
                members.append(i)
            else:
                pending.append(i)
                new = windows.offset[pending]
                if len(pending) >= 2 and np.linalg.norm(new[-1] - new[-2]) > tol:
                    outliers.extend(pending[:-1])          # not one new offset: outliers
                    pending = pending[-1:]
                if len(pending) >= persist:
                    # Windows after the last agreeing one hold the change: in neither part.
                    outliers.extend(range(members[-1] + 1, pending[0]))
                    close(pending[0] - 1)
                    first, members, outliers, pending = pending[0], list(pending), [], []
        elif windows.turn_deg[i] < still_deg and windows.jump[i] > jump_tol:
            outliers.extend(pending)
            pending = []
            close(i)
            first, members, outliers = i + 1, [], []
        i += 1
    outliers.extend(pending)
    if first < W:
        close(W - 1)
    joined: list[OffsetSegment] = []
    for seg in (s for s in segments if s.last >= s.first):
        prev = joined[-1] if joined else None
        if prev is not None and prev.turning and seg.turning and \
                np.linalg.norm(prev.offset - seg.offset) <= tol:
            w = np.array([prev.turning, seg.turning], dtype=float)
            offset = (w[0] * prev.offset + w[1] * seg.offset) / w.sum()
            joined[-1] = OffsetSegment(prev.first, seg.last, offset,
                                       prev.turning + seg.turning,
                                       prev.outliers + seg.outliers)
        else:
            joined.append(seg)
    return joined


def consistent_rows(windows: OffsetWindows, segments: list[OffsetSegment],
                    n_rows: int) -> tuple[np.ndarray, OffsetSegment]:
    """Rows of the segment with most turning windows (ties: the longer), its outlier windows
    left out; and that segment.

    Returns
    -------
    ndarray of bool, shape (n_rows,)
    OffsetSegment
    """
    best = max(segments, key=lambda s: (s.turning, s.last - s.first))
    keep = np.zeros(n_rows, dtype=bool)
    keep[windows.start[best.first]:windows.stop[best.last]] = True
    if best.last == len(windows.start) - 1:
        keep[windows.stop[best.last]:] = True                 # the rows after the last window
    for i in best.outliers:
        keep[windows.start[i]:windows.stop[i]] = False
    return keep, best
