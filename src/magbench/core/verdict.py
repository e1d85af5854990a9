"""A calibration's verdict in units a user reads: field-magnitude error in %, heading error in
degrees, and whether the recording's field directions cover enough of the sphere to trust it.

*Field error.* For corrected samples ``m_k`` the field has unit magnitude, so
``100 |1 - ||m_k|| |`` is the error of the field strength in percent of the field.

*Heading error.* A compass on a level sensor reads the heading from the horizontal component of
the field, ``B cos I`` at inclination ``I``. A residual error vector of size ``e B`` (``e`` the
relative field error above, taken as the size of the vector error, which the magnitude alone
cannot bound from below) turns that component by at most ``asin(e / cos I)``. The figure is given
for a horizontal field (``I = 0``, the smallest); it grows about as ``1 / cos I`` (twice at 60 deg).
It is an estimate implied by the magnitude spread, not a bound on errors of direction that leave
the magnitude unchanged (a rotation is not observable from magnitudes at all).

*Coverage.* The coverage sweep (results/coverage) found that data filling a hemisphere are
calibrated by nearly every full-model method, while a cap of half-angle 60 deg defeats most of
them. Samples within a cap of half-angle theta leave an empty cap of radius ``180 - theta``
(:func:`magbench.core.geometry.largest_gap`); :data:`MAX_GAP_DEG` (100, a cap of 80 deg) lies
between the two, with room for the few-degree bias of a sphere-fit centre on partial data.
"""

from __future__ import annotations

import math

import numpy as np

from magbench.core.geometry import coverage, largest_gap

__all__ = ["MAX_GAP_DEG", "coverage_report", "field_error_pct", "heading_error_deg",
           "magnitude_verdict"]

MAX_GAP_DEG = 100.0


def field_error_pct(corrected: np.ndarray) -> np.ndarray:
    """``100 |1 - ||m_k|| |`` for each corrected sample (the field is of unit magnitude)."""
    m = np.asarray(corrected, dtype=float)
    return 100.0 * np.abs(1.0 - np.sqrt(np.einsum("ij,ij->i", m, m)))


def heading_error_deg(error_pct: float, inclination_deg: float = 0.0) -> float:
    """Heading error of a level compass from a field error of ``error_pct`` % (see notes)."""
    ratio = error_pct / 100.0 / math.cos(math.radians(inclination_deg))
    return math.degrees(math.asin(min(1.0, ratio)))


def magnitude_verdict(corrected: np.ndarray, *, held_out: bool) -> dict:
    """The field-error percentiles of corrected samples and the heading errors they imply.

    Parameters
    ----------
    corrected : ndarray, shape (K, 3)
        Corrected samples ``A (y - b)`` (or any gauge: only the norms are used).
    held_out : bool
        Whether the samples were not used to fit the calibration (recorded in the result).

    Returns
    -------
    dict
        ``field_error_pct`` with ``median``, ``p95`` and ``max``; ``heading_error_deg`` with
        ``p95`` and ``max`` for a level sensor in a horizontal field; ``samples`` and
        ``held_out``.
    """
    err = field_error_pct(corrected)
    p50, p95, worst = (float(np.percentile(err, 50)), float(np.percentile(err, 95)),
                       float(err.max()))
    return {"held_out": bool(held_out), "samples": int(err.size),
            "field_error_pct": {"median": p50, "p95": p95, "max": worst},
            "heading_error_deg": {"p95": heading_error_deg(p95),
                                  "max": heading_error_deg(worst),
                                  "assumes": "level sensor, horizontal field; about 1/cos(I) "
                                             "times larger at inclination I (x2 at 60 deg)"}}


def _rotation_hint(directions: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Axis (unit, sensor frame) of the rotation that carries the recorded field directions
    toward the uncovered ``centre``: the sensor should be turned about it."""
    mean = np.mean(directions / np.linalg.norm(directions, axis=1)[:, None], axis=0)
    axis = np.cross(mean, centre)
    n = float(np.linalg.norm(axis))
    if n < 1e-6:                       # mean and gap aligned or opposite: any perpendicular
        axis = np.cross(centre, np.eye(3)[int(np.argmin(np.abs(centre)))])
        n = float(np.linalg.norm(axis))
    return axis / n


def _axis_name(v: np.ndarray) -> str:
    """``X``, ``Y`` or ``Z`` when the axis lies within about 35 deg of one, else its vector."""
    i = int(np.argmax(np.abs(v)))
    text = f"({v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f})"
    return f"{'XYZ'[i]} axis {text}" if abs(v[i]) > 0.8 else f"axis {text}"


def coverage_report(directions: np.ndarray, *, max_gap_deg: float = MAX_GAP_DEG) -> dict:
    """How much of the sphere the field directions cover, and a warning when too little.

    Parameters
    ----------
    directions : ndarray, shape (K, 3)
        Field directions in the sensor's axes (corrected samples, or samples minus a centre).
    max_gap_deg : float
        Largest uncovered cap radius accepted without a warning (see the module notes).

    Returns
    -------
    dict
        ``coverage`` (fraction, :func:`magbench.core.geometry.coverage`), ``largest_gap_deg``
        and ``gap_centre`` (unit vector), ``rotate_about`` (unit axis) and ``warning`` (a
        sentence, or None when the coverage is sufficient).
    """
    d = np.asarray(directions, dtype=float)
    gap, centre = largest_gap(d)
    axis = _rotation_hint(d, centre)
    warning = None
    if gap > max_gap_deg:
        warning = (f"coverage is insufficient: no field direction within {gap:.0f} deg of "
                   f"({centre[0]:+.2f}, {centre[1]:+.2f}, {centre[2]:+.2f}) in the sensor's "
                   f"axes (the samples fill a cap of about {180 - gap:.0f} deg; the coverage "
                   f"sweep shows most full-model fits fail below about 90); turn the sensor "
                   f"about its {_axis_name(axis)} as well and record again")
    return {"coverage": coverage(d), "largest_gap_deg": float(gap),
            "gap_centre": centre.tolist(), "rotate_about": axis.tolist(), "warning": warning}
