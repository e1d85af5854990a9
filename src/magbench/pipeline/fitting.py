"""Fitting one recording with a method and scoring the fit by J_r: what ``calibrate`` and the
real-data sweep (:mod:`magbench.studies.real`) share.

Without a ground truth, a calibration is judged by J_r of eq. (81), the mean of
``(||m_k||^2 - 1)^2`` with ``m_k = T^-1 (y_k - h)`` (82).

*Preprocessing* (:func:`fit_recording`). ``scale`` divides by the mean sample norm: the review's
"remove gross scaling errors" (section 10.1, below eq. 68). ``centre`` also subtracts the centre
of the linear least-squares sphere fit and divides by its radius, so the methods see data close
to the unit sphere about the origin, as in the synthetic sweeps (offsets of at most gamma = 1).
``none`` passes the recording as it is (the registry still scales by a power of two). The
estimate is always mapped back: ``T`` and ``h`` are in the recorded units.

*Rows* (:func:`evaluate_recording`): every method and preprocessing fitted on each fit set (by
default all samples, and each half in time scored on the other half), one row per test set;
:func:`summary_records` folds them into one record per method. The fits run in a supervised
child, so a method that ends its process gives rows with the reason.

*Robustness on real data* (:func:`is_meaningful`). There is no ``J0`` of eq. (75); a fit counts
as meaningful when (i) the method ended normally (converged, finite), (ii) its J_r on its fit
data is at most ``sphere_factor`` (2) times that of the linear least-squares sphere fit
``T = r I, h = c`` on the same data (every full or sphere model contains that answer, so doing
much worse means the method missed the basin a simple linear fit finds; the factor leaves room
for sphere-model methods, which at best tie with it), and (iii) its calibrated directions cover
at least ``coverage_ratio`` (0.5) times the coverage of the sphere fit's directions.
Condition (iii) is needed because J_r has a
degenerate minimiser: with ``h`` far away and ``T = D I``, every ``m_k`` lands near one point
of the unit sphere and J_r tends to 0 as D grows. Methods that start from ``y_k / ||y_k||``
(MAG.I.C.AL, Dorveaux) walk into it on recordings whose offset exceeds the field radius.

Methods that need more samples than a fit has, or gyro data a recording lacks, or inputs beyond
samples, gyro and time (MagFactor3's attitude), give rows with ``skipped=True`` and the reason
(:func:`applicability`).
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from magbench.core.geometry import coverage, sphere_fit
from magbench.core.metrics import real_cost
from magbench.core.model import Calibration
from magbench.engine.isolation import map_supervised
from magbench.engine.plugins import plugin_modules
from magbench.engine.trial import H_COLUMNS, T_COLUMNS, estimate_columns, run_method
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method
from magbench.sources.recordings import Recording

__all__ = ["DEFAULT_MAX_SAMPLES", "PREPROCESSING", "REAL_ROW_COLUMNS", "applicability",
           "calibrated_coverage", "evaluate_recording", "fit_recording", "is_meaningful",
           "is_usable", "preprocessing", "summary_records"]

DEFAULT_MAX_SAMPLES = 2000
PREPROCESSING = ("none", "scale", "centre")
REAL_ROW_COLUMNS = (["dataset", "n_rows", "stride", "preprocess", "algorithm", "fit_on", "K_fit",
                     "test_on", "K_test", "skipped", "ok", "error", "n_iter",
                     "J_r_fit", "J_r_test", "J_r_sphere_fit", "J_r_sphere_test",
                     "coverage_fit", "coverage_sphere_fit", "usable", "meaningful"]
                    + H_COLUMNS + T_COLUMNS)


def applicability(name: str, rec: Recording) -> str:
    """Why ``name`` cannot run on ``rec`` (empty string if it can)."""
    spec = get_method(name)
    if rec.K < spec.min_samples:
        return f"skipped: {name} needs at least {spec.min_samples} samples, this fit has {rec.K}"
    if spec.needs_gyro and not rec.has_gyro:
        return f"skipped: {name} needs gyroscope data and times; the recording has none"
    params = inspect.signature(spec.fit).parameters.values()
    needs = [p.name for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY
             and p.default is inspect.Parameter.empty
             and p.name not in ("angular_rate", "time", "rng")]
    if needs:
        held = [n for n in needs if getattr(rec, n, None) is not None]
        if held:
            return (f"skipped: {name} also needs {', '.join(needs)}; the recording holds "
                    f"{', '.join(held)}, but calibrate does not pass it to a candidate's fit "
                    "(it aligns the chosen fit to the IMU afterwards instead)")
        return f"skipped: {name} also needs {', '.join(needs)}, which a recording does not hold"
    return ""


def preprocessing(y: np.ndarray, how: str) -> tuple[np.ndarray, float]:
    """Offset and scale with ``y' = (y - offset) / scale`` for the named preprocessing."""
    if how == "none":
        return np.zeros(3), 1.0
    if how == "scale":
        return np.zeros(3), float(np.mean(np.sqrt(np.einsum("ij,ij->i", y, y))))
    if how == "centre":
        c, r = sphere_fit(y)
        return c, r
    raise ValueError(f"preprocess must be one of {', '.join(PREPROCESSING)}, got {how!r}")


