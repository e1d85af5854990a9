"""The export step of ``calibrate``: what is written for the chosen calibration.

:func:`calibration_json` is the payload (``calibration.json``): the correction in the safe gauge
of :mod:`magbench.core.gauge`, ``m = A (y - b)`` with ``A = (T T^T)^(-1/2)`` symmetric positive
definite and ``b = h``, in the recording's units (never a mirror image; the rotation removed
from the method's own ``T^-1`` is reported), with the status, the choice, the verdict and the
intervals. :func:`add_time_varying` and :func:`add_mounting` add what a flight log adds
(:mod:`magbench.pipeline.flight`); :func:`write_exports` writes ``calibration.h`` and the
firmware files that accept the values (:mod:`magbench.core.exports`). Each returns the line the
command prints, so that the command only prints (:mod:`magbench.cli.calibrate`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from magbench.core.exports import (
    MOTOR_REGRESSORS,
    MotorCompensation,
    c_header,
    field_strength,
    firmware_files,
    to_json_dict,
)
from magbench.core.files import write_text_atomic
from magbench.core.gauge import safe_gauge
from magbench.core.model import Calibration
from magbench.core.units import UNKNOWN, Units
from magbench.methods.api import calibrate as magbench_calibrate
from magbench.methods.registry import get_method
from magbench.pipeline.flight import (
    mounting_rotation,
    time_varying_terms,
    unused_regressors,
    usable_regressors,
)
from magbench.pipeline.holdout import estimate
from magbench.pipeline.result import CalibrationResult
from magbench.sources.recordings import Recording

__all__ = ["ARDUPILOT_LOGS", "add_mounting", "add_time_varying", "calibration_json",
           "held_out_rms_pct", "instance_keys", "write_exports"]


def calibration_json(result: CalibrationResult, *, file: str, columns: list, n_file: int,
                     preprocess: str, units: Units = UNKNOWN,
                     expected_field: float | None = None) -> dict:
    """The chosen calibration as a JSON-ready dict: the correction in the safe gauge.

    The schema of :func:`magbench.core.exports.to_json_dict` (``A``, ``b`` of ``m = A (y - b)``,
    ``T = A^-1``, ``h = b``), plus ``status`` and ``fitness`` (PASS, WARN or FAIL and why), the
    method, the choice, verdict, intervals, thinning, outliers and coverage; ``removed`` records
    the rotation angle taken out of the method's own ``T^-1``, whether it was a mirror image, and
    the method's ``T`` itself; ``unit`` the recording's unit and ``field_strength_expected`` the
    ``field_strength`` key in file units (None if unset). A FAIL holds no correction at the top
    level (``apply`` refuses it): the rejected ``A``, ``b``, ``T``, ``h`` are under ``rejected``.

    Raises
    ------
    ValueError
        If the chosen ``T`` is singular or not finite (such a fit is never written).
    """
    row = result.chosen
    T, h = estimate(row)
    gauge = safe_gauge(T, h)
    correction = to_json_dict(Calibration(T, h), units=units, columns=columns)
    status = result.fitness["status"]
    if status == "FAIL":
        rejected = {k: correction.pop(k) for k in ("A", "b", "T", "h")}
        correction["rejected"] = rejected
    return {
        "status": status, "fitness": result.fitness, **correction,
        "file": file, "method": row["algorithm"], "label": get_method(row["algorithm"]).label,
        "model": get_method(row["algorithm"]).model, "choice": result.how, "tie": result.tie,
        "candidates": {"fitted": sorted({r["algorithm"] for r in result.trials}),
                       "not_fitted": result.not_fitted,
                       "second_round": result.second_round or None},
        "removed": {"rotation_deg": gauge.rotation_deg, "mirrored": gauge.mirrored,
                    "method_T": T.tolist()},
        "field_strength": field_strength(Calibration(T, h)),
        "field_strength_expected": expected_field,
        "verdict": result.verdict,
        "intervals": result.intervals.to_dict() if result.intervals else None,
        "bootstrap": result.bootstrap,
        "thinning": {"thinned": result.thinned, "distinct_directions": result.directions,
                     "band_half_width_deg": result.band_deg,
                     "rule": "equal-area direction cells of about 10 deg; no cell keeps more "
                             "than 10x the median occupied cell's count"},
        "outliers": {"set_aside": result.outliers, "by_sphere_screen": result.screened,
                     "by_chosen_fit": result.trimmed, "applied": result.screen.applied,
                     "rule": "norm residual more than 5 robust sigmas (1.4826 MAD) from the "
                             "median"},
        "coverage": result.coverage, "warnings": list(result.warnings),
        "J_r_in": float(row["J_r_in"]), "J_r_out": _finite(row["J_r_out"]),
        "J_r_worst_fold": _finite(row["J_r_worst"]),
        "worst_out_pct": _finite(row["worst_out_pct"]),
        "J_r_sphere_fit": float(row["J_r_sphere_in"]), "meaningful": bool(row["meaningful"]),
        "converged": bool(row["ok"]), "n_iter": int(row["n_iter"]),
        "preprocess": preprocess, "samples_used": int(row["K"]), "samples_in_file": n_file,
        "stride": int(result.stride),
    }


def instance_keys(rec: Recording) -> dict:
    """``instance`` (the column and value kept) and what the firmware files take from it: an
    ArduPilot ``I`` or ``instance`` of 0-3 numbers the parameter set, a ``device_id`` is PX4's
    CAL_MAGn_ID."""
    if rec.instance is None:
        return {"instance": None}
    column, value = rec.instance
    number = int(float(value)) if value.lstrip("-").replace(".", "", 1).isdigit() else None
    index = number if column != "device_id" and number is not None and 0 <= number <= 3 else 0
    device = number if column == "device_id" else None
    return {"instance": {"column": column, "value": value}, "instance_index": index,
            "device_id": device}


def _finite(x: float) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def held_out_rms_pct(terms: dict) -> dict[str, float]:
    """The held-out RMS field error (%) of ``time_varying``'s static and time-varying fits
    (the dict holds their mean squared norm residuals)."""
    return {k: 100 * float(np.sqrt(terms[f"held_out_{k}"])) for k in ("static", "time_varying")}


def add_mounting(result: CalibrationResult, payload: dict,
                  corrected: np.ndarray | None = None) -> str:
    """Adds the detected mounting rotation to ``payload`` (``mounting_rotation``: the id of
    the autopilots' rotation enum, or None with the reason) when the recording has an
    attitude or an accelerometer (:mod:`magbench.pipeline.flight`); its line, or "".
    ``corrected``: the samples corrected with kept time-varying terms, used instead of
    ``A (y - b)``."""
    found = mounting_rotation(result.rec, np.array(payload["A"]), np.array(payload["b"]),
                              result.inliers, corrected)
    if found is None:
        return ""
    payload["mounting_rotation"] = found.to_dict()
    return found.line()


def add_time_varying(result: CalibrationResult, payload: dict, wanted: list[str] | None,
                      options: dict) -> tuple[str, np.ndarray | None]:
    """Fits ``y = T m + h + C u`` after the chosen static fit and adds ``time_varying`` to
    ``payload`` (regressors, held-out errors static and with the terms, kept or not, and the
    fit's ``A``, ``b``, ``C``). The static start is the chosen method if it fits the full model
    without a gyro, else Fang (the terms are fitted with a full ``A``). ``wanted``:
    ``compensate`` (None: auto). Returns the line ("" when there is nothing to fit) and, when
    the terms are kept, every sample corrected with them (NaN where ``u`` is missing)."""
    rec: Recording = result.rec
    names = usable_regressors(rec, wanted)
    unused = unused_regressors(rec) if wanted is None else []
    if not names:
        return ("time-varying terms not fitted: " + ", ".join(unused) if unused else ""), None
    spec = get_method(payload["method"])
    name = payload["method"] if spec.model == "full" and spec.magnetometer_only else "fang"
    opts = options.get(name) or {}

    def static_fit(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return magbench_calibrate(samples, name, **opts).correction()

    choice = time_varying_terms(rec, names, static_fit, result.inliers)
    payload["time_varying"] = {"method": name, **choice.to_dict(names)}
    firmware = [n for n in names if n in MOTOR_REGRESSORS][:1]
    if choice.kept and firmware and len(names) > 1:
        # The autopilots hold a current or throttle term only: that term alone, if it holds.
        alone = time_varying_terms(rec, firmware, static_fit, result.inliers)
        if alone.kept:
            payload["time_varying"]["firmware"] = alone.to_dict(firmware)
    left_out = f"; not fitted: {', '.join(unused)}" if unused else ""
    head = (f"time-varying terms (y = T m + h + C u, u = {', '.join(names)}{left_out}; {name}; "
            "held out on interleaved time blocks): ")
    if choice.fit is None:
        return head + f"not kept ({choice.reason})", None
    terms = "; ".join(f"{n} ({', '.join(f'{c:.3g}' for c in choice.fit.C[:, j])})"
                      for j, n in enumerate(names))
    verdict = "kept" if choice.kept else f"not kept ({choice.reason})"
    line = (head + f"held-out mean squared norm residual {choice.static_out:.3g} static, "
            f"{choice.varying_out:.3g} with the terms: {verdict}; C per unit of u (file "
            f"units): {terms}")
    corrected = choice.fit.apply(rec.y, rec.stack(names)) if choice.kept \
        else None
    return line, corrected


def write_exports(cal: Calibration, payload: dict, out: Path,
                   result: CalibrationResult) -> tuple[list[str], list[str]]:
    """calibration.h always; each firmware file of :func:`magbench.core.exports.firmware_files`
    (with the mounting rotation as COMPASS_ORIENT and CAL_MAGn_ROT when it was detected with
    confidence, none when refused) that can be written (one line says why not the others, each
    reason once; a stale one from an earlier run in ``out`` is removed). Returns the names
    written and that line, if any."""
    f = payload["verdict"]["field_error_pct"]
    verdict = (f"{payload['label']}: field magnitude error {f['p95']:.2f} % (95th percentile), "
               f"{f['max']:.2f} % (max), "
               f"{'held out' if payload['verdict']['held_out'] else 'in sample'}; "
               f"from {Path(payload['file']).name}")
    units = Units.from_dict(payload.get("unit"))
    rotation, why_not = _export_rotation(payload)
    write_text_atomic(c_header(cal, "mag_cal", verdict=verdict, units=units),
                      out / "calibration.h")
    firmware_cal, motor, motor_note = _export_motor(cal, payload)
    written, refused = firmware_files(firmware_cal, units,
                                      instance=payload.get("instance_index") or 0,
                                      device_id=payload.get("device_id"), rotation=rotation,
                                      motor=motor, comment=verdict + (
                                          f"\n{motor_note}" if motor else ""),
                                      samples=result.rec.y[result.inliers])
    for file, text in written.items():
        write_text_atomic(text, out / file)
    notes = ["not writing " + "; ".join(
        f"{', '.join(n for n, r in refused.items() if r == reason)} ({reason})"
        for reason in dict.fromkeys(refused.values()))] if refused else []
    return (["calibration.h", *written],
            notes + [line for line in (why_not, motor_note if written else "") if line])


def _export_motor(cal: Calibration, payload: dict) -> tuple[Calibration, MotorCompensation | None,
                                                             str]:
    """The calibration the firmware files hold, its motor term and a line saying so: the
    time-varying fit's ``A``, ``b`` and ``C`` when its only kept term is the current or the
    throttle (what ArduPilot's COMPASS_MOT and PX4's CAL_MAGn_*COMP hold), else ``cal``."""
    tv = payload.get("time_varying") or {}
    if not tv.get("kept"):
        return cal, None, ""
    names = tv["regressors"]
    terms = tv if len(names) == 1 and names[0] in MOTOR_REGRESSORS else tv.get("firmware")
    if terms is None:
        return cal, None, (f"firmware files hold the static calibration: the kept "
                           f"{', '.join(names)} terms have no ArduPilot or PX4 parameter "
                           "(they hold one current or throttle term)")
    name = terms["regressors"][0]
    motor = MotorCompensation(name, np.asarray(terms["C"], dtype=float)[:, 0])
    # The alignment of the static fit goes with it, so that the files' headers say the
    # rotation calibration.json applies and they do not.
    kept = Calibration(np.linalg.inv(np.asarray(terms["A"], dtype=float)),
                       np.asarray(terms["b"], dtype=float), alignment=cal.alignment)
    rms = held_out_rms_pct(terms)
    others = [n for n in names if n != name]
    alone = (f" alone, as {' and '.join(others)} {'has' if len(others) == 1 else 'have'} no "
             "parameter" if terms is not tv else "")
    return kept, motor, (f"firmware files hold the fit with the {name} term{alone} "
                         f"(COMPASS_MOT*, CAL_MAGn_*COMP; held-out field magnitude error "
                         f"{rms['time_varying']:.2f} % RMS, static {rms['static']:.2f} %); "
                         "calibration.json and calibration.h hold the static calibration")


#: ArduPilot logs: their ``MAG`` is after COMPASS_ORIENT (docs/flight_logs.md).
ARDUPILOT_LOGS = (".bin", ".log")


def _export_rotation(payload: dict) -> tuple[int | None, str]:
    """The mounting rotation the firmware files set (COMPASS_ORIENT, CAL_MAGn_ROT): the
    confident detection's id, else None. From an ArduPilot log the detection is relative to the
    compass's current COMPASS_ORIENT, so nothing is set and a line says so."""
    found = (payload.get("mounting_rotation") or {}).get("id")
    if found is None or Path(payload["file"]).suffix.lower() not in ARDUPILOT_LOGS:
        return found, ""
    n = payload.get("instance_index") or 0
    key = f"COMPASS_ORIENT{'' if n == 0 else n + 1}"
    name = payload["mounting_rotation"]["name"]
    payload["mounting_rotation"]["suggested"] = {"parameter": key, "on_top_of_current": True}
    return None, (f"mounting: set {key} = {found} ({name}) if it is 0 (ROTATION_NONE) now; an "
                  f"ArduPilot log's MAG is already turned by {key}, so {name} comes on top of "
                  "its current value (compose the two); not written to the firmware files")
