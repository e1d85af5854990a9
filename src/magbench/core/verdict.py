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

*Fitness* (:func:`fitness`). Every calibration is PASS, WARN or FAIL, with its reasons, from
stated thresholds (:class:`Gate`, the ``gate.*`` keys of ``calibrate``), as ArduPilot's
calibrator checks its fit's residual: the held-out 95th-percentile field error, the largest
uncovered cap, the number of distinct directions (occupied equal-area cells,
:func:`magbench.core.geometry.direction_cells`), directions confined to a band about one plane
(:func:`magbench.core.geometry.band_half_width`), the fitted field strength against the
samples' own radius and, when known, an expected value or range, and, when the recording has a
reference attitude, the held-out heading error measured against it. The worst status wins, with
one exception. A FAIL says "do not use this": the fit is not determined by the data (too few
directions, too wide a gap), unsafe (a field strength off the data's or the expected
one), or no better than no correction (the raw data's field-magnitude spread, as a share of the
field, not narrowed below :data:`NARROWING` of itself). A shortfall measured on held-out data
by magnitude (the field error, an offset that moves between the halves of the recording) FAILs
only when the correction is not clearly better than none (the heading error against an attitude
measures direction, which no magnitude can outweigh: it always counts); otherwise it WARNs, and
says that the correction was written nonetheless: the user's alternative is the raw data, and a
phone whose hard iron is ten times the field points 60-90 deg astray without one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from magbench.core.geometry import coverage, largest_gap, row_norms

__all__ = [
    "MAX_GAP_DEG",
    "STATUSES",
    "Gate",
    "coverage_report",
    "field_error_pct",
    "fitness",
    "heading_error_deg",
    "magnitude_verdict",
    "turn_advice",
    "with_reason",
]

MAX_GAP_DEG = 100.0


#: Share of the samples, by field magnitude, that :func:`central_spread_pct` keeps.
CENTRAL_SHARE = 0.95
#: A field error up to this many times the noise's own (:func:`noise_p95_pct`) is noise.
NOISE_FACTOR = 1.5
#: A correction must bring the field magnitude's spread below this share of the raw one.
NARROWING = 0.8


def field_error_pct(corrected: np.ndarray) -> np.ndarray:
    """``100 |1 - ||m_k|| |`` for each corrected sample (the field is of unit magnitude)."""
    m = np.asarray(corrected, dtype=float)
    return 100.0 * np.abs(1.0 - np.sqrt(np.einsum("ij,ij->i", m, m)))


def heading_error_deg(error_pct: float, inclination_deg: float = 0.0) -> float:
    """Heading error of a level compass from a field error of ``error_pct`` % (see notes)."""
    ratio = error_pct / 100.0 / math.cos(math.radians(inclination_deg))
    return math.degrees(math.asin(min(1.0, ratio)))


def noise_p95_pct(y: np.ndarray, radius: float) -> float:
    """The 95th percentile (%) of the field error that white sensor noise alone gives:
    ``1.96`` times the per-axis noise, from the robust spread of the second differences of
    ``y`` in time order (which cancel a smooth turn: ``var = 6 sigma^2``), over ``radius``.
    NaN with fewer than 10 samples."""
    y = np.asarray(y, dtype=float)
    if y.shape[0] < 10 or not radius > 0:
        return np.nan
    # One axis at a time, in place: the whole-array expression held four (K, 3) arrays at
    # once (the differences, their deviations and the medians' partition copies), the
    # largest share of ``calibrate``'s memory on a long recording. Same values: a median
    # selects them.
    spreads = np.empty(y.shape[1])
    for j in range(y.shape[1]):
        d2 = np.diff(y[:, j], n=2)
        d2 -= np.median(d2)
        np.abs(d2, out=d2)
        spreads[j] = np.median(d2)
    sigma = 1.4826 * spreads / np.sqrt(6)
    return float(100 * 1.96 * np.sqrt(np.mean(sigma ** 2)) / radius)


def central_spread_pct(vectors: np.ndarray, share: float = CENTRAL_SHARE,
                       scale: float | None = None) -> float:
    """``100 std|v| / mean|v|`` over the ``share`` of the samples whose norm lies closest to
    the median norm: the spread of the field magnitude with the few largest deviations
    (spikes, on either side) left out. With ``scale`` (the field's strength in the units of
    ``v``, e.g. the samples' own radius) the spread is a share of it instead of the mean
    norm: raw samples whose offset exceeds the field have a mean norm of about the offset,
    which would make any spread look small."""
    return central_spread_of_norms(row_norms(vectors), share, scale)


def central_spread_of_norms(norm: np.ndarray, share: float = CENTRAL_SHARE,
                            scale: float | None = None) -> float:
    """:func:`central_spread_pct` from the vectors' norms (shape (K,)), for a caller that has
    them without the vectors: :func:`magbench.core.robust.corrected_norms` gives a long
    recording's corrected norms without building the corrected samples."""
    norm = np.asarray(norm, dtype=float)
    deviation = np.abs(norm - np.median(norm))
    kept = norm[deviation <= np.percentile(deviation, 100 * share)]
    unit = kept.mean() if scale is None else scale
    return float(100 * kept.std() / unit) if kept.size and unit > 0 else np.nan


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


