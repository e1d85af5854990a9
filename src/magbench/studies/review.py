"""The review's Monte Carlo sweeps (Algorithm 8; Table 2, Figures 2-5) and partial coverage.

A work unit is one trial at one point: a dataset drawn from ``rng(seed, point.key, trial)``
(keyed by the point's values, so the nominal point draws the same datasets in every sweep that
contains it) on which every selected method runs, one row per method. ``meaningful`` is eq.
(76), ``J < delta * J0``, wherever an estimate exists, a capped one included.

A sweep may also vary one method's option instead of the data (:class:`OptionAxis`, e.g. the
EKF's initial covariance, ``vary: options.crassidis.P0``): every trial's dataset is drawn once
and the method runs on it at its default and at each value, the value in a column named
``<method>.<option>`` (empty for the default run and for the other methods).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.crb import crb_covariance, crb_mse, efficient_expected_J
from magbench.core.files import file_sha256, read_csv_columns, write_csv_atomic
from magbench.core.intervals import bootstrap_paired_ratio
from magbench.core.metrics import accuracy_cost, summarize, trivial_cost
from magbench.core.seeding import rng
from magbench.engine.sweep import Study
from magbench.engine.trial import H_COLUMNS, T_COLUMNS, estimate_columns, run_method
from magbench.methods.api import CheckedSamples, calibrate
from magbench.methods.registry import get_method
from magbench.sources.synthetic import Point, make_dataset
from magbench.studies.selection import write_efficient_selection
from magbench.studies.times import split_times, with_times

__all__ = ["POINT_COLUMNS", "ROW_COLUMNS", "SELECTION_RECORD", "SUMMARY_COLUMNS",
           "TIME_COLUMNS", "TRUTH_COLUMNS",
           "OptionAxis", "ReviewStudy", "coverage_label", "efficiency_intervals",
           "method_options", "point_with", "points_for", "read_trials", "summarize_review",
           "trial_rows", "with_coverage_column", "write_efficiency"]

POINT_COLUMNS = ["K", "sigma", "beta", "gamma", "cap_deg", "band_deg"]
TRUTH_COLUMNS = [f"h_true_{i}" for i in range(3)] + [f"T_true_{i}{j}" for i in range(3)
                                                      for j in range(3)]
ROW_COLUMNS = (POINT_COLUMNS + ["trial", "seed", "algorithm", "ok", "error", "n_iter",
                                "J", "J_h", "J_T", "J0", "meaningful", "sq_err", "crb", "crb_J"]
               + TRUTH_COLUMNS + H_COLUMNS + T_COLUMNS)
#: The columns of a study's times sidecar (:mod:`magbench.studies.times`).
TIME_COLUMNS = ["trial", "algorithm", "time_s"]
#: The key of ``efficiency.json`` recording what ``efficient_selection.csv`` was computed for.
SELECTION_RECORD = "efficient_selection"
#: The columns :func:`summarize_review` needs: ``time_s`` comes from the sidecar (or from an
#: older trials file that still holds it), ``trial`` matches the sidecar's rows.
SUMMARY_COLUMNS = POINT_COLUMNS + ["trial", "algorithm", "meaningful", "J", "time_s", "sq_err",
                                   "crb", "crb_J"]


def truth_columns(T: np.ndarray, h: np.ndarray) -> dict:
    """``h_true_*`` and ``T_true_*`` of a dataset."""
    return {**dict(zip(TRUTH_COLUMNS[:3], np.asarray(h).tolist(), strict=True)),
            **dict(zip(TRUTH_COLUMNS[3:], np.asarray(T).ravel().tolist(), strict=True))}


@dataclass(frozen=True)
class OptionAxis:
    """One method's option swept over values on the same datasets.

    Attributes
    ----------
    method, option : str
        A registered method and one of its keyword options.
    values : tuple
        The option's values; the method also runs once at its default (column empty).
    """

    method: str
    option: str
    values: tuple

    @property
    def column(self) -> str:
        """The rows' column holding the value: ``<method>.<option>``."""
        return f"{self.method}.{self.option}"

    @classmethod
    def parse(cls, vary: str, values: Sequence) -> OptionAxis:
        """The axis of ``vary = "options.<method>.<option>"``; ValueError for another form."""
        parts = vary.split(".")
        if len(parts) != 3 or parts[0] != "options" or not all(parts):
            raise ValueError(f"an option axis is written options.<method>.<option>, got {vary!r}")
        return cls(parts[1], parts[2], tuple(values))


