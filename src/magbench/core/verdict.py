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
           "magnitude_verdict", "turn_advice"]

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
    """Axis (unit, sensor frame) to turn the sensor about, right-handed, so that the field
    directions move toward the uncovered ``centre``.

    The field seen by the sensor turns opposite to the sensor: turning the sensor by ``Q``
    takes a field direction ``b`` to ``Q^T b``. The mean direction reaches ``centre`` by a
    rotation about ``a = mean x centre``, so the sensor turns about ``-a``.
    """
    mean = np.mean(directions / np.linalg.norm(directions, axis=1)[:, None], axis=0)
    axis = np.cross(mean, centre)
    n = float(np.linalg.norm(axis))
    if n < 1e-6:                       # mean and gap aligned or opposite: any perpendicular
        axis = np.cross(centre, np.eye(3)[int(np.argmin(np.abs(centre)))])
        n = float(np.linalg.norm(axis))
    return -axis / n


#: Per sensor axis and sense of turn: the words for a vehicle with X forward, Y right and Z
#: down (the aerospace body frame).
_VEHICLE = {(0, "+"): "roll right, right side down", (0, "-"): "roll left, left side down",
            (1, "+"): "nose up", (1, "-"): "nose down",
            (2, "+"): "yaw right, nose right", (2, "-"): "yaw left, nose left"}


def turn_advice(axis: np.ndarray) -> str:
    """How to turn the sensor about ``axis`` (right-handed), in the sensor's own axes.

    E.g. ``"rotate it about its Y axis, turning its +X end toward -Z (nose up if X points
    forward, Y right and Z down)"`` when the axis lies within about 35 deg of a sensor axis,
    else the axis as a vector.
    """
    v = np.asarray(axis, dtype=float)
    i = int(np.argmax(np.abs(v)))
    if abs(v[i]) <= 0.8:
        return f"rotate it about the axis ({v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f}) of its frame"
    sign = "+" if v[i] > 0 else "-"
    # A right-handed turn about +e_i takes +e_(i+1) toward +e_(i+2) (X->Y, Y->Z, Z->X); about
    # -e_i toward -e_(i+2). About Y that is +Z toward +X, i.e. +X toward -Z.
    a, b = "XYZ"[(i + 1) % 3], "XYZ"[(i + 2) % 3]
    if i == 1:
        moving, toward = "X", ("-" if sign == "+" else "+") + "Z"
    else:
        moving, toward = a, sign + b
    return (f"rotate it about its {'XYZ'[i]} axis, turning its +{moving} end toward {toward} "
            f"({_VEHICLE[(i, sign)]} if X points forward, Y right and Z down)")


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
        and ``gap_centre`` (unit vector), ``rotate_about`` (unit axis, right-handed, to turn
        the sensor about), ``advice`` (:func:`turn_advice`) and ``warning`` (a sentence, or
        None when the coverage is sufficient).
    """
    d = np.asarray(directions, dtype=float)
    gap, centre = largest_gap(d)
    axis = _rotation_hint(d, centre)
    advice = turn_advice(axis)
    warning = None
    if gap > max_gap_deg:
        warning = (f"coverage is insufficient: no field direction within {gap:.0f} deg of "
                   f"({centre[0]:+.2f}, {centre[1]:+.2f}, {centre[2]:+.2f}) in the sensor's "
                   f"axes (the samples fill a cap of about {180 - gap:.0f} deg; the coverage "
                   f"sweep shows most full-model fits fail below about 90); record again and "
                   f"also {advice}, until the field has pointed that way")
    return {"coverage": coverage(d), "largest_gap_deg": float(gap),
            "gap_centre": centre.tolist(), "rotate_about": axis.tolist(), "advice": advice,
            "warning": warning}
