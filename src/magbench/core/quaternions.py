"""Unit quaternions: Hamilton product, rotation of vectors, conversion to and from matrices.

Scalar first, ``q = (w, x, y, z)``, Hamilton convention; an attitude ``q`` maps sensor axes to
world axes, ``v_world = q v_sensor q*`` (the convention of the BROAD recordings and of the
attitude columns magbench reads). Arrays are ``(..., 4)``; every function broadcasts.

The arithmetic is :class:`scipy.spatial.transform.Rotation`'s (active rotations, Hamilton
product, the same convention): these functions only fix the scalar-first layout, broadcast, and
carry NaN rows through as NaN (scipy refuses them). scipy normalises every quaternion it is
given, so a quaternion that is not unit is read as the rotation it points to.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from magbench.core.rotations import rotation_class, span_deg

__all__ = [
    "BLOCK_ROWS",
    "MatrixView",
    "UnitRows",
    "blocks",
    "finite_rows",
    "matrix_to_quat",
    "quat_about_axis",
    "quat_conjugate",
    "quat_multiply",
    "quat_rotate",
    "quat_span_deg",
    "quat_to_matrix",
    "quat_to_rotvec",
    "unit_quaternions",
]


def _rowwise(fn: Callable[..., np.ndarray], out_tail: tuple[int, ...],
             *arrays: tuple[np.ndarray, int]) -> np.ndarray:
    """``fn`` over the broadcast rows of ``arrays`` (each ``(array, trailing ndim)``), with NaN
    out where any input row is not finite or is a zero quaternion."""
    lead = np.broadcast_shapes(*(a.shape[:a.ndim - nd] for a, nd in arrays))
    flat = [np.broadcast_to(a, lead + a.shape[a.ndim - nd:]).reshape((-1,) + a.shape[a.ndim - nd:])
            for a, nd in arrays]
    ok = np.ones(len(flat[0]), dtype=bool) if flat else np.ones(0, dtype=bool)
    for f in flat:
        ok &= np.isfinite(f.reshape(len(f), -1)).all(axis=1)
        if f.shape[1:] == (4,):
            ok &= np.any(f != 0, axis=1)
    out = np.full((len(ok),) + out_tail, np.nan)
    if ok.any():
        out[ok] = fn(*(f[ok] for f in flat))
    return out.reshape(lead + out_tail)


def _rot(q: np.ndarray) -> object:
    return rotation_class().from_quat(q, scalar_first=True)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p q`` of ``(..., 4)`` quaternions (scalar first): the rotation ``q``
    then ``p``."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    return _rowwise(lambda a, b: (_rot(a) * _rot(b)).as_quat(scalar_first=True), (4,),
                    (p, 1), (q, 1))


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """``q* = (w, -x, -y, -z)``: the inverse rotation of a unit quaternion."""
    # A sign flip, exact; scipy's inv() would also normalise.
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions: ``R v = q v q*``."""
    q = np.asarray(q, dtype=float)
    return _rowwise(lambda a: _rot(a).as_matrix(), (3, 3), (q, 1))


#: Rows turned into matrices at a time by :class:`MatrixView`'s users: a long log's
#: ``(K, 3, 3)`` matrices are 72 bytes a sample, three times its compass samples.
BLOCK_ROWS = 1 << 14


def unit_quaternions(q: np.ndarray) -> np.ndarray:
    """``q`` (a fresh float array of ``(n, 4)`` quaternions) normalised in place, row by row
    (each row by its own norm), a zero row made NaN."""
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q /= np.where(norm > 0, norm, np.nan)
    return q