#: The statuses, best first; FAIL writes no firmware file and exits 3.
STATUSES = ("PASS", "WARN", "FAIL")


@dataclass(frozen=True)
class Gate:
    """Thresholds of :func:`fitness` (the ``gate.*`` keys; each WARN below its FAIL).

    Attributes
    ----------
    warn_error_pct, fail_error_pct : float
        Held-out 95th-percentile field error (%) above which a result warns / fails:
        ArduPilot's default fitness, 16 mGauss RMS on a ~500 mGauss field (3.2 % RMS, about
        6 % at the 95th percentile of Gaussian errors), and its "relaxed" 32 mGauss (12 %).
    warn_gap_deg, fail_gap_deg : float
        Largest uncovered cap (deg): 100 (a cap of 80 deg, where the coverage sweep's full
        models start to fail) and 135 (a cap of 45 deg, where they all do).
    warn_directions, fail_directions : int
        Distinct directions (occupied cells of about 10 deg): fewer than 10 cannot identify the
        9 parameters of a full model and a check; 20 leave room for the 24 static shots of a
        cave-survey calibration.
    warn_band_deg : float
        Directions within +- this of one plane (95 %) warn: the axis across it is extrapolated.
    warn_field_pct, fail_field_pct : float
        Fitted field strength farther than this (%) from the expected value (or outside the
        expected range by this much) warns / fails; ``fail_field_pct`` also bounds the
        distance from the samples' own sphere-fit radius (a fit that lost the data's scale).
    warn_heading_deg, fail_heading_deg : float
        Held-out heading RMS (deg) measured against a reference attitude, when the recording
        has one, above which a result warns / fails: 10 deg is past what a compass-aided
        navigator tolerates; 30 deg is a field that does not follow the sensor's rotation (a
        magnet on the board for part of the recording, steel near the path).
    """

    warn_error_pct: float = 6.0
    fail_error_pct: float = 12.0
    warn_gap_deg: float = MAX_GAP_DEG
    fail_gap_deg: float = 135.0
    warn_directions: int = 20
    fail_directions: int = 10
    warn_band_deg: float = 30.0
    warn_field_pct: float = 10.0
    fail_field_pct: float = 25.0
    warn_heading_deg: float = 10.0
    fail_heading_deg: float = 30.0


def _field_distance_pct(value: float, expected: float | tuple[float, float]) -> float:
    """How far (%) ``value`` lies from ``expected`` (a value, or outside a range)."""
    if isinstance(expected, tuple):
        low, high = expected
        if low <= value <= high:
            return 0.0
        return 100.0 * (low / value - 1.0 if value < low else value / high - 1.0)
    return 100.0 * abs(value / expected - 1.0)


