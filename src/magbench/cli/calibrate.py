"""``python -m magbench calibrate file=PATH [method=NAME] [columns=[mx,my,mz]] [out=DIR]``.

Calibrates a user's own recording: every candidate method (or the one named) is fitted on all
samples (J_r in sample, eq. 81) and on each half in time with J_r on the other half (out of
sample), as in the real-data sweep (:mod:`magbench.studies.real`). The candidates are the
registered methods except the review's printed variants (family ``variant``: benchmark-only,
wrong as printed) and, without gyro data, the gyro-aided ones; ``method=NAME`` runs any one.
The methods are ranked, meaningful fits first (:func:`magbench.studies.real.is_meaningful`),
then by J_r out of sample (in sample where a recording is too short to split).

The best (or the named) calibration is written in the safe gauge of :mod:`magbench.core.gauge`:
the correction a firmware applies is ``m = A (y - b)`` with ``A = (T T^T)^(-1/2)`` symmetric
positive definite and ``b = h``, in the recording's units (never rotated, never a mirror image;
the rotation removed from the method's own ``T^-1`` is reported). Beside ``calibration.json``
(:func:`magbench.core.exports.to_json_dict`) go ``calibration.h`` and ``ardupilot.param`` (the
latter only where ArduPilot accepts the values, see :mod:`magbench.core.exports`). The verdict
(:mod:`magbench.core.verdict`) is the corrected field magnitude's error in percent on the half
in time each half-fit was not fitted on (in sample when there are no usable half-fits) and the
heading error it implies; a warning is printed and stored when the field directions cover too
little of the sphere. A picture shows the data before and after.
The preprocessing is ``centre`` (remove the sphere-fit centre and radius
first), which the real-data sweep found necessary for MAG.I.C.AL and Dorveaux when the offset
exceeds the field radius; ``preprocess=scale`` selects the review's.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

from magbench.cli.config import (
    UsageError,
    check_common,
    check_integer,
    check_options,
    writable_folder,
)
from magbench.core.exports import ardupilot_param_file, ardupilot_params, c_header, to_json_dict
from magbench.core.files import write_csv_atomic, write_text_atomic
from magbench.core.gauge import safe_gauge
from magbench.core.model import Calibration
from magbench.core.verdict import coverage_report, magnitude_verdict
from magbench.figures.real import calibration_picture
from magbench.figures.style import save_figure
from magbench.methods.registry import get_method, methods
from magbench.sources.recordings import Recording, read_samples
from magbench.studies.real import (
    DEFAULT_MAX_SAMPLES,
    PREPROCESSING,
    applicability,
    evaluate_recording,
    recording_summary,
)

__all__ = ["calibration_json", "rank", "run_calibrate"]


def _columns(cfg: DictConfig) -> list | None:
    columns = cfg.get("columns")
    if columns is None:
        return None
    if OmegaConf.is_list(columns):
        return list(OmegaConf.to_container(columns))
    raise UsageError(f"columns must be a list of three names or positions, e.g. "
                     f"columns=[mx,my,mz] or columns=[0,1,2], got {columns!r}")


def _candidates(cfg: DictConfig, rec_has_gyro: bool) -> list[str]:
    name = cfg.get("method")
    if name is not None:
        if str(name) not in methods():
            raise UsageError(f"unknown method {name!r}; expected one of: "
                             f"{', '.join(methods())}")
        return [str(name)]
    # The printed variants reproduce the review's misprints: benchmark rows, never a user's fit.
    return [m for m in methods() if get_method(m).family != "variant"
            and (rec_has_gyro or not get_method(m).needs_gyro)]


def rank(summary: pd.DataFrame) -> pd.DataFrame:
    """Rows of :func:`magbench.studies.real.recording_summary` in ranked order, with a
    ``rank`` column.

    Meaningful fits first, by J_r out of sample (in sample if there is none), then fits that
    ran but are not meaningful, then failures and skipped methods.
    """
    key = summary["J_r_out"].where(np.isfinite(summary["J_r_out"]), summary["J_r_in"])
    group = np.where(summary["meaningful"], 0, np.where(summary["ok"], 1, 2))
    out = summary.assign(_group=group, _key=key.fillna(np.inf))
    out = out.sort_values(["_group", "_key"], kind="stable").drop(columns=["_group", "_key"])
    out.insert(0, "rank", range(1, len(out) + 1))
    return out.reset_index(drop=True)


def _estimate(row: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` of a row of the real-data tables."""
    T = np.array([[row[f"T_{i}{j}"] for j in range(3)] for i in range(3)], dtype=float)
    return T, np.array([row[f"h_{i}"] for i in range(3)], dtype=float)