@dataclass(frozen=True)
class ReviewStudy(Study):
    """One review sweep: every selected method on ``trials`` datasets at each point.

    Attributes
    ----------
    name : str
        Sweep name (``baseline``, ``gamma``, ...); results go to ``<results_dir>/<name>/``.
    points : sequence of Point
        The settings, in the order they are reported.
    trials, seed : int
        Datasets per point; base seed of every random stream.
    algorithms : sequence of str
        Registered method names; all see the same dataset in a trial.
    options : dict
        Per-method keyword options, ``{method: {option: value}}``.
    delta : float
        Robustness threshold of eq. (76), in (0, 1).
    call_timeout_s : float or None
        Time limit of one calibration call.
    plugins : sequence of str
        Modules imported in every worker before it runs (they register extra methods).
    axis : OptionAxis or None
        A method option swept on the same datasets (one extra column), or None.
    """

    name: str
    points: Sequence[Point]
    trials: int
    seed: int
    algorithms: Sequence[str]
    options: dict = field(default_factory=dict)
    delta: float = 0.5
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()
    axis: OptionAxis | None = None
    #: The Cramer-Rao columns (``crb``, ``crb_J``) of units whose rows were reused beside the
    #: ones this study computes, ``{(point index, trial): (crb, crb_J)}``: a dataset's bound,
    #: the same for every method, read back instead of computed again (:meth:`given_reused`).
    known_bounds: Mapping | None = field(default=None, compare=False, repr=False,
                                         metadata={"setting": False})

    @property
    def method_column(self) -> str | None:
        """Rows are cached per method (:mod:`magbench.engine.sweep`), except with an option
        axis, whose extra runs come after every method's and so are not one method's block."""
        return "algorithm" if self.axis is None else None

    @property
    def tables(self) -> dict:
        columns = ROW_COLUMNS if self.axis is None else [*ROW_COLUMNS, self.axis.column]
        return {"trials": ("trials.csv", columns),
                "times": ("trials_times.csv", TIME_COLUMNS)}

    @property
    def summary_columns(self) -> list[str]:
        """The columns :meth:`summarize` reads (and holds in memory), ``time_s`` from the
        times sidecar."""
        return SUMMARY_COLUMNS + ([] if self.axis is None else [self.axis.column])

    def units(self) -> list[tuple[int, int]]:
        return [(i, t) for i in range(len(self.points)) for t in range(self.trials)]

    def run_unit(self, unit: tuple[int, int]) -> dict[str, list[dict]]:
        point_index, trial = unit
        bounds = None if self.known_bounds is None else self.known_bounds.get(unit)
        rows, times = split_times(trial_rows(self.points[point_index], trial, self.seed,
                                             self.algorithms, self.options, self.delta,
                                             self.call_timeout_s, self.axis, bounds), "trial")
        return {"trials": rows, "times": times}

    def given_reused(self, tables: Mapping[str, Path]) -> ReviewStudy:
        """This study with the bound columns of every unit the reused rows hold
        (:attr:`known_bounds`): computing them is most of a new method's trial beside its
        own call. A float is written by ``repr`` and read back by ``float``, which gives the
        same number, so the rows are those computed without them."""
        path = tables.get("trials")
        if path is None or self.axis is not None:
            return self
        index = {tuple(float(getattr(p, c)) for c in POINT_COLUMNS): i
                 for i, p in enumerate(self.points)}
        known: dict[tuple[int, int], tuple[float, float]] = {}
        with open(path, newline="") as handle:
            reader = csv.reader(handle)
            header = next(reader, [])
            try:
                at = [header.index(c) for c in [*POINT_COLUMNS, "trial", "crb", "crb_J"]]
            except ValueError:
                return self
            for row in reader:
                point = index.get(tuple(float(row[i]) for i in at[:6]))
                unit = (point, int(row[at[6]]))
                if point is None or unit in known or not row[at[7]] or not row[at[8]]:
                    continue
                known[unit] = (float(row[at[7]]), float(row[at[8]]))
        return replace(self, known_bounds=known) if known else self

    def describe(self) -> dict:
        out = super().describe()
        out["points"] = [asdict(p) for p in self.points]
        return out

    def summarize(self, out_dir: Path | str) -> pd.DataFrame:
        """Write and return ``summary.csv`` from ``trials.csv``; with points of partial
        coverage, also ``efficient_selection.csv`` (what the robustness test does to an
        efficient estimator's scores there, :mod:`magbench.studies.selection`).

        Reads only the columns the statistics use (:data:`SUMMARY_COLUMNS`), in chunks: a
        tenth of the file's values, so a million-trial sweep is summarised in bounded memory.
        """
        extra = [] if self.axis is None else [self.axis.column]
        path = Path(out_dir) / "trials.csv"
        trials = with_times(read_csv_columns(path, self.summary_columns), path, "trial")
        summary = summarize_review(trials, extra)
        write_csv_atomic(summary, Path(out_dir) / "summary.csv")
        if self.has_selection() and not self.selection_is_current(out_dir):
            write_efficient_selection(list(self.points), self.trials, self.seed, self.delta,
                                      out_dir)
        return summary

    def has_selection(self) -> bool:
        """Whether the sweep has points of partial coverage (``efficient_selection.csv``)."""
        return any(p.cap_deg < 180 or p.band_deg < 90 for p in self.points)

    def selection_record(self, out_dir: Path | str) -> dict | None:
        """What :data:`SELECTION_RECORD` keeps of ``efficient_selection.csv``: the
        :meth:`base_fingerprint` it was computed for (it depends on the points, trials, seed,
        delta and code, on no method) and its SHA-256; None without the file."""
        path = Path(out_dir) / "efficient_selection.csv"
        if not self.has_selection() or not path.exists():
            return None
        return {"base": self.base_fingerprint(), "sha256": file_sha256(path)}

    def selection_is_current(self, out_dir: Path | str) -> bool:
        """True when ``efficient_selection.csv`` was computed for this study's base and is
        unchanged since (the record :data:`SELECTION_RECORD` names in ``efficiency.json``):
        adding a method does not recompute it."""
        import json

        try:
            kept = json.loads((Path(out_dir) / "efficiency.json").read_text())[SELECTION_RECORD]
        except (OSError, ValueError, KeyError, TypeError):
            return False
        return kept is not None and kept == self.selection_record(out_dir)