def fitness(gate: Gate, *, p95_pct: float, held_out: bool, gap_deg: float, directions: int,
            band_deg: float, field: float, radius: float,
            expected_field: float | tuple[float, float] | None = None,
            heading_deg: float | None = None,
            spread_pct: tuple[float, float] | None = None,
            noise_p95_pct: float | None = None) -> dict:
    """PASS, WARN or FAIL with the reasons (see the module notes).

    Parameters
    ----------
    gate : Gate
        The thresholds.
    p95_pct : float
        95th-percentile field error (%), held out when ``held_out``.
    held_out : bool
        False when no held-out error exists (a short recording): that alone warns.
    gap_deg, directions, band_deg : float, int, float
        Largest uncovered cap, distinct directions, band half-width about a plane.
    field, radius : float
        The fit's field strength ``|det T|^(1/3)`` and the data's: the field strength the
        candidate fits agree on, or the samples' sphere-fit radius.
    expected_field : float or (low, high), optional
        The field strength expected in the recording's units.
    heading_deg : float, optional
        Held-out heading RMS (deg) measured against a reference attitude; None without one.
    spread_pct : (float, float), optional
        :func:`central_spread_pct` of every sample of the recording corrected, and
        uncorrected as a share of the field (``scale``: the samples' radius): a correction
        that does not narrow it below :data:`NARROWING` times the raw one is a FAIL: it would
        leave the user no better off, or worse, than no correction (data calibrated already,
        or a field that itself changes). One that does turns the held-out shortfalls of
        magnitude into warnings (module notes).
    noise_p95_pct : float, optional
        The 95th percentile of the field error that the sensor's own noise alone gives
        (:func:`noise_p95_pct`): a field error above the FAIL threshold but within
        :data:`NOISE_FACTOR` times it is the sensor's noise, not the calibration, a WARN.

    Returns
    -------
    dict
        ``status`` (``PASS``, ``WARN`` or ``FAIL``), ``reasons`` (one short phrase each, the
        failing ones first), ``thresholds`` (the gate), ``better_than_raw`` and
        ``spread_pct`` (as given).
    """
    fails, warns, unsafe = [], [], []
    better = spread_pct is not None and spread_pct[0] < NARROWING * spread_pct[1]

    def judge(value: float, warn: float, fail: float, text: str, above: bool = True,
              into: list[str] = fails) -> None:
        bad_fail = value > fail if above else value < fail
        bad_warn = value > warn if above else value < warn
        if bad_fail:
            into.append(text.format(v=value, t=fail))
        elif bad_warn:
            warns.append(text.format(v=value, t=warn))

    noisy = (noise_p95_pct is not None and p95_pct > gate.fail_error_pct
             and p95_pct <= NOISE_FACTOR * noise_p95_pct)
    if noisy:
        warns.append(f"field error {p95_pct:.1f} % (p95) is the sensor's own noise "
                     f"({noise_p95_pct:.1f} % p95 from sample-to-sample changes), not the "
                     "calibration: filter or average the samples before use")
    else:
        judge(p95_pct, gate.warn_error_pct, gate.fail_error_pct,
              "field error {v:.1f} % (p95" + (", held out" if held_out else ", in sample")
              + ") > {t:g} %")
    # Too few directions or too wide a gap: the data do not determine the fit, so no
    # comparison with the raw data can vouch for it.
    judge(gap_deg, gate.warn_gap_deg, gate.fail_gap_deg,
          "no direction within {v:.0f} deg of the gap centre (> {t:g} deg)", into=unsafe)
    judge(directions, gate.warn_directions, gate.fail_directions,
          "{v:.0f} distinct directions (< {t:g})", above=False, into=unsafe)
    if band_deg < gate.warn_band_deg:
        warns.append(f"directions within +-{band_deg:.0f} deg of one plane (< "
                     f"{gate.warn_band_deg:g}): the axis across it is extrapolated")
    if not held_out:
        warns.append("no held-out score: the error is in sample")
    if radius > 0:
        off = _field_distance_pct(field, radius)
        if off > gate.fail_field_pct:
            unsafe.append(f"fitted field {field:.4g} is {off:.0f} % from the data's field "
                          f"{radius:.4g}")
    if expected_field is not None:
        judge(_field_distance_pct(field, expected_field), gate.warn_field_pct,
              gate.fail_field_pct, f"field strength {field:.4g} is {{v:.0f}} % from the "
              f"expected {_expected_text(expected_field)} (> {{t:g}} %)", into=unsafe)
    if spread_pct is not None and not better:
        unsafe.append(f"the correction narrows the field magnitude's spread over the recording "
                      f"by less than {1 - NARROWING:.0%} ({spread_pct[0]:.1f} % against "
                      f"{spread_pct[1]:.1f} % of the field uncorrected): the data are "
                      "calibrated already, or the field itself changes (disturbances, another "
                      "state)")
    if heading_deg is not None and math.isfinite(heading_deg):
        # Measured against the attitude: a spread that narrowed cannot outweigh it.
        judge(heading_deg, gate.warn_heading_deg, gate.fail_heading_deg,
              "heading error {v:.1f} deg RMS (held out, against the attitude) > {t:g} deg",
              into=unsafe)
    if better and fails and not unsafe:
        # A shortfall measured on held-out data, but the correction is the better compass.
        warns = [*fails, *warns, _better_text(spread_pct)]
        fails = []
    fails = unsafe + fails
    status = "FAIL" if fails else "WARN" if warns else "PASS"
    return {"status": status, "reasons": fails + warns, "thresholds": dict(gate.__dict__),
            "better_than_raw": better, "spread_pct": spread_pct}


_BETTER = "written nonetheless"


def _better_text(spread_pct: tuple[float, float]) -> str:
    return (f"{_BETTER}: it is clearly better than no correction (field magnitude "
            f"spread {spread_pct[0]:.1f} % against {spread_pct[1]:.1f} % of the field "
            "uncorrected); record again for a better one")


def with_reason(fit: dict, reason: str, *, fail: bool = False, quality: bool = False
                ) -> dict:
    """:func:`fitness`'s result with one more reason: a failing one goes first and makes it
    FAIL; a warning goes last and makes a PASS a WARN. A ``quality`` failure (not a safety
    one) only warns when the correction is clearly better than none (``better_than_raw``) and
    nothing else failed: a FAIL writes nothing, so it never says "written nonetheless"."""
    if fail and quality and fit.get("better_than_raw") and fit["status"] != "FAIL":
        note = [] if any(r.startswith(_BETTER) for r in fit["reasons"]) else \
            [_better_text(fit["spread_pct"])]
        status = "WARN" if fit["status"] == "PASS" else fit["status"]
        return {**fit, "status": status, "reasons": [*fit["reasons"], reason, *note]}
    if fail:
        # nothing is written now: a demoted shortfall's "written nonetheless" no longer holds
        kept = [r for r in fit["reasons"] if not r.startswith(_BETTER)]
        return {**fit, "status": "FAIL", "reasons": [reason, *kept]}
    status = "WARN" if fit["status"] == "PASS" else fit["status"]
    return {**fit, "status": status, "reasons": [*fit["reasons"], reason]}


def _expected_text(expected: float | tuple[float, float]) -> str:
    if isinstance(expected, tuple):
        return f"{expected[0]:.4g}-{expected[1]:.4g}"
    return f"{expected:.4g}"