def calibration_json(row: pd.Series, *, file: str, columns: list, n_file: int,
                     preprocess: str, verdict: dict | None = None,
                     coverage: dict | None = None) -> dict:
    """The chosen calibration as a JSON-ready dict: the correction in the safe gauge.

    The schema of :func:`magbench.core.exports.to_json_dict` (``A``, ``b`` of ``m = A (y - b)``,
    ``T = A^-1``, ``h = b``), plus the method, verdict and coverage; ``removed`` records the
    rotation angle taken out of the method's own ``T^-1``, whether it was a mirror image, and
    the method's ``T`` itself.

    Raises
    ------
    ValueError
        If the row's ``T`` is singular or not finite (such a fit is never written).
    """
    T, h = _estimate(row)
    gauge = safe_gauge(T, h)
    warnings_ = [coverage["warning"]] if coverage and coverage.get("warning") else []
    return {
        **to_json_dict(Calibration(T, h), units="as recorded in the file", columns=columns),
        "file": file, "method": row["algorithm"], "label": get_method(row["algorithm"]).label,
        "removed": {"rotation_deg": gauge.rotation_deg, "mirrored": gauge.mirrored,
                    "method_T": T.tolist()},
        "field_strength": float(np.cbrt(abs(np.linalg.det(T)))),
        "verdict": verdict, "coverage": coverage, "warnings": warnings_,
        "J_r_in": float(row["J_r_in"]), "J_r_out": _finite(row["J_r_out"]),
        "J_r_sphere_fit": float(row["J_r_sphere_in"]), "meaningful": bool(row["meaningful"]),
        "converged": bool(row["ok"]), "n_iter": int(row["n_iter"]),
        "preprocess": preprocess, "samples_used": int(row["K"]), "samples_in_file": n_file,
        "stride": int(row["stride"]),
    }


def held_out_corrected(trials: pd.DataFrame, rec: Recording, method: str,
                       preprocess: str) -> np.ndarray | None:
    """Each half in time corrected by the fit on the other half, stacked; None unless both
    half-fits gave a usable estimate (the recording is too short or a half-fit failed)."""
    rows = trials[(trials["algorithm"] == method) & (trials["preprocess"] == preprocess)
                  & (trials["fit_on"] != "all")]
    if len(rows) != 2 or not rows["usable"].astype(bool).all():
        return None
    halves = dict(zip(("first_half", "second_half"), rec.halves(), strict=True))
    out = []
    for _, row in rows.iterrows():
        T, h = _estimate(row)
        out.append(np.linalg.solve(T, (halves[row["test_on"]].y - h).T).T)
    return np.vstack(out)


def chosen_verdict(trials: pd.DataFrame, rec: Recording, best: pd.Series,
                   preprocess: str) -> dict:
    """:func:`magbench.core.verdict.magnitude_verdict` of the chosen method, held out when
    both half-fits are usable, else in sample on ``rec``."""
    corrected = held_out_corrected(trials, rec, best["algorithm"], preprocess)
    if corrected is not None:
        return magnitude_verdict(corrected, held_out=True)
    T, h = _estimate(best)
    return magnitude_verdict(np.linalg.solve(T, (rec.y - h).T).T, held_out=False)


def _verdict_lines(payload: dict) -> list[str]:
    v, g = payload["verdict"], payload["removed"]
    f, hd = v["field_error_pct"], v["heading_error_deg"]
    where = ("held out: each half in time corrected by the fit on the other half" if
             v["held_out"] else "in sample: no usable half-fits, so this flatters the fit")
    return [f"verdict ({where}; {v['samples']} samples): field magnitude error {f['p95']:.2f} % "
            f"(95th percentile), {f['max']:.2f} % (max); heading error of a level compass about "
            f"{hd['p95']:.2f} deg (95 %), {hd['max']:.2f} deg (max) in a horizontal field, "
            "about twice at 60 deg inclination",
            f"field strength {payload['field_strength']:.4g} (file units); the method's own "
            f"correction held a {g['rotation_deg']:.1f} deg rotation"
            f"{' and a mirror image' if g['mirrored'] else ''}, removed (m = A (y - b), A "
            "symmetric positive definite)"]


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _fmt(x: float) -> str:
    return f"{x:11.3g}" if np.isfinite(x) else f"{'-':>11}"


def _why_not(r) -> str:
    if isinstance(r.error, str) and r.error:
        return r.error
    if not r.coverage >= 0.5 * r.coverage_sphere:
        return (f"degenerate: calibrated directions cover {r.coverage:.2f} of the sphere, the "
                f"sphere fit's {r.coverage_sphere:.2f}")
    return f"J_r above twice the sphere fit's ({r.J_r_sphere_in:.3g})"


def _table(ranked: pd.DataFrame) -> str:
    lines = [f"{'rank':>4}  {'method':<16}{'J_r in':>11}{'J_r out':>11}{'time ms':>9}  note"]
    for r in ranked.itertuples(index=False):
        note = "" if r.meaningful else _why_not(r)
        lines.append(f"{r.rank:>4}  {r.algorithm:<16}{_fmt(r.J_r_in)}{_fmt(r.J_r_out)}"
                     f"{1e3 * r.time_s:9.2f}  {note[:70]}")
    return "\n".join(lines)


