"""Geometry of field directions: the Fibonacci lattice, sphere fit, coverage and thickness.

``thickness`` is the smallest over the largest singular value of the mean-centred samples (1 for
a full sphere, 0 for samples in a plane); below :data:`MIN_THICKNESS` the samples are "nearly
coplanar". ``coverage`` is the fraction of :data:`COVERAGE_GRID` Fibonacci directions lying
within :data:`COVERAGE_ANGLE_DEG` of some sample direction seen from the sphere-fit centre (1 for
a full sphere, about 0.5 for a hemisphere or for a single great circle, which is why both
figures are checked); below :data:`MIN_COVERAGE` the samples cover "too little of the sphere".

*Thinning by direction.* A recording that lies still for half its length holds half its samples
in one direction; a fit (and an outlier screen's median) then serves that one direction. As
ArduPilot's and PX4's calibrators do, :func:`thin_by_direction` caps the samples kept per
direction: the sphere is cut into :data:`DIRECTION_CELLS` nearly equal-area cells (the nearest
point of a Fibonacci lattice, cells about 10 deg across) and no cell keeps more than
:data:`CELL_CAP_FACTOR` times the median count of the occupied cells (at least
:data:`CELL_CAP_MIN`), evenly spread in time. A still stretch then counts as one direction, while
an evenly turned recording loses nothing (its cells hold about the median). The directions need
a centre that a still stretch cannot pull: :func:`distinct_rows` keeps one sample per occupied
cube of a grid over the samples' range (no centre needed), from which a sphere fit is taken.

*Memory.* ``calibrate`` screens every sample of a recording (10 million rows are 240 MB of
samples), so the helpers that see every row work a block of :data:`BLOCK_ROWS` rows at a time
(:func:`row_norms`, :func:`direction_cells`, :func:`distinct_rows`, :func:`sphere_fit`),
instead of building ``(K, 3)`` temporaries such as ``y - centre``. Each row goes through the same
operations as in one whole-array expression, so the values are the same to the last bit; the
sphere fit of more than one block is the exception: its least squares are solved by TSQR
(:mod:`magbench.core.tsqr`), equal to ``lstsq`` on the whole design to round-off.
"""

from __future__ import annotations

import math

import numpy as np

from magbench.core.tsqr import lstsq_blocks

__all__ = ["BLOCK_ROWS", "CELL_CAP_FACTOR", "CELL_CAP_MIN", "COVERAGE_ANGLE_DEG",
           "COVERAGE_GRID", "DIRECTION_CELLS", "GOLDEN_RATIO", "MIN_COVERAGE", "MIN_THICKNESS",
           "band_half_width", "check_geometry", "column_medians", "coverage", "direction_cells",
           "distinct_rows", "fibonacci_sphere", "largest_gap", "row_norms", "sphere_fit",
           "thickness", "thin_by_direction", "unit_rows"]

GOLDEN_RATIO = (1.0 + np.sqrt(5.0)) / 2.0
COVERAGE_GRID = 200
COVERAGE_ANGLE_DEG = 30.0
MIN_COVERAGE = 0.3
MIN_THICKNESS = 0.1
#: Equal-area direction cells of :func:`direction_cells` (each about 10 deg across).
DIRECTION_CELLS = 400
#: A cell keeps at most this many times the median count of the occupied cells ...
CELL_CAP_FACTOR = 10.0
#: ... and never fewer than this many samples.
CELL_CAP_MIN = 3
#: :func:`distinct_rows`'s cube edge is this fraction of the samples' typical separation.
DISTINCT_GRID = 20
#: Rows per block of the helpers that see every sample (module notes, *Memory*): a block's
#: temporaries take a few MB whatever the recording's length.
BLOCK_ROWS = 1 << 16


def _blocks(n: int):
    """``slice`` objects of :data:`BLOCK_ROWS` rows covering ``range(n)``."""
    return (slice(start, start + BLOCK_ROWS) for start in range(0, n, BLOCK_ROWS))


