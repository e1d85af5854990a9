"""``calibrate``'s direction part: the veto's notes in the ranking, the heading-true
correction and the lines that say what the direction is (:mod:`magbench.pipeline.alignment`)."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np

from magbench.core.direction import dip_angles, rest_mask, world_field
from magbench.core.exports import to_json_dict
from magbench.core.geomagnetic import Site
from magbench.core.model import Calibration, CalibrationFailed
from magbench.core.units import Units
from magbench.pipeline.alignment import (
    DirectionVeto,
    align_chosen,
    field_check,
    inertial_of,
    inertial_source,
)
from magbench.pipeline.result import CalibrationResult

__all__ = ["direction_lines", "mark_vetoes", "measured_inclination"]


def mark_vetoes(ranked: list[dict], veto: DirectionVeto) -> None:
    """Each candidate's held-out heading as a column of the ranking (in place), when one was
    measured; the note of one the direction set aside is the choice's own
    (:func:`magbench.pipeline.choice.eligibility`)."""
    if not veto.scores:
        return
    for row in ranked:
        row["heading_out_deg"] = veto.scores.get(str(row["algorithm"]), math.nan)


def measured_inclination(cal: Calibration, rec, keep: np.ndarray) -> float | None:
    """The field's inclination (deg, positive down) under a heading-true ``cal``: from the
    attitude (the world's up is the mean world-frame specific force when there is an
    accelerometer, else its z axis) or from the accelerometer at rest; None without either."""
    inertial = inertial_of(rec)
    A, b = cal.correction()
    field = (rec.y - b) @ A.T
    if inertial.attitude is not None:
        ok = keep & np.isfinite(inertial.attitude).all(axis=1)
        if ok.sum() >= 10:
            f = world_field(field[ok], inertial.attitude[ok])
            f /= np.linalg.norm(f, axis=1, keepdims=True)
            up = np.array([0.0, 0.0, 1.0])
            if inertial.acceleration is not None:
                up = world_field(inertial.acceleration[ok], inertial.attitude[ok]).mean(axis=0)
                up /= np.linalg.norm(up)
            return float(np.degrees(np.arcsin(-np.median(f @ up))))
    if inertial.acceleration is not None:
        still = keep & rest_mask(inertial.gyro, inertial.acceleration)
        if still.sum() >= 2:
            return float(np.degrees(np.median(dip_angles(inertial.acceleration[still],
                                                         field[still]))))
    return None


def direction_lines(result: CalibrationResult, cal: Calibration, payload: dict,
                    veto: DirectionVeto, site: tuple[Site | None, dt.date | None],
                    lag_s: float = 0.0) -> tuple[Calibration, list[str]]:
    """The chosen calibration heading-true when the recording's inertial columns fix its
    rotation (``payload``'s correction rewritten in that gauge, with ``direction``), and the
    lines to print. Without inertial columns: ``cal`` unchanged, no line. ``lag_s``: the
    magnetometer lag removed before fitting (said in a line)."""
    lines: list[str] = []
    if lag_s:
        lines.append(f"lag: the magnetometer read {1e3 * lag_s:.1f} ms late against the "
                     "inertial streams; removed before fitting")
        payload["magnetometer_lag_s"] = lag_s
    name = payload["method"]
    source = inertial_source(result.rec)
    if source != "none":
        try:
            cal, source = align_chosen(cal, result.rec, result.inliers)
        except CalibrationFailed as exc:
            lines.append(f"direction: symmetric gauge, the rotation to the IMU is unknown "
                         f"({exc})")
        else:
            units = Units.from_dict(payload.get("unit"))
            payload |= to_json_dict(cal, units=units, columns=payload.get("columns"))
            heading = veto.scores.get(name, math.nan)
            payload["direction"] = {"gauge": cal.gauge, "source": source,
                                    "alignment_deg": _angle(cal.alignment),
                                    "heading_out_rms_deg": None if math.isnan(heading)
                                    else heading}
            held = (f"held-out heading RMS {heading:.2f} deg, " if math.isfinite(heading)
                    else "")
            lines.append(f"direction: {held}heading-true (alignment to the IMU "
                         f"{_angle(cal.alignment):.2f} deg, from {source})")
    lines += [f"direction: {n} set aside, {why}" for n, why in veto.vetoes.items()]
    where, date = site
    if where is not None:
        incl = measured_inclination(cal, result.rec, result.inliers) \
            if cal.alignment is not None else None
        check = field_check(payload["field_strength"], incl, where, date)
        e = check["expected"]
        lines.append(f"site: IGRF {e.strength_nT:.0f} nT, inclination {e.inclination_deg:.1f} "
                     f"deg on {date}; fit {payload['field_strength']:.4g} "
                     f"{check['unit'] or '(unit unknown)'}"
                     + (f", inclination {incl:.1f} deg" if incl is not None else "")
                     + ("" if check["ok"] else f" ({'; '.join(check['reasons'])})"))
        payload["site"] = {"expected_nT": e.strength_nT, "expected_inclination_deg":
                           e.inclination_deg, "unit": check["unit"],
                           "measured_inclination_deg": incl, "ok": check["ok"],
                           "reasons": check["reasons"]}
    return cal, lines


def _angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