class UnitRows:
    """Unit quaternions of four ``(K,)`` columns (``w, x, y, z``), made only for the rows
    indexed: ``view[rows]`` is :func:`unit_quaternions` of those rows stacked (row by row the
    numbers of the whole ``(K, 4)`` array normalised), so a long log's attitude is read a
    block at a time without its normalised ``(K, 4)`` copy (32 bytes a sample).

    The rows are stacked as columns (each contiguous in memory), the layout of
    :meth:`magbench.sources.recordings.Recording.stack`."""

    def __init__(self, columns: Sequence[np.ndarray], index: np.ndarray | None = None) -> None:
        if len(columns) != 4:
            raise ValueError(f"UnitRows takes 4 columns (w, x, y, z), got {len(columns)}")
        self.columns = [np.asarray(c) for c in columns]
        self.index = index
        self.shape = (len(self.columns[0]) if index is None else len(index), 4)
        self.ndim = 2

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, rows: slice | np.ndarray) -> np.ndarray:
        rows = rows if self.index is None else self.index[rows]
        return unit_quaternions(np.array([np.asarray(c[rows], dtype=float)
                                          for c in self.columns]).T)

    def take(self, index: np.ndarray) -> UnitRows:
        """The view of rows ``index`` (integers) of this one: 8 bytes a row, not 32."""
        return UnitRows(self.columns, index if self.index is None else self.index[index])


def finite_rows(q: np.ndarray | UnitRows) -> np.ndarray:
    """Which rows of ``(K, d)`` values (an array or a :class:`UnitRows`) are all finite,
    read a block at a time."""
    if isinstance(q, np.ndarray):
        return np.isfinite(q).all(axis=1)
    ok = np.empty(len(q), dtype=bool)
    for rows in blocks(len(q)):
        ok[rows] = np.isfinite(q[rows]).all(axis=1)
    return ok


class MatrixView:
    """The rotation matrices of ``(K, 4)`` quaternions (an array or a :class:`UnitRows`),
    made only for the rows indexed: ``view[rows]`` is ``quat_to_matrix(q[rows])`` (row by
    row the same numbers), so code written for a ``(K, 3, 3)`` array can walk a long
    attitude a block at a time."""

    def __init__(self, q: np.ndarray | UnitRows) -> None:
        self.q = q if isinstance(q, UnitRows) else np.asarray(q, dtype=float)
        self.shape = (len(self.q), 3, 3)

    def __len__(self) -> int:
        return len(self.q)

    def __getitem__(self, rows: slice | np.ndarray) -> np.ndarray:
        return quat_to_matrix(self.q[rows])


def blocks(K: int, size: int | None = None) -> list[slice]:
    """Consecutive slices of ``size`` rows (default :data:`BLOCK_ROWS`) covering ``K``."""
    size = size or BLOCK_ROWS
    return [slice(s, min(s + size, K)) for s in range(0, K, size)]


def quat_span_deg(q: np.ndarray) -> float:
    """:func:`magbench.core.rotations.span_deg` of the matrices of ``(K, 4)`` quaternions (or
    of a :class:`MatrixView`), a block at a time: the largest angle from the first (0 when
    empty)."""
    view = q if isinstance(q, MatrixView) else MatrixView(q)
    if not len(view):
        return 0.0
    first = view[:1]
    return max(span_deg(np.concatenate([first, view[rows]])) for rows in blocks(len(view)))


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``q v q*`` for ``(..., 4)`` unit quaternions and ``(..., 3)`` vectors."""
    q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
    return _rowwise(lambda a, b: _rot(a).apply(b), (3,), (q, 1), (v, 1))


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (``w >= 0``) of ``(..., 3, 3)`` rotation matrices."""
    R = np.asarray(R, dtype=float)
    Rotation = rotation_class()
    return _rowwise(lambda a: Rotation.from_matrix(a).as_quat(canonical=True, scalar_first=True),
                    (4,), (R, 2))


def quat_about_axis(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """The rotation by ``angle`` (radians, right-handed) about ``axis`` (normalised here)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.asarray(angle, dtype=float)[..., None]
    # from_rotvec keeps cos(angle/2) as w (no sign canonicalisation), as the formula does.
    Rotation = rotation_class()
    return _rowwise(lambda a, t: Rotation.from_rotvec(a * t).as_quat(scalar_first=True), (4,),
                    (axis, 1), (angle, 1))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (axis times angle, radians, angle in ``[0, pi]``) of
    ``(..., 4)`` quaternions: the logarithm, taken the short way (``q`` and ``-q`` agree)."""
    q = np.asarray(q, dtype=float)
    return _rowwise(lambda a: _rot(a).as_rotvec(), (3,), (q, 1))
