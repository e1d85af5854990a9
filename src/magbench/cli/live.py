"""What ``capture`` shows while the sensor turns: coverage, a running held-out fit, the next turn.

:func:`live_status` takes the samples so far and returns a :class:`LiveStatus`, computed as
``calibrate`` computes its own figures, so that "enough" here means what the gate means there:

- *Directions.* The robust centre of :func:`magbench.core.robust.screen` (still stretches
  thinned, outliers set aside), the samples an even stride down to :data:`MAX_FIT` (as
  ``calibrate``'s ``max_samples``); the share of the sphere covered
  (:func:`magbench.core.geometry.coverage`), the largest empty cap and its centre
  (:func:`~magbench.core.geometry.largest_gap`), the distinct directions (occupied equal-area
  cells, :func:`~magbench.core.geometry.direction_cells`) and the band about one plane.
- *Held-out error.* A cheap fit on calibrate's own interleaved time-block folds
  (:func:`magbench.pipeline.holdout.fold_indices`): the sphere fit, and the ellipsoid fit once
  the largest gap is within the gate (``calibrate`` allows full models only then), each fitted
  on every block but a fold's and scored on that fold; the better one's 95th percentile of
  ``100 |1 - |m||`` over every held-out sample, the figure the gate judges.
- *Enough.* Every ``WARN`` threshold of :class:`magbench.core.verdict.Gate` that the live
  figures can check is met: held-out error, largest gap, distinct directions and band.
  ``calibrate`` then runs its full choice and verdict on the saved recording.
- *Next turn* (:func:`turn_words`). From the field direction seen now toward the centre of the
  largest gap: the sensor turns about ``-(now x gap)`` (the field turns opposite to the sensor,
  :func:`magbench.core.verdict.turn_advice`'s convention), named for a vehicle with X forward,
  Y right and Z down ("nose down", "roll left"), with the angle. While the directions lie near
  one plane (the gate's band), the centre and so the gap are not known yet, and the words ask
  for a turn about another axis instead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from magbench.core.geometry import (
    DIRECTION_CELLS,
    band_half_width,
    coverage,
    direction_cells,
    largest_gap,
)
from magbench.core.model import CalibrationFailed
from magbench.core.robust import screen
from magbench.core.verdict import Gate, field_error_pct
from magbench.methods.api import calibrate as fit_method
from magbench.pipeline.holdout import fold_indices

__all__ = ["MAX_FIT", "MIN_SAMPLES", "LiveStatus", "live_status", "map_rows", "turn_words"]

#: Fewer samples than this give no figures yet (a fold fit needs a few dozen).
MIN_SAMPLES = 30
#: The live figures use at most about this many samples (calibrate's ``max_samples``).
MAX_FIT = 2000

#: The equal-area cells' layout (:func:`direction_cells`): bands of z, twice as many longitudes.
BANDS = max(1, round(math.sqrt(DIRECTION_CELLS / 2.0)))


@dataclass
class LiveStatus:
    """The live figures (module notes); ``None`` where too few samples give none."""

    samples: int
    coverage: float = 0.0
    gap_deg: float = 180.0
    gap_centre: list[float] = field(default_factory=lambda: [0.0, 0.0, -1.0])
    directions: int = 0
    band_deg: float = 0.0
    error_p95_pct: float | None = None
    fit: str = ""
    cells: list[int] = field(default_factory=list)
    now: list[float] | None = None
    enough: bool = False
    quality: float = 0.0
    missing: list[str] = field(default_factory=list)
    prompt: str = "turn the sensor slowly through every orientation"

    def as_dict(self) -> dict:
        """The figures for ``capture.json`` (the cells as a count, not a list)."""
        out = dict(self.__dict__)
        out["cells"] = len(self.cells)
        return out


#: Sensor axis and sense of a right-handed turn -> words for a vehicle with X forward, Y right,
#: Z down (as :func:`magbench.core.verdict.turn_advice` names them).
_WORDS = {(0, 1): "roll right", (0, -1): "roll left", (1, 1): "nose up", (1, -1): "nose down",
          (2, 1): "yaw right", (2, -1): "yaw left"}


def turn_words(now: Sequence[float], target: Sequence[float]) -> str:
    """How to turn the sensor so that the field, now along ``now`` in the sensor's axes, comes
    to lie along ``target``: e.g. ``"turn it nose down about 90 deg"`` (module notes)."""
    a = np.asarray(now, dtype=float)
    b = np.asarray(target, dtype=float)
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    angle = math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))
    axis = -np.cross(a, b)
    n = float(np.linalg.norm(axis))
    if n < 1e-6:                     # already there, or exactly opposite: any perpendicular
        axis = np.cross(b, np.eye(3)[int(np.argmin(np.abs(b)))])
        n = float(np.linalg.norm(axis))
    axis = axis / n
    order = np.argsort(-np.abs(axis))
    parts = [_WORDS[(int(order[0]), 1 if axis[order[0]] > 0 else -1)]]
    if abs(axis[order[1]]) > 0.45:   # a turn between two axes: name both
        parts.append(_WORDS[(int(order[1]), 1 if axis[order[1]] > 0 else -1)])
    return f"turn it {' and '.join(parts)} about {angle:.0f} deg"


def map_rows(cells: Sequence[int], gap_centre: Sequence[float] | None = None,
             now: Sequence[float] | None = None) -> list[str]:
    """The equal-area cells as text: one row per band of z (top: the field along +Z), one
    character per longitude step; ``#`` covered, ``.`` not yet, ``O`` the largest gap's
    centre, ``@`` the field direction now."""
    grid = [["."] * (2 * BANDS) for _ in range(BANDS)]

    def put(cell: int, ch: str) -> None:
        band, step = divmod(int(cell), 2 * BANDS)
        grid[BANDS - 1 - band][step] = ch

    for cell in cells:
        put(cell, "#")
    if gap_centre is not None:
        put(int(direction_cells(np.array([gap_centre]))[0]), "O")
    if now is not None:
        put(int(direction_cells(np.array([now]))[0]), "@")
    return ["".join(row) for row in grid]


def _held_out_p95(y: np.ndarray, method: str) -> float | None:
    """95th percentile of the held-out field error (%) of ``method`` on the folds."""
    errors = []
    for test in fold_indices(y.shape[0]):
        train = np.setdiff1d(np.arange(y.shape[0]), test)
        try:
            cal = fit_method(y[train], method)
        except (ValueError, CalibrationFailed):
            return None
        errors.append(field_error_pct(np.linalg.solve(cal.T, (y[test] - cal.h).T).T))
    return float(np.percentile(np.concatenate(errors), 95))


def _progress(status: LiveStatus, gate: Gate) -> tuple[float, list[str]]:
    """Progress toward each WARN threshold, 0..1, the smallest first; what is still missing."""
    err = status.error_p95_pct
    items = [
        (min(1.0, max(0.0, (180.0 - status.gap_deg) / (180.0 - gate.warn_gap_deg))),
         f"largest gap {status.gap_deg:.0f} deg > {gate.warn_gap_deg:g}"),
        (min(1.0, status.directions / max(gate.warn_directions, 1)),
         f"{status.directions} directions < {gate.warn_directions}"),
        (min(1.0, status.band_deg / gate.warn_band_deg) if gate.warn_band_deg > 0 else 1.0,
         f"within +-{status.band_deg:.0f} deg of one plane"),
        (0.0 if err is None else min(1.0, gate.warn_error_pct / err) if err > 0 else 1.0,
         "no held-out error yet" if err is None else
         f"field error {err:.1f} % > {gate.warn_error_pct:g} %"),
    ]
    quality = min(p for p, _ in items)
    return quality, [text for p, text in items if p < 1.0]


def live_status(y: np.ndarray, gate: Gate | None = None) -> LiveStatus:
    """The live figures of the samples so far (module notes).

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        The samples received, in time order.
    gate : Gate, optional
        The thresholds "enough" is judged by (``calibrate``'s ``gate.*``).
    """
    gate = gate or Gate()
    y = np.asarray(y, dtype=float)
    status = LiveStatus(samples=int(y.shape[0]))
    if y.shape[0] < MIN_SAMPLES:
        status.missing = [f"{y.shape[0]} samples < {MIN_SAMPLES}"]
        status.prompt = "waiting for samples"
        return status
    try:
        current = screen(y)
    except (ValueError, np.linalg.LinAlgError):
        status.missing = ["the samples do not lie near a sphere yet"]
        return status
    work = y[current.work]
    work = work[::max(1, math.ceil(work.shape[0] / MAX_FIT))]
    d = work - current.centre
    gap, centre = largest_gap(d)
    cells = np.unique(direction_cells(d))
    status.coverage, status.gap_deg, status.gap_centre = coverage(d), float(gap), centre.tolist()
    status.directions, status.cells = int(cells.size), cells.tolist()
    status.band_deg = band_half_width(d)
    status.now = (y[-1] - current.centre).tolist()
    best = None
    for method in ("sphere", "ellipsoid") if gap <= gate.warn_gap_deg else ("sphere",):
        p95 = _held_out_p95(work, method)
        if p95 is not None and (best is None or p95 < best[0]):
            best = (p95, method)
    if best is not None:
        status.error_p95_pct, status.fit = best
    status.quality, status.missing = _progress(status, gate)
    status.enough = not status.missing
    if status.enough:
        status.prompt = "enough: coverage and error meet the gate"
    elif status.band_deg < gate.warn_band_deg:
        # near one plane the centre, hence the gap, is not known yet: no direction to name
        status.prompt = "turn it about another axis too: the directions so far lie near one plane"
    elif gap > gate.warn_gap_deg or status.directions < gate.warn_directions:
        status.prompt = turn_words(status.now, centre) + " (toward the gap)"
    else:
        status.prompt = "keep turning slowly through new orientations"
    return status
