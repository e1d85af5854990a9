"""The timing protocol for tau (eq. 79): a dedicated pass, after a sweep's trials.

The per-trial ``time_s`` (``trials_times.csv``) is measured while the sweep's workers share
the machine, so it carries their load, worker start-up and first-call costs. This pass
measures speed on its own, in the sweep's process once the workers are gone:

* every method is timed on the *same* datasets: the first ``datasets`` trials of each sweep
  point, drawn exactly as the sweep drew them (``rng(seed, point.key, trial)``);
* warmed up: each method is called once before anything is timed (imports, numba's cached
  loops, allocations), so the first point pays nothing the others do not;
* single-threaded: one process, BLAS pinned to one thread (``python -m magbench`` sets it before
  numpy loads), methods interleaved per dataset so a drift of the machine's load spreads over
  all of them instead of landing on one;
* each call repeated (at least ``repeats`` times, more for fast methods) and its median
  taken, which removes the machine's noise; tau (``tau_s``) is the mean of these medians over
  the datasets, each dataset weighted once, as eq. (79) averages over datasets (a method whose
  iterations vary from dataset to dataset, such as MAG.I.C.AL at large gamma, keeps that
  variation) on which the method ended by its own rule, as (79) times the successful runs
  (``tau_all_s``: every dataset); ``median_s`` is the median over datasets, and the
  quartiles are over all calls;
  the row records the CPU model;
* the time is the process's CPU time of the call (``time.process_time``): on one thread it
  equals the wall time of a quiet machine, and on a shared one it leaves out the time the
  process waited for a core, which is the other work's cost, not the method's. The wall-clock
  median is kept beside it (``wall_median_s``).

The budget: each dataset gets at least 3 calls, a fast method more until 3 ms are spent on it
(at most 30), and a call longer than 10 ms only one (a long call's length dwarfs the jitter);
docs/decisions.md records what this costs per sweep. A method whose second warm-up call
takes more than ``slow_call_s`` is timed on one dataset, once per point, so a slow or hanging
method cannot blow the budget. Calls go through the one trial loop
(:func:`magbench.engine.trial.run_method`), so exactly what a trial times is timed here, in a
supervised child process as the trials are (:func:`magbench.engine.isolation.map_supervised`):
a method that ends or seizes its process gives a row with the reason (``error``) and the pass
goes on. The clocks are read inside the child around the method alone.

The result is ``timing.csv`` in the sweep's folder; figures' speed panels and the report's
speed columns read it when it is there (``trials_times.csv`` keeps the per-trial times).
:func:`compare_timings` compares two passes (``python -m magbench bench timing_check=true``).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.core.seeding import rng
from magbench.engine.isolation import map_supervised
from magbench.engine.plugins import plugin_modules
from magbench.engine.record import cpu_model
from magbench.engine.trial import Outcome, run_method
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method
from magbench.sources.synthetic import Point, make_dataset
from magbench.studies.review import POINT_COLUMNS, ReviewStudy, method_options

__all__ = ["DATASETS", "MIN_TIME_S", "REPEATS", "TIMING_COLUMNS", "TIMING_FILE",
           "compare_timings", "read_timing", "repeat_timing", "time_methods",
           "timing_is_current", "write_timing"]

TIMING_FILE = "timing.csv"
#: Datasets per sweep point and timed calls per dataset (see the module notes for the budget).
DATASETS, REPEATS = 3, 3
#: Time spent per (dataset, method) at the least: fast methods get more than REPEATS calls.
MIN_TIME_S = 0.003
TIMING_COLUMNS = POINT_COLUMNS + ["algorithm", "calls", "failed_calls", "spent_s", "tau_s",
                                  "tau_all_s",
                                  "ok_datasets", "median_s", "q25_s",
                                  "q75_s", "min_s", "wall_median_s", "speed_hz", "datasets",
                                  "cpu_model", "fingerprint", "measured", "error"]


def _call(name: str, y: np.ndarray, opts: dict, seed: int, stream: tuple,
          call_timeout_s: float | None) -> Outcome:
    """One call through the trial loop; its ``cpu_s`` and ``time_s`` time the method alone."""
    return run_method(name, lambda o: calibrate(y, name, raw=True, **o), options=opts,
                      seed=seed, stream=stream, call_timeout_s=call_timeout_s)


def time_methods(points: Sequence[Point], seed: int, algorithms: Sequence[str],
                 options: dict | None = None, *, datasets: int = DATASETS,
                 repeats: int = REPEATS, min_time_s: float = MIN_TIME_S,
                 max_repeats: int = 30, long_call_s: float = 0.01,
                 slow_call_s: float = 0.2,
                 call_timeout_s: float | None = None,
                 clock: Callable[[], str] | None = None) -> pd.DataFrame:
    """Time every method on the first ``datasets`` datasets of each point (the protocol above).

    The calls run in a supervised child process, as a sweep's trials do
    (:func:`magbench.engine.isolation.map_supervised`): a method that ends or seizes its
    process is not called again at that point, and its row says why (``error``); the pass and
    the command go on. Each call's clocks are read around the method alone, inside the child,
    so the supervision's messages are not timed.

    Parameters
    ----------
    points : sequence of Point
        The sweep's points.
    seed : int
        The sweep's seed: the datasets are the sweep's own first trials.
    algorithms : sequence of str
        Registered methods.
    options : dict, optional
        Per-method options, as the sweep passes them (the true sigma added where a method
        takes one, :func:`magbench.studies.review.method_options`).
    datasets, repeats : int
        Datasets per point and the fewest timed calls per dataset.
    min_time_s, max_repeats : float, int
        A fast method is called again on a dataset until ``min_time_s`` is spent on it (at most
        ``max_repeats`` calls): more calls where they are cheap.
    long_call_s : float
        A call longer than this on a dataset is not repeated there (its length dwarfs the
        machine's jitter, and repeating it would spend the budget).
    slow_call_s : float
        A method whose second warm-up call takes longer is timed once per point, on one dataset.
    call_timeout_s : float, optional
        Time limit of one call (as in the sweep).
    clock : callable, optional
        Returns the ``measured`` timestamp (tests pass a fixed one).

    Returns
    -------
    DataFrame
        One row per (point, method), columns :data:`TIMING_COLUMNS` (``fingerprint`` empty);
        ``error`` is the first reason a call at that point failed (empty if none did).
    """
    if datasets < 1 or repeats < 1:
        raise ValueError(f"datasets and repeats must be >= 1, got {datasets}, {repeats}")
    names = list(algorithms)
    stamp = (clock or (lambda: datetime.now(UTC).isoformat(timespec="seconds")))()
    machine = cpu_model()
    work = _PointPass(tuple(points), seed, tuple(names), options or {}, datasets,
                      _Budget(repeats, min_time_s, max_repeats, long_call_s), slow_call_s,
                      call_timeout_s)
    for name in names:      # loaded once here (no call), so each child starts with them
        get_method(name).prepare()
    per_point = map_supervised(work, range(len(points)), name="timing pass",
                               plugins=plugin_modules(names))
    rows = [{**{c: getattr(point, c) for c in POINT_COLUMNS}, "algorithm": name, **cell,
             "cpu_model": machine, "fingerprint": "", "measured": stamp}
            for point, cells in zip(points, per_point, strict=True)
            for name, cell in zip(names, cells, strict=True)]
    return pd.DataFrame(rows, columns=TIMING_COLUMNS)


@dataclass(frozen=True)
class _Budget:
    """How often a method is called on one dataset (see :func:`time_methods`)."""

    repeats: int
    min_time_s: float
    max_repeats: int
    long_call_s: float

    def once(self) -> _Budget:
        """The budget of a slow method: one call, nothing more for speed's sake."""
        return _Budget(1, 0.0, 1, self.long_call_s)


@dataclass
class _Calls:
    """The timed calls of one method on one dataset."""

    cpu: list[float]
    wall: list[float]
    failed: int
    fine: bool
    error: str = ""


#: Per process and pass: method -> slow (its second warm-up call took longer than
#: ``slow_call_s``). A fresh supervised child (after a death) warms up again, as a fresh
#: process must.
_WARM: dict[tuple[int, int], dict[str, bool]] = {}


@dataclass(frozen=True)
class _PointPass:
    """The pass at one point (a unit of :func:`map_supervised`): the per-method cells."""

    points: tuple[Point, ...]
    seed: int
    names: tuple[str, ...]
    options: dict
    datasets: int
    budget: _Budget
    slow_call_s: float
    call_timeout_s: float | None

    def __call__(self, k: int) -> list[dict]:
        point = self.points[k]
        slow = {name: self._warm_up(name) for name in self.names}
        data = [make_dataset(rng(self.seed, point.key, t), point) for t in range(self.datasets)]
        calls: dict[str, list[_Calls]] = {n: [] for n in self.names}
        for t, d in enumerate(data):
            for name in self.names:              # interleaved: load drift spreads over all
                if slow[name] and t > 0:
                    continue
                opts = method_options(name, point, self.options)
                calls[name].append(_time_on_dataset(
                    name, d.y, opts, self.seed, (point.key, t), self.call_timeout_s,
                    self.budget.once() if slow[name] else self.budget))
        return [_tau(calls[name]) for name in self.names]

    def _warm_up(self, name: str) -> bool:
        """Two untimed calls on the first dataset (the first loads or compiles the method's
        loops), once per process; True when the second is slower than ``slow_call_s``."""
        warm = _WARM.setdefault((os.getpid(), id(self)), {})
        if name not in warm:
            first = self.points[0]
            y = make_dataset(rng(self.seed, first.key, 0), first).y
            opts = method_options(name, first, self.options)
            outs = [_call(name, y, opts, self.seed, (first.key, 0), self.call_timeout_s)
                    for _ in range(2)]
            if outs[-1].skipped:        # not called here: it ended a process on this point
                return False
            warm[name] = outs[-1].time_s > self.slow_call_s
        return warm[name]


def _time_on_dataset(name: str, y: np.ndarray, opts: dict, seed: int, stream: tuple,
                     call_timeout_s: float | None, budget: _Budget) -> _Calls:
    """At least ``budget.repeats`` calls, more for a fast method until ``min_time_s`` is spent:
    a median of 3 sub-millisecond calls moves with every burst of load, one of 30 does not.
    A call skipped by the supervision (it ended its process here before) ends the dataset."""
    out = _Calls([], [], 0, True)
    spent = 0.0
    while (len(out.cpu) < budget.repeats and not (out.cpu and out.cpu[0] > budget.long_call_s)
           ) or (spent < budget.min_time_s and len(out.cpu) < budget.max_repeats):
        call = _call(name, y, opts, seed, stream, call_timeout_s)
        out.error = out.error or call.error
        out.failed += not call.ok
        out.fine = out.fine and call.ok
        if call.skipped:
            break
        out.cpu.append(call.cpu_s)
        out.wall.append(call.time_s)
        spent += call.time_s
    return out


def _tau(calls: Sequence[_Calls]) -> dict:
    """tau of eq. (79) and the spread of one method's calls at one point.

    The median of a dataset's calls removes the machine's noise; tau is the mean over the
    datasets on which the method ended by its own rule, each weighted once (as eq. (79) times
    the successful runs); ``tau_all_s`` averages all that were timed. A dataset with no call
    made (the method ended its process there) counts in ``datasets`` and ``failed_calls``.
    """
    timed = [c for c in calls if c.cpu]
    per_dataset = [float(np.median(c.cpu)) for c in timed]
    good = [v for v, c in zip(per_dataset, timed, strict=True) if c.fine]
    tau = float(np.mean(good)) if good else np.nan
    x = np.concatenate([c.cpu for c in timed]) if timed else np.array([])
    wall = np.concatenate([c.wall for c in timed]) if timed else np.array([])
    some = x.size > 0
    return {"calls": x.size, "failed_calls": sum(c.failed for c in calls),
            "spent_s": float(x.sum()), "tau_s": tau,
            "tau_all_s": float(np.mean(per_dataset)) if some else np.nan,
            "ok_datasets": len(good),
            "median_s": float(np.median(per_dataset)) if some else np.nan,
            "q25_s": float(np.quantile(x, 0.25)) if some else np.nan,
            "q75_s": float(np.quantile(x, 0.75)) if some else np.nan,
            "min_s": float(x.min()) if some else np.nan,
            "wall_median_s": float(np.median(wall)) if some else np.nan,
            "speed_hz": 1.0 / tau if good and tau > 0 else np.nan,
            "datasets": len(calls), "error": next((c.error for c in calls if c.error), "")}


def timing_is_current(study: ReviewStudy, out_dir: Path | str) -> bool:
    """True when ``out_dir`` holds a timing pass of this very study (same fingerprint)."""
    path = Path(out_dir) / TIMING_FILE
    if not path.exists():
        return False
    try:
        found = set(pd.read_csv(path, usecols=["fingerprint"], dtype=str)["fingerprint"])
    except (OSError, ValueError, KeyError):
        return False
    return found == {study.fingerprint()}


def write_timing(study: ReviewStudy, out_dir: Path | str, *, datasets: int = DATASETS,
                 repeats: int = REPEATS, progress: bool = False) -> Path:
    """Run the timing pass of ``study`` and write ``<out_dir>/timing.csv``.

    Run after the sweep's trials (the workers are gone); the sweep's command calls it unless
    the folder already holds a pass of the same study.
    """
    out_dir = Path(out_dir)
    start = time.perf_counter()
    frame = time_methods(study.points, study.seed, study.algorithms, study.options,
                         datasets=datasets, repeats=repeats, call_timeout_s=study.call_timeout_s)
    frame["fingerprint"] = study.fingerprint()
    path = out_dir / TIMING_FILE
    write_csv_atomic(frame, path)
    if progress:
        print(f"{study.name}: timing pass, {len(frame)} (point, method) cells, "
              f"{time.perf_counter() - start:.1f} s", file=sys.stderr)
    return path


def read_timing(folder: Path | str) -> pd.DataFrame | None:
    """``<folder>/timing.csv``, or None when the sweep has no timing pass."""
    path = Path(folder) / TIMING_FILE
    return pd.read_csv(path) if path.exists() else None


def compare_timings(first: pd.DataFrame, second: pd.DataFrame,
                    tolerance: float = 0.10) -> pd.DataFrame:
    """Per method, how far two timing passes on the same cells agree.

    Parameters
    ----------
    first, second : DataFrame
        Two outputs of :func:`time_methods` (the same points and methods).
    tolerance : float
        Largest accepted relative difference of tau.

    Returns
    -------
    DataFrame
        One row per method (in ``first``'s order): ``cells`` compared, ``tau_s_first``,
        ``tau_s_second`` (medians over the cells), ``worst_ratio`` (second / first of the
        cell farthest from 1), ``agree`` (every cell within ``tolerance``); ``common_ratio``
        (the median ratio over all cells and methods: the machine's change of speed),
        ``worst_relative`` and ``agree_relative``, the same after dividing by it. Cells
        present in only one pass are left out; a method with none does not agree.
    """
    keys = POINT_COLUMNS + ["algorithm"]
    both = first[keys + ["tau_s"]].merge(second[keys + ["tau_s"]], on=keys,
                                         suffixes=("_first", "_second"))
    both["ratio"] = both["tau_s_second"] / both["tau_s_first"]
    # A cell with no normally ended call in a pass has no tau (NaN): nothing to compare.
    both = both[np.isfinite(both["ratio"])]
    # A change of the whole machine's speed between the passes (another tenant, a frequency
    # step) moves every method by one factor; dividing it out shows whether the methods'
    # relative speeds, which every speed verdict rests on, still agree.
    common = float(np.median(both["ratio"])) if len(both) else np.nan
    rows = []
    for name in dict.fromkeys(first["algorithm"]):
        g = both[both["algorithm"] == name]
        if g.empty:
            rows.append({"algorithm": name, "cells": 0, "tau_s_first": np.nan,
                         "tau_s_second": np.nan, "worst_ratio": np.nan, "agree": False,
                         "common_ratio": common, "worst_relative": np.nan,
                         "agree_relative": False})
            continue
        ratio = g["ratio"].to_numpy(float)
        worst = float(ratio[int(np.argmax(np.abs(np.log(ratio))))])
        relative = ratio / common
        rows.append({"algorithm": name, "cells": len(g),
                     "tau_s_first": float(g["tau_s_first"].median()),
                     "tau_s_second": float(g["tau_s_second"].median()),
                     "worst_ratio": worst,
                     "agree": bool(np.all(np.abs(ratio - 1.0) <= tolerance)),
                     "common_ratio": common,
                     "worst_relative": float(relative[int(np.argmax(np.abs(np.log(relative))))]),
                     "agree_relative": bool(np.all(np.abs(relative - 1.0) <= tolerance))})
    return pd.DataFrame(rows)


def repeat_timing(study: ReviewStudy, tolerance: float = 0.10,
                  progress: Callable[[str], None] | None = None,
                  ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run the timing pass of ``study`` twice, one after the other, and compare them.

    Returns
    -------
    (passes, comparison) : tuple of DataFrame
        Both passes stacked (column ``pass`` = 1 or 2) and :func:`compare_timings` of them.
    """
    passes = []
    for k in (1, 2):
        start = time.perf_counter()
        frame = time_methods(study.points, study.seed, study.algorithms, study.options,
                             call_timeout_s=study.call_timeout_s)
        passes.append(frame.assign(fingerprint=study.fingerprint(), **{"pass": k}))
        if progress:
            progress(f"timing pass {k} of {study.name}: {time.perf_counter() - start:.1f} s")
    return pd.concat(passes, ignore_index=True), compare_timings(*passes, tolerance=tolerance)