def trial_rows(point: Point, trial: int, seed: int, algorithms: Sequence[str],
               options: dict | None = None, delta: float = 0.5,
               call_timeout_s: float | None = None, axis: OptionAxis | None = None,
               bounds: tuple[float, float] | None = None) -> list[dict]:
    """Every method on the trial's dataset; one row per method, failures included.

    With an ``axis``, its method runs at its default and then once per value (one row each,
    the value in ``axis.column``, empty for the default). ``bounds``: the dataset's
    ``(crb, crb_J)`` when known (from rows of other methods on it), else computed.
    """
    options = options or {}
    data = make_dataset(rng(seed, point.key, trial), point)
    J0 = trivial_cost(data.T, data.h)
    if bounds is not None:
        bound = {"crb": bounds[0], "crb_J": bounds[1]}
    else:
        # Cramer-Rao bound on E[J_h^2 + J_T^2] and E[J] of an efficient estimator (core/crb).
        C = crb_covariance(data.T, data.m, point.sigma)
        bound = {"crb": crb_mse(data.T, data.h, data.m, point.sigma, covariance=C).total,
                 "crb_J": efficient_expected_J(data.T, data.m, point.sigma, covariance=C)}
    base = {**{c: getattr(point, c) for c in POINT_COLUMNS},
            "trial": int(trial), "seed": int(seed)}
    truth = truth_columns(data.T, data.h)
    runs = [(name, None) for name in algorithms]
    if axis is not None:
        runs += [(axis.method, v) for v in axis.values if axis.method in algorithms]
    rows = []
    # Checked once for every method on this dataset, outside the methods' timed calls.
    samples = CheckedSamples(data.y).prepare_for(algorithms)
    for name, value in runs:
        opts = method_options(name, point, options)
        if value is not None:
            opts[axis.option] = value
        out = run_method(name, lambda o, n=name: calibrate(samples, n, raw=True, **o),
                         options=opts,
                         seed=seed, stream=(point.key, trial), call_timeout_s=call_timeout_s)
        J, J_h, J_T = (accuracy_cost(out.T, out.h, data.T, data.h) if out.calibration
                       else (np.nan, np.nan, np.nan))
        rows.append({**base, "algorithm": name, "ok": out.ok, "error": out.error,
                     "time_s": out.time_s, "n_iter": out.n_iter, "J": J, "J_h": J_h,
                     "J_T": J_T, "J0": J0, "meaningful": bool(np.isfinite(J) and J < delta * J0),
                     "sq_err": J_h ** 2 + J_T ** 2, **bound,
                     **truth, **estimate_columns(out.T, out.h),
                     **({} if axis is None else {axis.column: value})})
    return rows


def method_options(name: str, point: Point, options: dict | None = None) -> dict:
    """The keyword options ``name`` gets at ``point``: the user's, plus the true noise level.

    Methods that weight by an assumed noise level (TWOSTEP's and the EKF's eq. 5) are told the
    true one unless the user set it, as the review assumes ("sigma_k^2 ... similar to the
    measurement's output error variance").
    """
    opts = dict((options or {}).get(name) or {})
    if "sigma" in get_method(name).option_names() and "sigma" not in opts and point.sigma > 0:
        opts["sigma"] = point.sigma
    return opts