def fit_recording(rec: Recording, method: str, preprocess: str = "centre",
                  options: dict | None = None, inputs: dict | None = None) -> Calibration:
    """Calibrate ``rec`` with ``method`` after preprocessing; ``T, h`` in the recorded units.

    With ``y' = (y - o) / s`` and the method's ``y' = T' m + h'``, the recording obeys
    ``y = (s T') m + (s h' + o)``. ``inputs`` are the method's inertial keywords; by default
    a gyro-aided method gets the recording's ``angular_rate`` and ``time``.
    """
    offset, scale = preprocessing(rec.y, preprocess)
    extra = dict(inputs or {})
    if inputs is None and get_method(method).needs_gyro:
        extra = {"angular_rate": rec.gyro, "time": rec.t}
    cal = calibrate((rec.y - offset) / scale, method, raw=True, **extra,
                    **dict(options or {}))
    # replace() keeps every other field (the gyro bias, an alignment to the inertial axes),
    # none of which a common scale and offset of the samples changes.
    return replace(cal, T=scale * cal.T, h=scale * cal.h + offset)


def calibrated_coverage(y: np.ndarray, T: np.ndarray, h: np.ndarray) -> float:
    """Coverage of the calibrated directions ``T^-1 (y - h)``."""
    return coverage(np.linalg.solve(T, (y - h).T).T)


def is_meaningful(ok: bool, J_r: float, J_r_sphere: float, coverage_fit: float,
                  coverage_sphere: float, coverage_ratio: float = 0.5,
                  sphere_factor: float = 2.0) -> bool:
    """Robustness criterion on real data (see the module notes).

    ``ok`` (ended normally), ``J_r <= sphere_factor * J_r_sphere`` and
    ``coverage_fit >= coverage_ratio * coverage_sphere``.
    """
    return bool(ok and is_usable(coverage_fit, coverage_sphere, coverage_ratio)
                and np.isfinite(J_r) and J_r <= sphere_factor * J_r_sphere)


def is_usable(coverage_fit: float, coverage_sphere: float, coverage_ratio: float = 0.5) -> bool:
    """An estimate that is not the degenerate one: its directions keep their coverage."""
    return bool(np.isfinite(coverage_fit) and coverage_fit >= coverage_ratio * coverage_sphere)


def _sphere_baseline(fit: Recording, tests: list[tuple[str, Recording | None]]) -> dict:
    """The sphere fit on ``fit``: the baseline of every method's rows on that fit set.

    Computed once per fit set, not once per method and preprocessing: its coverage alone was
    a fifth of ``calibrate``'s fitting time.
    """
    c, r = sphere_fit(fit.y)
    sphere_T = r * np.eye(3)
    return {"J_r_sphere_fit": real_cost(fit.y, sphere_T, c),
            "coverage_sphere_fit": coverage(fit.y - c),
            "J_r_sphere_test": [real_cost(test.y, sphere_T, c) if test is not None else np.nan
                                for _, test in tests]}