def run_calibrate(cfg: DictConfig) -> int:
    """The ``calibrate`` command; a bad file or value raises :class:`UsageError`."""
    common = check_common(cfg)
    if not cfg.get("file"):
        raise UsageError("calibrate needs file=PATH, a CSV of magnetometer samples (columns "
                         "mx,my,mz, or choose them with columns=[...])")
    path = Path(str(cfg.file))
    preprocess = str(cfg.get("preprocess", "centre"))
    if preprocess not in PREPROCESSING:
        raise UsageError(f"preprocess must be one of {', '.join(PREPROCESSING)}, got "
                         f"{preprocess!r}")
    max_samples = check_integer(cfg.get("max_samples", DEFAULT_MAX_SAMPLES), "max_samples", 8)
    columns = _columns(cfg)
    name = cfg.get("method")
    need = get_method(str(name)).min_samples if name and str(name) in methods() else min(
        get_method(m).min_samples for m in methods())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            rec = read_samples(path, columns, min_samples=need)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    for w in caught:
        print(f"magbench: warning: {w.message}", file=sys.stderr)
    candidates = _candidates(cfg, rec.has_gyro)
    options = check_options(cfg, candidates)
    thinned = rec.thinned(max_samples)
    if name is not None:
        reason = applicability(str(name), thinned)
        if reason:
            raise UsageError(reason.removeprefix("skipped: "))
    if thinned.stride > 1:
        print(f"using 1 sample in {thinned.stride}: {thinned.K} of {rec.K} "
              f"(max_samples={max_samples})")
    rows = evaluate_recording(thinned, candidates, [preprocess], options=options,
                              seed=common["seed"], call_timeout_s=common["call_timeout_s"])
    ranked = rank(recording_summary(pd.DataFrame(rows)))
    print(f"{path.name}: {rec.K} samples, preprocessing '{preprocess}'; J_r (eq. 81) in sample "
          "and out of sample (fit on one half in time, tested on the other)")
    print(_table(ranked))
    usable = ranked[ranked["meaningful"]]
    if usable.empty:
        raise UsageError("no method produced a meaningful calibration of this recording (see "
                         "the table); check that the sensor was turned through many "
                         "orientations in a steady field")
    trials = pd.DataFrame(rows)
    best = next((r for _, r in usable.iterrows() if _writable(r)), None)
    if best is None:
        raise UsageError("every meaningful fit has a singular or non-finite T; no correction "
                         "can be written")
    out = writable_folder(cfg.out if cfg.get("out") else f"{rec.name}-calibration", "out")
    T, h = _estimate(best)
    cover = coverage_report((thinned.y - h) @ safe_gauge(T, h).A.T)
    payload = calibration_json(best, file=str(path), columns=list(rec.columns),
                               n_file=rec.K, preprocess=preprocess,
                               verdict=chosen_verdict(trials, thinned, best, preprocess),
                               coverage=cover)
    write_text_atomic(json.dumps(payload, indent=2) + "\n", out / "calibration.json")
    written = ["calibration.json (m = A (y - b))", *_write_exports(Calibration(T, h), payload,
                                                                  out)]
    write_csv_atomic(ranked, out / "ranking.csv")
    save_figure(_picture(rec, payload, calibration_picture), out / "calibration.png")
    print(f"chosen: {payload['label']} (J_r in {payload['J_r_in']:.3g})")
    print("\n".join(_verdict_lines(payload)))
    for warning in payload["warnings"]:
        print(f"magbench: warning: {warning}", file=sys.stderr)
    print(f"wrote {out}/: {', '.join([*written, 'ranking.csv', 'calibration.png'])}")
    return 0


def _write_exports(cal: Calibration, payload: dict, out: Path) -> list[str]:
    """calibration.h always; ardupilot.param when ArduPilot accepts the values (else one line
    saying why not). Returns the names written."""
    f = payload["verdict"]["field_error_pct"]
    verdict = (f"{payload['label']}: field magnitude error {f['p95']:.2f} % (95th percentile), "
               f"{f['max']:.2f} % (max), "
               f"{'held out' if payload['verdict']['held_out'] else 'in sample'}; "
               f"from {Path(payload['file']).name}")
    write_text_atomic(c_header(cal, "mag_cal", verdict=verdict), out / "calibration.h")
    try:
        params = ardupilot_params(cal)
    except ValueError as exc:
        print(f"not writing ardupilot.param: {exc}")
        return ["calibration.h"]
    note = ("magbench calibration for ArduPilot: corrected = M (COMPASS_SCALE (raw + OFS)), "
            f"raw in milligauss\n{verdict}")
    write_text_atomic(ardupilot_param_file(params, note), out / "ardupilot.param")
    return ["calibration.h", "ardupilot.param"]


def _writable(row: pd.Series) -> bool:
    try:
        safe_gauge(*_estimate(row))
    except ValueError:
        return False
    return True


def _picture(rec: Recording, payload: dict, draw):
    A = np.array(payload["A"])
    b = np.array(payload["b"])
    y = rec.thinned(5000).y
    before = y / float(np.mean(np.linalg.norm(y, axis=1)))
    after = (y - b) @ A.T
    where = Path(payload["file"])
    return draw(before, after, f"{where.parent.name}/{where.name}: {payload['label']}, "
                               f"J_r = {payload['J_r_in']:.3g}")