def read_trials(path: Path | str) -> pd.DataFrame:
    """A trials CSV with ``error`` as text (empty where ok) and ``time_s`` from its sidecar."""
    frame = pd.read_csv(path, dtype={"error": "string"})
    return with_times(frame.assign(error=frame["error"].fillna("")), path, "trial")


def summarize_review(trials: pd.DataFrame, extra: Sequence[str] = ()) -> pd.DataFrame:
    """RB %, rho, tau (eqs. 77-79) and the Cramer-Rao columns per point and method (and per
    value of the ``extra`` columns, such as an option axis's)."""
    return summarize(trials, POINT_COLUMNS + list(extra) + ["algorithm"])


def efficiency_intervals(trials: pd.DataFrame, by: Sequence[str], sweep: str) -> pd.DataFrame:
    """Efficiency (Cramer-Rao bound / MSE over the meaningful runs, as in :func:`summarize`)
    with its 95 % paired-bootstrap interval, per group.

    ``trials`` needs ``meaningful``, ``crb`` and ``sq_err`` and the ``by`` columns; each
    group's resamples are drawn from the stream named by ``sweep``, ``"efficiency"`` and the
    group's values. Returns ``by`` plus ``n``, ``n_meaningful``, ``efficiency``, ``eff_lo``
    and ``eff_hi``.
    """
    rows = []
    # dropna=False: an option axis's default run has an empty value and is a group of its own.
    for key, g in trials.groupby(list(by), sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        ok = g[g["meaningful"].astype(bool)]
        stream = [f"{c}={v}" for c, v in zip(by, key, strict=True)]
        low, high = bootstrap_paired_ratio(ok["crb"], ok["sq_err"], sweep, "efficiency",
                                             *stream)
        mse = float(ok["sq_err"].mean()) if len(ok) else np.nan
        rows.append({**dict(zip(by, key, strict=True)), "n": len(g), "n_meaningful": len(ok),
                     "efficiency": float(ok["crb"].mean()) / mse if mse > 0 else np.nan,
                     "eff_lo": low, "eff_hi": high})
    return pd.DataFrame(rows, columns=[*by, "n", "n_meaningful", "efficiency", "eff_lo",
                                       "eff_hi"])


def write_efficiency(out_dir: Path | str, sweep: str, extra: Sequence[str] = ()) -> Path:
    """Write ``<out_dir>/efficiency.csv``: :func:`efficiency_intervals` per point and method
    (and value of the ``extra`` columns, such as an option axis's), from the ``meaningful``,
    ``crb`` and ``sq_err`` columns of ``trials.csv`` (read in chunks, the other columns never
    held)."""
    out_dir = Path(out_dir)
    by = [*POINT_COLUMNS, *extra, "algorithm"]
    trials = read_csv_columns(out_dir / "trials.csv", [*by, "meaningful", "crb", "sq_err"])
    path = out_dir / "efficiency.csv"
    write_csv_atomic(efficiency_intervals(trials, by, sweep), path)
    return path


def coverage_label(cap_deg: float, band_deg: float) -> str:
    """Readable name of a coverage point: a polar cap or an equatorial band."""
    if band_deg < 90:
        return f"band +-{band_deg:g} deg"
    return "full sphere" if cap_deg >= 180 else f"cap {cap_deg:g} deg"


def with_coverage_column(summary: pd.DataFrame) -> pd.DataFrame:
    """Add ``coverage`` (label, in the sweep's order) for the coverage sweep's summary."""
    out = summary.copy()
    out["coverage"] = [coverage_label(c, b) for c, b in zip(out["cap_deg"], out["band_deg"],
                                                              strict=True)]
    return out


def points_for(nominal: Point, vary: str | None, values: Iterable[float]) -> list[Point]:
    """The sweep's points: the nominal point with one parameter set to each value in turn."""
    if not vary:
        return [nominal]
    return [point_with(nominal, {vary: v}) for v in values]


def point_with(nominal: Point, changes: dict) -> Point:
    """The nominal point with some parameters (from POINT_COLUMNS) changed."""
    unknown = sorted(set(changes) - set(POINT_COLUMNS))
    if unknown:
        raise ValueError(f"cannot set {', '.join(unknown)}; a point has "
                         f"{', '.join(POINT_COLUMNS)}")
    fields = asdict(nominal)
    fields.update({k: int(v) if k == "K" else float(v) for k, v in changes.items()})
    return Point(**fields)