def _fit_row(rec: Recording, part: str, fit: Recording,
             tests: list[tuple[str, Recording | None]],
             method: str, preprocess: str, options: dict, seed: int,
             call_timeout_s: float | None, coverage_ratio: float,
             sphere_factor: float, sphere: dict) -> list[dict]:
    """Fit once on ``fit`` and evaluate on each test set; one row per test set (at least one).

    ``sphere`` is :func:`_sphere_baseline` of ``fit`` and ``tests``.
    """
    base = {"dataset": rec.name, "n_rows": rec.n_rows, "stride": rec.stride,
            "preprocess": preprocess, "algorithm": method, "fit_on": part, "K_fit": fit.K,
            "J_r_sphere_fit": sphere["J_r_sphere_fit"],
            "coverage_sphere_fit": sphere["coverage_sphere_fit"]}
    reason = applicability(method, fit)
    T = h = None
    n_iter, elapsed, error = 0, 0.0, reason
    if not reason:
        out = run_method(method, lambda o: fit_recording(fit, method, preprocess, o),
                         options=options, seed=seed, stream=(rec.name,),
                         stream_tail=(part, preprocess), call_timeout_s=call_timeout_s)
        T, h, n_iter, elapsed, error = out.T, out.h, out.n_iter, out.time_s, out.error
    ok = not error
    J_fit = real_cost(fit.y, T, h) if T is not None else np.nan
    cov_fit = calibrated_coverage(fit.y, T, h) if T is not None else np.nan
    rows = []
    for (test_name, test), J_sphere_test in zip(tests, sphere["J_r_sphere_test"], strict=True):
        J_test = real_cost(test.y, T, h) if (T is not None and test is not None) else np.nan
        rows.append({
            **base, "test_on": test_name, "K_test": 0 if test is None else test.K,
            "skipped": bool(reason), "ok": ok, "error": error, "time_s": elapsed,
            "n_iter": n_iter, "J_r_fit": J_fit, "J_r_test": J_test,
            "J_r_sphere_test": J_sphere_test,
            "coverage_fit": cov_fit,
            "usable": T is not None and is_usable(cov_fit, base["coverage_sphere_fit"],
                                                  coverage_ratio),
            "meaningful": is_meaningful(ok, J_fit, base["J_r_sphere_fit"], cov_fit,
                                        base["coverage_sphere_fit"], coverage_ratio,
                                        sphere_factor),
            **estimate_columns(T, h),
        })
    return rows


def _method_rows(unit: tuple[str, str], *, rec: Recording, fits: list, spheres: list,
                 options: dict, seed: int, call_timeout_s: float | None,
                 coverage_ratio: float, sphere_factor: float) -> list[dict]:
    """:func:`evaluate_recording`'s rows of one (preprocessing, method)."""
    how, method = unit
    rows = []
    for (part, fit, tests), sphere in zip(fits, spheres, strict=True):
        rows += _fit_row(rec, part, fit, tests, method, how, dict(options.get(method) or {}),
                         seed, call_timeout_s, coverage_ratio, sphere_factor, sphere)
    return rows