def row_norms(y: np.ndarray, centre: np.ndarray | None = None) -> np.ndarray:
    """Euclidean norm of every row of ``y - centre``, a block of rows at a time.

    Parameters
    ----------
    y : array_like, shape (K, 3)
        Samples.
    centre : array_like of shape (3,) or (K, 3), optional
        Subtracted from every row (a vector) or row by row (an array like ``y``); none by
        default.

    Returns
    -------
    ndarray, shape (K,)
        Equal to the last bit to ``np.linalg.norm(y - centre, axis=1)``, without its two
        ``(K, 3)`` temporaries (the difference and its square).
    """
    y = np.asarray(y, dtype=float)
    c = None if centre is None else np.asarray(centre, dtype=float)
    out = np.empty(y.shape[0])
    for rows in _blocks(y.shape[0]):
        block = y[rows] if c is None else y[rows] - (c[rows] if c.ndim == 2 else c)
        out[rows] = np.linalg.norm(block, axis=1)
    return out


def column_medians(y: np.ndarray) -> np.ndarray:
    """``np.median(y, axis=0)``, one column at a time: the same values (a median selects
    them), with a copy of one column instead of all of them for the partition."""
    y = np.asarray(y, dtype=float)
    return np.array([np.median(y[:, j]) for j in range(y.shape[1])])


def fibonacci_sphere(K: int, radius: float = 1.0,
                     z_range: tuple[float, float] = (-1.0, 1.0)) -> np.ndarray:
    """K nearly uniform directions on a sphere (Algorithm 8, steps 2-3).

    Parameters
    ----------
    K : int
        Number of directions.
    radius : float
        Sphere radius r.
    z_range : (float, float)
        Restrict the lattice to the zone ``z_low <= z / r <= z_high`` (a cap or a band), still
        evenly spread over it. The default is the whole sphere, exactly Algorithm 8.

    Returns
    -------
    ndarray, shape (K, 3)
        ``[r cos(theta) sin(phi), r sin(theta) sin(phi), r cos(phi)]`` with
        ``theta = 2 pi k / golden_ratio`` and ``phi = arccos(1 - 2 (k - 0.5) / K)``, k = 1..K
        (for the whole sphere; a zone maps ``1 - 2 (k - 0.5) / K`` linearly onto it).
    """
    k = np.arange(1, K + 1, dtype=float)
    theta = 2.0 * np.pi * k / GOLDEN_RATIO
    z_low, z_high = z_range
    if (z_low, z_high) == (-1.0, 1.0):
        cos_phi = 1.0 - 2.0 * (k - 0.5) / K
    else:
        cos_phi = z_high - (z_high - z_low) * (k - 0.5) / K
    phi = np.arccos(cos_phi)
    return radius * np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                                     np.cos(phi)])


