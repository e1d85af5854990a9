"""Outliers and collapsed fits: what ``calibrate`` sets aside and what it refuses to write.

*Outliers.* A calibration maps every good sample onto the unit sphere, so the norm residual
``r_k = ||A (y_k - b)|| - 1`` (the quantity squared in J_r, eq. 81) is small for all of them;
a spike (a bad read, a bit flip) or a magnetic disturbance (a magnet or a motor near the
sensor) gives a large one. :func:`outliers` flags residuals more than :data:`CUTOFF` robust
standard deviations (1.4826 median absolute deviations, consistent with a Gaussian's sigma)
from their median, and never a deviation below :data:`FLOOR` (0.1 % of the field), so that
noise-free or very quiet data are not trimmed by round-off. The statistics come from the
current inliers and the limit is applied to every sample, so a sample set aside early can come
back once the fit improves (iterative trimming, a few rounds until the set stops changing).

*A first robust fit* (:func:`robust_sphere_fit`). Spikes ten times the field drag a least-squares
fit of any model, so the first round does not fit at all: it measures the distance of every
sample from the coordinate-wise median of the samples against the median distance. Later
rounds use the linear least-squares sphere fit of the inliers
(:func:`magbench.core.geometry.sphere_fit`). The sphere fit cannot represent soft iron, so its
residuals are wider than a full model's; that only makes this first screen lenient, and the
chosen method's own residuals are trimmed afterwards (:mod:`magbench.pipeline.screening`).

*Collapsed fits* (:func:`refusal_reason`). J_r has a degenerate minimiser: with ``h`` far
away and a large ``T``, every corrected sample lands near one point of the unit sphere and
J_r tends to 0 (see :mod:`magbench.pipeline.fitting`). Such a fit, a near-singular ``A`` or a
non-finite answer is refused, never written.

*Still stretches* (:func:`screen`). A recording that lies still for half its length puts half
its samples at one point: the median of the first round sits there, and the rotation is set
aside as outliers. :func:`screen` therefore takes its centre from the distinct samples
(:func:`magbench.core.geometry.distinct_rows`), thins the samples by direction around it
(:func:`magbench.core.geometry.thin_by_direction`), fits the robust sphere on the thinned ones
and applies its limit to every sample. A screen that would empty most of the occupied direction
cells is not applied (:func:`keeps_directions`): outliers are the few, never the directions.

*Memory.* :func:`screen` sees every sample of the recording, so it builds no array of the
samples' size beyond the kept ones: norms, medians, direction cells and the sphere fit's design
matrix are taken block by block or in place (:mod:`magbench.core.geometry`, *Memory*), with the
same values as the whole-array expressions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magbench.core.geometry import (
    BLOCK_ROWS,
    column_medians,
    direction_cells,
    distinct_rows,
    row_norms,
    sphere_fit,
    thin_by_direction,
    unit_rows,
)

__all__ = ["COLLAPSE_RATIO", "CUTOFF", "FLOOR", "MAD_SCALE", "MAX_CONDITION", "Screen",
           "corrected_norms", "keeps_directions", "norm_residuals", "outliers", "refusal_reason",
           "resultant_length", "robust_sphere_fit", "screen", "trimmed"]

MAD_SCALE = 1.4826
#: Robust standard deviations from the median beyond which a norm residual is an outlier.
CUTOFF = 5.0
#: Relative deviations from the field magnitude that are never called outliers (0.1 %).
FLOOR = 1e-3
#: Largest accepted condition number of ``T``: a magnetometer's scale factors differ by tens
#: of percent, never by a factor of 100.
MAX_CONDITION = 100.0
#: A fit is collapsed when ``1 - R`` of its corrected directions (R the length of the mean unit
#: vector; 0 for a full sphere, 1 for one direction) is below this share of the sphere fit's.
COLLAPSE_RATIO = 0.25


def outliers(residuals: np.ndarray, reference: np.ndarray | None = None, *,
             cutoff: float = CUTOFF, floor: float = FLOOR) -> np.ndarray:
    """Mask of the residuals farther than ``cutoff`` robust sigmas from the median.

    Parameters
    ----------
    residuals : ndarray, shape (K,)
        Relative norm residuals ``||m_k|| - 1``.
    reference : ndarray, optional
        The residuals the median and MAD are taken from (the current inliers); by default
        ``residuals`` itself.
    cutoff : float
        Limit in robust standard deviations (``1.4826 MAD``).
    floor : float
        Smallest limit: deviations below it are never outliers.

    Returns
    -------
    ndarray of bool, shape (K,)
        True for an outlier.
    """
    r = np.asarray(residuals, dtype=float)
    ref = r if reference is None else np.asarray(reference, dtype=float)
    med = float(np.median(ref))
    spread = MAD_SCALE * float(np.median(np.abs(ref - med)))
    return ~(np.abs(r - med) <= max(cutoff * spread, floor))


def robust_sphere_fit(y: np.ndarray, *, rounds: int = 5, cutoff: float = CUTOFF,
                      ) -> tuple[np.ndarray, float, np.ndarray]:
    """Sphere fit with iterative trimming of the norm residuals (see the module notes).

    Returns
    -------
    centre : ndarray, shape (3,)
    radius : float
    inliers : ndarray of bool, shape (K,)
        False for the samples set aside.
    """
    y = np.asarray(y, dtype=float)
    centre = column_medians(y)
    d = row_norms(y, centre)
    radius = float(np.median(d))
    d /= radius         # in place: the same values as d / radius - 1.0, one array fewer
    d -= 1.0
    inliers = ~outliers(d, cutoff=cutoff)
    del d
    for _ in range(rounds):
        if inliers.sum() < 4:
            break
        centre, radius = sphere_fit(y, None if inliers.all() else inliers)
        r = row_norms(y, centre)
        r /= radius
        r -= 1.0
        new = ~outliers(r, r[inliers], cutoff=cutoff)
        if np.array_equal(new, inliers):
            break
        inliers = new
    return centre, radius, inliers


def resultant_length(directions: np.ndarray) -> float:
    """Length of the mean unit vector of ``directions`` (0 for a full sphere, 1 for one
    direction)."""
    u = unit_rows(np.asarray(directions, dtype=float))
    return float(np.linalg.norm(u.mean(axis=0))) if len(u) else 1.0


def refusal_reason(T: np.ndarray, h: np.ndarray, y: np.ndarray, centre: np.ndarray) -> str:
    """Why the calibration ``T, h`` of ``y`` must not be written, or ``""`` if it may.

    Refused: a non-finite ``T`` or ``h``; ``cond(T)`` above :data:`MAX_CONDITION`; corrected
    directions that collapse (``1 - R`` below :data:`COLLAPSE_RATIO` times that of the
    directions ``y - centre`` seen from the sphere-fit centre); non-finite corrected samples.
    """
    T = np.asarray(T, dtype=float)
    h = np.asarray(h, dtype=float)
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(h))):
        return "the estimate is not finite"
    s = np.linalg.svd(T, compute_uv=False)
    if not s[-1] > 0 or s[0] / s[-1] > MAX_CONDITION:
        return (f"T is nearly singular (condition number "
                f"{s[0] / s[-1] if s[-1] > 0 else np.inf:.3g} > {MAX_CONDITION:g})")
    corrected = np.linalg.solve(T, (np.asarray(y, float) - h).T).T
    if not np.all(np.isfinite(corrected)):
        return "the corrected samples are not finite"
    spread = 1.0 - resultant_length(corrected)
    reference = 1.0 - resultant_length(np.asarray(y, float) - centre)
    if spread < COLLAPSE_RATIO * reference:
        return (f"the corrected field directions collapse toward one direction (mean unit "
                f"vector length {1 - spread:.2f}; {1 - reference:.2f} seen from the sphere "
                "fit's centre)")
    return ""


def keeps_directions(directions: np.ndarray, kept: np.ndarray, screened: np.ndarray, *,
                     centre: np.ndarray | None = None) -> bool:
    """Whether setting aside ``~screened`` leaves at least half of the direction cells that
    the ``kept`` samples occupy (see :func:`screen`); ``directions - centre`` with a
    ``centre``."""
    cell = direction_cells(directions, centre=centre)
    before = np.unique(cell[kept]).size
    after = np.unique(cell[kept & screened]).size
    return after >= 0.5 * before


@dataclass(frozen=True)
class Screen:
    """What :func:`screen` found: the centre and radius, and two masks over the samples.

    ``kept``: the samples left by thinning by direction; ``inliers``: not outliers. The fit
    uses ``kept & inliers``. ``applied`` is False when the outlier limit was not applied
    because it would have emptied most directions.
    """

    centre: np.ndarray
    radius: float
    kept: np.ndarray
    inliers: np.ndarray
    applied: bool = True

    @property
    def thinned(self) -> int:
        return int((~self.kept).sum())

    @property
    def work(self) -> np.ndarray:
        return self.kept & self.inliers


def screen(y: np.ndarray, *, cutoff: float = CUTOFF) -> Screen:
    """Thin by direction and set aside outliers, robust to still stretches (module notes).

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        Samples in time order.
    cutoff : float
        Outlier limit in robust standard deviations (:func:`outliers`).
    """
    y = np.asarray(y, dtype=float)
    distinct = distinct_rows(y)
    rough, _, _ = robust_sphere_fit(y[distinct], cutoff=cutoff)
    kept = thin_by_direction(y, centre=rough)
    # an evenly turned recording keeps every sample: no copy of them then
    centre, radius, _ = robust_sphere_fit(y if kept.all() else y[kept], cutoff=cutoff)
    residuals = row_norms(y, centre)
    residuals /= radius
    residuals -= 1.0
    return trimmed(Screen(centre, radius, kept, np.ones(len(y), dtype=bool)), residuals, y,
                   cutoff, centre=centre)


def corrected_norms(T: np.ndarray, h: np.ndarray, y: np.ndarray,
                    rows: np.ndarray | None = None) -> np.ndarray:
    """``||T^-1 (y_k - h)||`` for every sample (or those of the mask ``rows``), a block of
    rows at a time.

    Equal to the last bit to ``np.linalg.norm(np.linalg.solve(T, (y[rows] - h).T), axis=0)``
    (each block is solved with the same ``T``), without its ``(K, 3)`` temporaries: the
    selected rows, their difference, its transpose's solution and the solution's square.
    """
    T = np.asarray(T, dtype=float)
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    out = np.empty(y.shape[0] if rows is None else int(np.count_nonzero(rows)))
    filled = 0
    for start in range(0, y.shape[0], BLOCK_ROWS):
        block = y[start:start + BLOCK_ROWS]
        if rows is not None:
            block = block[rows[start:start + BLOCK_ROWS]]
        out[filled:filled + block.shape[0]] = np.linalg.norm(np.linalg.solve(T, (block - h).T),
                                                             axis=0)
        filled += block.shape[0]
    return out


def norm_residuals(T: np.ndarray, h: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``||T^-1 (y_k - h)|| - 1`` for every sample (:func:`corrected_norms`): the same values
    as ``np.linalg.norm(np.linalg.solve(T, (y - h).T), axis=0) - 1.0``."""
    out = corrected_norms(T, h, y)
    out -= 1.0
    return out


def trimmed(current: Screen, residuals: np.ndarray, directions: np.ndarray,
            cutoff: float = CUTOFF, *, centre: np.ndarray | None = None) -> Screen:
    """``current`` with its inliers recomputed from ``residuals`` (every sample), the
    statistics taken over its thinned inliers; unchanged inliers when the new ones would empty
    most direction cells (:func:`keeps_directions`). With ``centre``, ``directions`` are the
    samples and their directions ``directions - centre``, never built whole."""
    reference = current.kept & current.inliers
    new = ~outliers(residuals, residuals[reference], cutoff=cutoff)
    if not keeps_directions(directions, current.kept, new, centre=centre):
        return Screen(current.centre, current.radius, current.kept, current.inliers, False)
    return Screen(current.centre, current.radius, current.kept, new, current.applied)
