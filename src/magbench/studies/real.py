"""Real recordings, review section 10.2 (Figure 6): every method on every recording.

Without a ground truth, a calibration is judged by J_r of eq. (81), the mean of
``(||m_k||^2 - 1)^2`` with ``m_k = T^-1 (y_k - h)`` (82). Loading is
:mod:`magbench.sources.recordings`; coverage and thickness are :mod:`magbench.core.geometry`.

*Preprocessing* (:func:`fit_recording`). ``scale`` divides by the mean sample norm: the review's
"remove gross scaling errors" (section 10.1, below eq. 68). ``centre`` also subtracts the centre
of the linear least-squares sphere fit and divides by its radius, so the methods see data close
to the unit sphere about the origin, as in the synthetic sweeps (offsets of at most gamma = 1).
``none`` passes the recording as it is (the registry still scales by a power of two). The
estimate is always mapped back: ``T`` and ``h`` are in the recorded units.

*The sweep* (:class:`RealStudy`, ``python -m magbench sweep=real``; one work unit per
recording). Every selected method on every recording and preprocessing, three fits each: on
all samples (J_r in sample), on the
first half in time and on the second half in time, each evaluated on the other half (J_r out of
sample; time halves, not even/odd samples, because neighbouring samples of a slow hand rotation
are nearly equal and an even/odd split would test on the training data). A fit on all of one
qmc5883l recording is also evaluated on the other recording of the same sensor (cross).
Recordings longer than ``max_samples`` are thinned deterministically to every ``s``-th sample,
``s = ceil(n / max_samples)`` (a uniform stride keeps the time base uniform for the gyro methods).

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
(MAG.I.C.AL, Dorveaux) walk into it on recordings whose offset exceeds the field radius. RB % is
the share of meaningful fits among the applicable (not skipped) ones (eq. 77 in spirit).

Methods that need more samples than a fit has, or gyro data a recording lacks, or inputs beyond
samples, gyro and time (MagFactor3's attitude), give rows with ``skipped=True`` and the reason;
they count neither for nor against robustness.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from magbench.core.files import file_sha256, write_csv_atomic
from magbench.core.geometry import coverage, sphere_fit
from magbench.core.metrics import real_cost
from magbench.core.model import Calibration
from magbench.engine.isolation import map_supervised
from magbench.engine.plugins import plugin_modules
from magbench.engine.sweep import Study
from magbench.engine.trial import H_COLUMNS, T_COLUMNS, estimate_columns, run_method
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method, method_label
from magbench.sources.recordings import Recording, load_recording
from magbench.studies.times import split_times, with_times

if TYPE_CHECKING:     # the sweep's summaries only: calibrate shares this module, not pandas
    import pandas as pd

__all__ = ["DEFAULT_MAX_SAMPLES", "PARTNERS", "PREPROCESSING", "REAL_ROW_COLUMNS", "RealStudy",
           "applicability", "calibrated_coverage", "evaluate_recording", "fit_recording",
           "is_meaningful", "is_usable", "method_summary", "preprocessing", "recording_summary",
           "summary_records"]

DEFAULT_MAX_SAMPLES = 2000
PREPROCESSING = ("none", "scale", "centre")
#: Recordings of the same sensor: a fit on one is also evaluated on the other.
PARTNERS = {"qmc5883l_filtered": "qmc5883l_noisy", "qmc5883l_noisy": "qmc5883l_filtered"}
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


@dataclass(frozen=True)
class RealStudy(Study):
    """What the real-data sweep runs (see the module notes); one work unit per recording."""

    root: str
    datasets: Sequence[str]
    algorithms: Sequence[str]
    preprocess: Sequence[str] = ("scale", "centre")
    max_samples: int = DEFAULT_MAX_SAMPLES
    options: dict | None = None
    seed: int = 0
    call_timeout_s: float | None = None
    coverage_ratio: float = 0.5
    sphere_factor: float = 2.0
    plugins: Sequence[str] = ()
    name: str = "real"

    tables: ClassVar[dict] = {"trials": ("real_trials.csv", REAL_ROW_COLUMNS),
                              "times": ("real_trials_times.csv",
                                        ["dataset", "algorithm", "time_s"])}

    def units(self) -> list[str]:
        return list(self.datasets)

    def unit_weight(self, unit: str) -> int:
        return 1

    def describe(self) -> dict:
        """The settings and the SHA-256 of every recording's file: a recording edited between
        a killed run and its rerun makes another fingerprint, so no stale row is reused."""
        out = super().describe()
        out["recording_sha256"] = {name: _recording_sha256(Path(self.root) / name / "data.csv")
                                   for name in self.datasets}
        return out

    def run_unit(self, name: str) -> dict[str, list[dict]]:
        rec = load_recording(self.root, name, check=False).thinned(self.max_samples)
        partner = None
        if name in PARTNERS and PARTNERS[name] in self.datasets:
            partner = load_recording(self.root, PARTNERS[name],
                                     check=False).thinned(self.max_samples)
        rows, times = split_times(evaluate_recording(
            rec, self.algorithms, self.preprocess, options=self.options, seed=self.seed,
            partner=partner, call_timeout_s=self.call_timeout_s,
            coverage_ratio=self.coverage_ratio, sphere_factor=self.sphere_factor), "dataset")
        return {"trials": rows, "times": times}

    def summarize(self, out_dir: Path | str) -> tuple[pd.DataFrame, pd.DataFrame]:
        """Write ``real_summary.csv`` (per recording) and ``fig6_real.csv`` (per method)."""
        import pandas as pd

        out_dir = Path(out_dir)
        trials = pd.read_csv(out_dir / "real_trials.csv", dtype={"error": str, "test_on": str},
                             keep_default_na=True)
        trials["error"] = trials["error"].fillna("")
        trials["test_on"] = trials["test_on"].fillna("")
        trials = with_times(trials, out_dir / "real_trials.csv", "dataset")
        per_recording = recording_summary(trials)
        per_method = method_summary(per_recording)
        write_csv_atomic(per_recording, out_dir / "real_summary.csv")
        write_csv_atomic(per_method, out_dir / "fig6_real.csv")
        return per_recording, per_method


def _recording_sha256(path: Path) -> str:
    """SHA-256 of a recording's file ('missing' if it is not there), read once per version of
    the file (its size and modification time) in this process."""
    try:
        stat = path.stat()
    except OSError:
        return "missing"
    return _sha256_of(str(path), stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _sha256_of(path: str, size: int, mtime_ns: int) -> str:
    return file_sha256(path)


def recording_summary(trials: pd.DataFrame) -> pd.DataFrame:
    """One row per (recording, preprocessing, method): :func:`summary_records` as a table."""
    import pandas as pd

    return pd.DataFrame(summary_records(trials.to_dict("records")))


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


def method_summary(per_recording: pd.DataFrame) -> pd.DataFrame:
    """Figure 6's numbers: one row per (preprocessing, method).

    ``RB_pct`` is the share of meaningful all-samples fits among the applicable recordings;
    ``rho_in`` the mean J_r in sample over the meaningful ones (the review's "mean value of the
    cost function (81) across all the recorded datasets", restricted to meaningful fits as in
    eq. 78) and ``accuracy_in = 1 / rho_in``; ``rho_out`` and ``accuracy_out`` the same for the
    held-out J_r over the meaningful recordings that have one; ``median_ratio_in`` and
    ``median_ratio_out`` the medians over the same recordings of J_r over the sphere fit's J_r
    on the same data (scale-free: the means are dominated by the noisiest recordings).
    """
    import pandas as pd

    rows = []
    for (how, name), g in per_recording.groupby(["preprocess", "algorithm"], sort=False):
        applicable = g[~g["skipped"].astype(bool)]
        good = applicable[applicable["meaningful"].astype(bool)]
        out = good[np.isfinite(good["J_r_out"])]
        rho_in = float(good["J_r_in"].mean()) if len(good) else np.nan
        rho_out = float(out["J_r_out"].mean()) if len(out) else np.nan
        rows.append({
            "preprocess": how, "algorithm": name, "label": method_label(name),
            "n_recordings": len(g), "n_applicable": len(applicable),
            "n_meaningful": len(good), "n_out": len(out),
            "RB_pct": 100.0 * len(good) / len(applicable) if len(applicable) else np.nan,
            "rho_in": rho_in, "accuracy_in": 1.0 / rho_in if len(good) else np.nan,
            "rho_out": rho_out, "accuracy_out": 1.0 / rho_out if len(out) else np.nan,
            "median_ratio_in": float((good["J_r_in"] / good["J_r_sphere_in"]).median())
            if len(good) else np.nan,
            "median_ratio_out": float((out["J_r_out"] / out["J_r_sphere_out"]).median())
            if len(out) else np.nan,
            "tau_s": float(good["time_s"].mean()) if len(good) else np.nan,
        })
    return pd.DataFrame(rows)


#: The methods whose accuracy on a method's kept recordings is its selection's yardstick.
SELECTION_REFERENCE = ("twostep", "crassidis", "dorveaux", "vasconcelos", "ali", "wu_shi",
                       "magical")
#: A kept subset whose recordings are this much easier for the reference methods sets the bar.
SELECTION_FACTOR = 2.0


def selection_inflation(per_recording: pd.DataFrame,
                        reference: Sequence[str] = SELECTION_REFERENCE) -> pd.DataFrame:
    """How much of a method's in-sample accuracy comes from which recordings it kept.

    A method meaningful on only some recordings is scored on those (eq. 78): if they are the
    easy ones its 1/mean J_r is high whatever it does. For every (preprocessing, method) that
    kept a strict subset, the other reference methods' accuracy on that subset is set beside
    their accuracy on all the recordings they solved; ``inflation`` is the median ratio over
    them (1 = a representative subset) and ``others_on_kept`` their median accuracy on the
    subset. ``set_by_selection`` flags an inflation of at least :data:`SELECTION_FACTOR`.

    Returns
    -------
    DataFrame
        ``preprocess``, ``algorithm``, ``n_kept``, ``others_on_kept``, ``inflation``,
        ``set_by_selection``; only the methods that kept a strict, non-empty subset.
    """
    import pandas as pd

    rows = []
    usable = per_recording[~per_recording["skipped"].astype(bool)]
    for (how, name), g in usable.groupby(["preprocess", "algorithm"], sort=False):
        kept = set(g.loc[g["meaningful"].astype(bool), "dataset"])
        if not kept or len(kept) == len(g):
            continue
        same = usable[(usable["preprocess"] == how) & usable["algorithm"].isin(reference)
                      & (usable["algorithm"] != name) & usable["meaningful"].astype(bool)]
        on_kept, ratio = [], []
        for _, o in same.groupby("algorithm"):
            sub = o[o["dataset"].isin(kept)]
            if len(sub):
                on_kept.append(1.0 / sub["J_r_in"].mean())
                ratio.append(on_kept[-1] * o["J_r_in"].mean())
        inflation = float(np.median(ratio)) if ratio else np.nan
        rows.append({"preprocess": how, "algorithm": name, "n_kept": len(kept),
                     "others_on_kept": float(np.median(on_kept)) if on_kept else np.nan,
                     "inflation": inflation,
                     "set_by_selection": bool(inflation >= SELECTION_FACTOR)})
    return pd.DataFrame(rows, columns=["preprocess", "algorithm", "n_kept", "others_on_kept",
                                       "inflation", "set_by_selection"])