def sphere_fit(y: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Centre ``c`` and radius ``r`` of the linear least-squares sphere fit.

    ``||y||^2 = 2 c.y + (r^2 - ||c||^2)`` is linear in ``c`` and ``d = r^2 - ||c||^2``.
    ``T = r I, h = c`` is the simplest calibration (hard iron and one scale), the real-data
    baseline of :func:`is_meaningful`. Computed here, not taken from the registry, so the
    baseline stays fixed whatever methods are registered.

    Parameters
    ----------
    y : array_like, shape (K, 3)
        Samples.
    rows : ndarray of bool, shape (K,), optional
        Fit only these rows: the same answer as ``sphere_fit(y[rows])`` without the copy of
        the selected samples.

    Returns
    -------
    centre : ndarray, shape (3,)
    radius : float

    Notes
    -----
    At most :data:`BLOCK_ROWS` rows are solved by ``np.linalg.lstsq`` on the design matrix
    ``[2 z, 1]`` (``z = y / scale``); more rows a block at a time by TSQR
    (:func:`magbench.core.tsqr.lstsq_blocks`), in memory of one block.
    """
    y = np.asarray(y, dtype=float)
    n = y.shape[0] if rows is None else int(np.count_nonzero(rows))
    if n <= BLOCK_ROWS:
        c, r2, scale = _sphere_fit_whole(y, rows, n)
    else:
        c, r2, scale = _sphere_fit_blocks(y, rows)
    if not r2 > 0:
        raise ValueError("the sphere fit has no real radius; the samples do not lie near a "
                         "sphere or ellipsoid")
    return c * scale, math.sqrt(r2) * scale


def _sphere_fit_whole(y: np.ndarray, rows: np.ndarray | None, n: int
                      ) -> tuple[np.ndarray, float, float]:
    """:func:`sphere_fit` of at most one block by ``lstsq`` on the whole design: centre and
    squared radius over ``scale``, and ``scale``."""
    # The design matrix [2 z, 1] is filled in place, its first three columns first holding the
    # samples and then z = y / scale.
    A = np.empty((n, 4))
    z = A[:, :3]
    z[...] = y if rows is None else y[rows]
    squares = np.einsum("ij,ij->i", z, z)
    scale = float(np.sqrt(np.mean(squares))) or 1.0
    z /= scale
    np.einsum("ij,ij->i", z, z, out=squares)
    z *= 2.0
    A[:, 3] = 1.0
    sol = np.linalg.lstsq(A, squares, rcond=None)[0]
    c = sol[:3]
    return c, float(sol[3] + c @ c), scale


def _sphere_fit_blocks(y: np.ndarray, rows: np.ndarray | None
                       ) -> tuple[np.ndarray, float, float]:
    """:func:`sphere_fit` of many blocks by TSQR (:func:`magbench.core.tsqr.lstsq_blocks`):
    the same answer as :func:`_sphere_fit_whole` to round-off, without the design matrix and
    LAPACK's copies of it (five times the samples' bytes)."""
    total, n = 0.0, 0
    for z in _selected_blocks(y, rows):
        total += float(np.einsum("ij,ij->", z, z))
        n += z.shape[0]
    scale = math.sqrt(total / n) or 1.0

    def design():
        for block in _selected_blocks(y, rows):
            A = np.empty((block.shape[0], 4))
            z = A[:, :3]
            np.divide(block, scale, out=z)
            squares = np.einsum("ij,ij->i", z, z)
            z *= 2.0
            A[:, 3] = 1.0
            yield A, squares

    sol = lstsq_blocks(design())[0]
    c = sol[:3]
    return c, float(sol[3] + c @ c), scale


def _selected_blocks(y: np.ndarray, rows: np.ndarray | None):
    """The rows of ``y`` selected by the mask ``rows`` (all without one), in order, as arrays
    of :data:`BLOCK_ROWS` rows (the last may be shorter): the same blocks as
    ``y[rows]`` cut into blocks, so a mask and a copy give the same answer to the last bit."""
    if rows is None:
        yield from (y[block] for block in _blocks(y.shape[0]))
        return
    pending: list[np.ndarray] = []
    size = 0
    for block in _blocks(y.shape[0]):
        chosen = y[block][rows[block]]
        while chosen.shape[0]:
            part = chosen[:BLOCK_ROWS - size]
            chosen = chosen[part.shape[0]:]
            pending.append(part)
            size += part.shape[0]
            if size == BLOCK_ROWS:
                yield np.concatenate(pending)
                pending, size = [], 0
    if size:
        yield np.concatenate(pending)


def unit_rows(x: np.ndarray) -> np.ndarray:
    """The non-zero rows of ``x`` scaled to unit norm."""
    n = np.sqrt(np.einsum("ij,ij->i", x, x))
    return x[n > 0] / n[n > 0, None]


#: Samples in the thinned first pass of :func:`coverage` (see :func:`_first_pass`).
_FIRST_PASS = 1024


def _max_cosines(grid: np.ndarray, u: np.ndarray) -> np.ndarray:
    """For every row of ``grid``, the largest cosine to a row of ``u`` (unit rows)."""
    best = np.full(grid.shape[0], -1.0)
    for start in range(0, u.shape[0], 4096):      # bounded memory for long recordings
        best = np.maximum(best, (grid @ u[start:start + 4096].T).max(axis=1))
    return best


def _first_pass(u: np.ndarray) -> np.ndarray:
    """About :data:`_FIRST_PASS` of the rows of ``u``, evenly spread over the recording.

    A maximum over some of the samples never exceeds the maximum over all, so a grid direction
    near one of them is covered: the first pass settles most directions, and only the others
    are compared with every sample. Same answer, a third of the time at K = 10 000
    (``calibrate`` computes coverage two dozen times per file). :func:`largest_gap` needs every
    direction's exact nearest sample and gains little from it on a full sphere.
    """
    return u[::max(1, u.shape[0] // _FIRST_PASS)]


def coverage(directions: np.ndarray, *, grid: int = COVERAGE_GRID,
             angle_deg: float = COVERAGE_ANGLE_DEG) -> float:
    """Fraction of ``grid`` Fibonacci directions within ``angle_deg`` of a given direction.

    ``directions`` need not be normalised. A full sphere gives 1, a hemisphere about 0.5 + the
    margin, a cap of angular radius theta about ``(1 - cos(theta + angle)) / 2``.
    """
    u = unit_rows(np.asarray(directions, dtype=float))
    if u.shape[0] == 0:
        return 0.0
    g = fibonacci_sphere(grid)
    cos_limit = math.cos(math.radians(angle_deg))
    covered = _max_cosines(g, _first_pass(u)) >= cos_limit
    rest = ~covered
    if rest.any():
        covered[rest] = _max_cosines(g[rest], u) >= cos_limit
    return float(np.mean(covered))


def largest_gap(directions: np.ndarray, *, grid: int = 2000) -> tuple[float, np.ndarray]:
    """The largest cap of directions holding no sample: its angular radius and its centre.

    Parameters
    ----------
    directions : array_like, shape (K, 3)
        Sample directions (need not be normalised).
    grid : int
        Fibonacci directions tried as the centre (2000 resolve the radius to about 3 deg).

    Returns
    -------
    radius_deg : float
        Angle in degrees from the centre to the nearest sample: 180 - theta for samples filling
        a cap of half-angle theta (90 for a hemisphere), small for a full sphere.
    centre : ndarray, shape (3,)
        The unit direction farthest from every sample (the middle of the uncovered region).
    """
    u = unit_rows(np.asarray(directions, dtype=float))
    g = fibonacci_sphere(grid)
    if u.shape[0] == 0:
        return 180.0, g[0]
    nearest = _max_cosines(g, u)
    worst = int(np.argmin(nearest))
    return math.degrees(math.acos(min(1.0, float(nearest[worst])))), g[worst]


def thickness(y: np.ndarray) -> float:
    """Smallest over largest singular value of the mean-centred samples (0 = coplanar)."""
    s = np.linalg.svd(np.asarray(y, float) - np.mean(y, axis=0), compute_uv=False)
    return float(s[2] / s[0]) if s[0] > 0 else 0.0


def check_geometry(y: np.ndarray, *, min_coverage: float = MIN_COVERAGE,
                   min_thickness: float = MIN_THICKNESS, what: str = "samples") -> None:
    """Reject samples that are nearly coplanar or cover too little of the sphere.

    Raises
    ------
    ValueError
        With the figure that failed and the threshold (see the module notes for definitions).
    """
    th = thickness(y)
    if th < min_thickness:
        raise ValueError(f"{what}: samples are nearly coplanar (thickness {th:.3g}: smallest/"
                         f"largest singular value of the centred samples; at least "
                         f"{min_thickness:g} is needed); rotate the sensor about more than "
                         "one axis")
    c, _ = sphere_fit(y)
    cov = coverage(y - c)
    if cov < min_coverage:
        raise ValueError(f"{what}: samples cover too little of the sphere (coverage {cov:.2f}: "
                         f"fraction of {COVERAGE_GRID} evenly spread directions within "
                         f"{COVERAGE_ANGLE_DEG:g} deg of a sample direction seen from the "
                         f"sphere-fit centre; at least {min_coverage:g} is needed); point the "
                         "sensor in more directions")


def direction_cells(directions: np.ndarray, *, cells: int = DIRECTION_CELLS,
                    centre: np.ndarray | None = None) -> np.ndarray:
    """Index of the equal-area cell of each row's direction (about ``cells`` cells).

    The cells are a grid in ``z`` (the unit direction's third component) and longitude: the
    area element of the unit sphere is ``dz dphi``, so equal steps in both give equal areas
    (Archimedes' hat-box theorem). ``sqrt(cells / 2)`` bands of ``z`` and twice as many
    longitude steps make equatorial cells about as tall as wide. Rows need not be normalised;
    a zero row gets the cell of +X. With ``centre`` (shape (3,)), the directions are
    ``directions - centre``, taken a block of rows at a time (module notes, *Memory*).
    """
    d = np.asarray(directions, dtype=float)
    c = None if centre is None else np.asarray(centre, dtype=float)
    bands = max(1, round(math.sqrt(cells / 2.0)))
    # two bytes a sample, not eight, for the usual few hundred cells: the cells of every
    # sample (and the copies a caller's np.unique makes) are a long recording's arrays
    small = 2 * bands * bands <= 1 << 15
    out = np.empty(d.shape[0], dtype=np.int16 if small else np.int64)
    for rows in _blocks(d.shape[0]):
        block = d[rows] if c is None else d[rows] - c
        n = np.sqrt(np.einsum("ij,ij->i", block, block))
        n[n == 0] = 1.0
        z = np.clip(block[:, 2] / n, -1.0, 1.0)
        band = np.minimum(((z + 1.0) * (bands / 2.0)).astype(np.int64), bands - 1)
        phi = np.arctan2(block[:, 1], block[:, 0]) + np.pi
        step = np.minimum((phi * (bands / np.pi)).astype(np.int64), 2 * bands - 1)
        out[rows] = band * (2 * bands) + step
    return out


def thin_by_direction(directions: np.ndarray, *, cells: int = DIRECTION_CELLS,
                      cap_factor: float = CELL_CAP_FACTOR, cap_min: int = CELL_CAP_MIN,
                      centre: np.ndarray | None = None) -> np.ndarray:
    """Mask of the samples kept when no direction cell holds more than its share.

    Parameters
    ----------
    directions : ndarray, shape (K, 3)
        Field directions (samples minus a centre), in time order.
    cells : int
        Equal-area cells (:func:`direction_cells`).
    cap_factor, cap_min : float, int
        A cell keeps at most ``max(cap_min, ceil(cap_factor * median))`` samples, the median
        taken over the occupied cells' counts (see the module notes).
    centre : ndarray, shape (3,), optional
        Subtract it from ``directions`` (samples), block by block (:func:`direction_cells`).

    Returns
    -------
    ndarray of bool, shape (K,)
        True for a kept sample; in a capped cell the kept ones are evenly spread in time.
    """
    cell = direction_cells(directions, cells=cells, centre=centre)
    counts = np.bincount(cell)
    cap = max(int(cap_min), math.ceil(cap_factor * float(np.median(counts[counts > 0]))))
    keep = np.ones(cell.size, dtype=bool)
    over = counts[cell] > cap
    if not over.any():
        return keep
    members = np.flatnonzero(over)
    members = members[np.argsort(cell[members], kind="stable")]     # by cell, then time
    start = np.searchsorted(cell[members], cell[members])
    rank = np.arange(members.size) - start                          # position within its cell
    size = counts[cell[members]]
    # a cell of n samples keeps positions round(s (n - 1) / (cap - 1)), s = 0 .. cap - 1 (steps
    # above 1, so distinct); position j is one of them when it is that of its nearest s
    spacing = (size - 1) / (cap - 1)
    keep[members] = np.round(np.round(rank / spacing) * spacing) == rank
    return keep


def distinct_rows(y: np.ndarray, *, grid: int = DISTINCT_GRID) -> np.ndarray:
    """Indices of one sample per occupied cube of a grid over the samples (first in time).

    The cube's edge is ``1 / grid`` of the upper quartile of the distances between samples half
    a recording apart in time (about the field radius for a recording that turns; robust to
    spikes and to a still stretch of up to about seven eighths of the recording, which a range
    or a spread of the samples is not). Needs no centre: a still stretch falls in a few cubes
    whatever the offset.
    """
    y = np.asarray(y, dtype=float)
    half = y.shape[0] // 2
    if half == 0:
        return np.arange(y.shape[0])
    size = float(np.percentile(row_norms(y[half:2 * half], y[:half]), 75)) / grid
    if not size > 0:
        return np.arange(y.shape[0])
    median = column_medians(y)
    flat = np.empty(y.shape[0], dtype=np.int64)
    for rows in _blocks(y.shape[0]):
        keys = np.floor((y[rows] - median) / size).astype(np.int64)
        # one integer per cube (a rare collision far out merges two cubes, which does no harm)
        flat[rows] = (keys[:, 0] * 2_097_143 + keys[:, 1]) * 2_097_169 + keys[:, 2]
    _, first = np.unique(flat, return_index=True)
    return np.sort(first)


def band_half_width(directions: np.ndarray) -> float:
    """Half-width in degrees of the band about a plane holding 95 % of the directions.

    The plane is the one through the origin closest to the unit directions (normal: the
    eigenvector of the smallest eigenvalue of their second moment); about 72 for a full
    sphere, about 44 for a 60 deg cap, about 15 for directions within +-15 deg of a great circle.
    """
    u = unit_rows(np.asarray(directions, dtype=float))
    if u.shape[0] < 3:
        return 0.0
    _, vectors = np.linalg.eigh(u.T @ u)
    off = np.abs(u @ vectors[:, 0])
    return math.degrees(math.asin(min(1.0, float(np.percentile(off, 95)))))