def evaluate_recording(rec: Recording, algorithms: Sequence[str], preprocess: Sequence[str],
                       *, options: dict | None = None, seed: int = 0,
                       partner: Recording | None = None, call_timeout_s: float | None = None,
                       coverage_ratio: float = 0.5, sphere_factor: float = 2.0,
                       splits: Sequence[tuple[str, Recording, list]] | None = None
                       ) -> list[dict]:
    """All rows of one (already thinned) recording: methods x preprocessing x fits.

    ``splits`` replaces the fit sets (all samples and the two halves in time): a list of
    ``(fit_on, fit recording, [(test_on, test recording or None), ...])``.
    """
    options = options or {}
    fits = list(splits) if splits is not None else _halves_splits(rec, partner)
    spheres = [_sphere_baseline(fit, tests) for _, fit, tests in fits]
    work = functools.partial(_method_rows, rec=rec, fits=fits, spheres=spheres,
                             options=options, seed=seed, call_timeout_s=call_timeout_s,
                             coverage_ratio=coverage_ratio, sphere_factor=sphere_factor)
    # The fits run in a supervised child (here, unless this process is already supervised,
    # as a sweep's worker is): a method that ends its process gives rows with the reason.
    per_method = map_supervised(work, [(how, m) for how in preprocess for m in algorithms],
                                name=f"fits of {rec.name}", plugins=plugin_modules(algorithms))
    return [row for rows in per_method for row in rows]


def _halves_splits(rec: Recording, partner: Recording | None) -> list[tuple]:
    """All samples (tested on the partner, if any) and each half in time tested on the other."""
    first, second = rec.halves()
    return [("all", rec, [("partner:" + partner.name, partner)] if partner is not None else
             [("", None)]),
            ("first_half", first, [("second_half", second)]),
            ("second_half", second, [("first_half", first)])]


def _nanmean(values: Sequence[float]) -> float:
    """The mean of the values that are not NaN (NaN without any), as pandas' ``mean``."""
    x = np.asarray(values, dtype=float)
    x = x[~np.isnan(x)]
    return float(x.mean()) if x.size else np.nan


def summary_records(trials: Sequence[Mapping]) -> list[dict]:
    """One record per (recording, preprocessing, method), in the order of first appearance.

    ``J_r_in`` is the fit on all samples; ``J_r_out`` the mean of the two half-fits' J_r on the
    other half when both half-fits gave a usable estimate (not the degenerate one; an estimate
    stopped by its iteration cap counts, since it is what a user would get), else NaN;
    ``J_r_cross`` the all-samples fit on the partner recording; ``meaningful`` the
    all-samples fit's criterion. Plain records, so that ``calibrate`` needs no pandas; the
    sweep's table is :func:`recording_summary`.
    """
    keys = ["dataset", "preprocess", "algorithm"]
    groups: dict[tuple, list[Mapping]] = {}
    for row in trials:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    rows = []
    for key, group in groups.items():
        full = next(r for r in group if r["fit_on"] == "all")
        halves = [r for r in group if r["fit_on"] != "all"]
        cross = [r for r in group if str(r["test_on"]).startswith("partner:")]
        halves_ok = bool(len(halves) == 2 and all(bool(r["usable"]) for r in halves))
        rows.append({
            **dict(zip(keys, key, strict=True)), "K": int(full["K_fit"]),
            "n_rows": int(full["n_rows"]), "stride": int(full["stride"]),
            "skipped": bool(full["skipped"]), "ok": bool(full["ok"]),
            "meaningful": bool(full["meaningful"]), "error": full["error"],
            "time_s": float(full["time_s"]), "n_iter": int(full["n_iter"]),
            "J_r_in": float(full["J_r_fit"]), "J_r_sphere_in": float(full["J_r_sphere_fit"]),
            "J_r_out": _nanmean([r["J_r_test"] for r in halves]) if halves_ok else np.nan,
            "J_r_sphere_out": _nanmean([r["J_r_sphere_test"] for r in halves]) if halves
            else np.nan,
            "halves_usable": halves_ok,
            "cross_on": cross[0]["test_on"][len("partner:"):] if cross else "",
            "J_r_cross": float(cross[0]["J_r_test"]) if cross else np.nan,
            "coverage": float(full["coverage_fit"]),
            "coverage_sphere": float(full["coverage_sphere_fit"]),
            **{c: float(full[c]) for c in H_COLUMNS + T_COLUMNS},
        })
    return rows
