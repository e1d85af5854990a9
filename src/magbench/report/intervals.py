"""Intervals and provenance for every report table, from the CSV files and ``run.json`` alone.

The two statistics the report prints for every method carry a 95 % interval, computed by the
one helper of each kind in :mod:`magbench.core.intervals`: RB % with Wilson's binomial
interval (meaningful runs out of all runs), 1/rho with the percentile bootstrap over the
meaningful runs' J (seeded by the sweep, point and method, so a report is a pure function of
its files). Every section names the run it comes from: trial count and config fingerprint from
the folder's ``run.json``.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Sequence
from functools import cache
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.intervals import intervals_overlap, wilson
from magbench.report.format import format_number
from magbench.report.kept import bootstrap_inverse_mean

__all__ = ["accuracy_intervals", "annotate", "cell", "commit_in_history", "rb_interval",
           "read_run", "run_note", "significantly_different", "timing_provenance"]


def rb_interval(row: pd.Series | dict | object) -> tuple[float, float]:
    """Wilson interval (percent) of a summary row's RB %.

    Uses ``n_meaningful`` and ``n`` when present; otherwise recovers the count from ``RB_pct``
    and ``n`` (hand-made or older summaries).
    """
    get = row.get if hasattr(row, "get") else (lambda k, d=None: getattr(row, k, d))
    n = get("n", np.nan)
    k = get("n_meaningful", None)
    if k is None or not np.isfinite(k):
        k = round(float(get("RB_pct", np.nan)) * float(n) / 100.0) \
            if np.isfinite(n) and np.isfinite(get("RB_pct", np.nan)) else np.nan
    if not (np.isfinite(n) and np.isfinite(k)):
        return (np.nan, np.nan)
    return wilson(int(k), int(n))


def significantly_different(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """True when two 95 % intervals do not overlap (a conservative test of a difference)."""
    return not intervals_overlap(a, b)


def accuracy_intervals(trials: pd.DataFrame, by: Sequence[str], sweep: str,
                       value: str = "J", meaningful: str = "meaningful") -> pd.DataFrame:
    """Bootstrap interval of ``1 / mean(value)`` over the meaningful rows of every group.

    Parameters
    ----------
    trials : DataFrame
        One row per run, with ``value`` (J, or J_r) and the boolean ``meaningful``.
    by : sequence of str
        Grouping columns (the point's columns and ``algorithm``).
    sweep : str
        Name of the sweep, part of every group's bootstrap stream.

    Returns
    -------
    DataFrame
        ``by`` columns plus ``acc_lo`` and ``acc_hi``.
    """
    rows = []
    ok = trials[trials[meaningful].astype(bool)]
    for key, g in ok.groupby(list(by), sort=False):
        key = key if isinstance(key, tuple) else (key,)
        stream = [sweep] + [f"{c}={v}" for c, v in zip(by, key, strict=True)]
        # One run has no spread to resample: no interval rather than a point posing as one.
        lo, hi = (bootstrap_inverse_mean(g[value].to_numpy(float), *stream) if len(g) > 1
                  else (np.nan, np.nan))
        rows.append({**dict(zip(by, key, strict=True)), "acc_lo": lo, "acc_hi": hi})
    return pd.DataFrame(rows, columns=[*by, "acc_lo", "acc_hi"])


def cell(value: float, interval: tuple[float, float], digits: int = 3) -> str:
    """``value [low, high]`` for a Markdown table ('-' when the value is missing)."""
    text = format_number(value, digits)
    if text == "-" or not all(np.isfinite(v) for v in interval):
        return text
    return f"{text} [{format_number(interval[0], digits)}, {format_number(interval[1], digits)}]"


def read_run(folder: Path | str) -> dict | None:
    """``<folder>/run.json`` as a dict, or None when it is missing or unreadable."""
    try:
        return json.loads((Path(folder) / "run.json").read_text())
    except (OSError, ValueError):
        return None


def run_note(folder: Path | str, unit: str = "trials per point") -> str:
    """One italic line naming the run behind a section: trials, config fingerprint, commit.

    The count is the study's ``trials`` (review and gyro sweeps), ``runs`` (Wu and Shi) or its
    number of work units (recordings); the fingerprint is the hash of every setting that
    shapes the rows (:meth:`magbench.engine.sweep.Study.fingerprint`), so two sections with the
    same fingerprint come from the same configuration and any other from a different one.
    """
    record = read_run(folder)
    name = Path(folder).name
    if record is None:
        return f"*Run: no `{name}/run.json`, so the trial count and configuration are unknown.*"
    settings = record.get("settings") or {}
    count = settings.get("trials", settings.get("runs", record.get("units")))
    full = str(record.get("git_commit") or "")
    commit = full[:10] or "unknown"
    history = commit_in_history(full, Path(folder))
    flag = ("" if history is not False else
            " (not an ancestor of this checkout's HEAD: the code that ran is not in this "
            "history)")
    delta = f", delta = {settings['delta']:g}" if "delta" in settings else ""
    seed = f", seed {settings['seed']}" if "seed" in settings else ""
    return (f"*Run `{name}`: {count} {unit}{delta}{seed}; config fingerprint "
            f"`{record.get('fingerprint', '?')}`, commit `{commit}`{flag}, finished "
            f"{record.get('finished', '?')} ({record.get('cpu_model', '?')})"
            f"{timing_provenance(Path(folder), record)}.*")


def timing_provenance(folder: Path, record: dict | None = None) -> str:
    """Where and when the folder's timing pass (``timing.csv``) was measured, said beside
    the run's own machine: '' without a timing pass or without those columns."""
    path = Path(folder) / "timing.csv"
    if not path.exists():
        return ""
    t = pd.read_csv(path, usecols=lambda c: c in ("cpu_model", "measured"))
    if t.empty or not {"cpu_model", "measured"} <= set(t.columns):
        return ""
    cpus = ", ".join(map(str, dict.fromkeys(t["cpu_model"].dropna())))
    dates = sorted(str(d)[:10] for d in t["measured"].dropna())
    when = dates[0] if dates and dates[0] == dates[-1] else (
        f"{dates[0]} to {dates[-1]}" if dates else "?")
    other = record is not None and record.get("cpu_model") not in (None, cpus)
    return (f"; its timing pass (the speeds) measured on {cpus} on {when}"
            + (", another machine than the sweep's" if other else ""))


@cache
def commit_in_history(commit: str, where: Path) -> bool | None:
    """Whether ``commit`` is an ancestor of HEAD of the git checkout holding ``where``
    (``git merge-base --is-ancestor``); None when that cannot be told (no git, not a
    checkout, no commit recorded)."""
    if not commit or not where.exists():
        return None
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=where,
                             capture_output=True, text=True, timeout=10)
        if top.returncode != 0:
            return None
        done = subprocess.run(["git", "merge-base", "--is-ancestor", commit, "HEAD"],
                              cwd=where, capture_output=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    # 0: an ancestor; 1: not one; otherwise (128) the commit is unknown here: not in history
    return done.returncode == 0


def annotate(summary: pd.DataFrame, trials: pd.DataFrame | None = None,
             timing: pd.DataFrame | None = None, sweep: str = "") -> pd.DataFrame:
    """``summary`` with the intervals and the timing pass beside every row.

    Adds ``RB_lo``, ``RB_hi`` (Wilson), ``acc_lo``, ``acc_hi`` (bootstrap over ``trials``'
    meaningful J; NaN without ``trials``), ``speed_timed`` (1/tau of the timing pass; NaN
    without ``timing``), matched on the point's columns and ``algorithm``, and the report's
    one speed per row, ``speed`` with its ``speed_source`` (:func:`one_speed`).
    """
    from magbench.studies.review import POINT_COLUMNS

    out = summary.copy()
    bounds = [rb_interval(r) for _, r in out.iterrows()]
    out["RB_lo"] = [b[0] for b in bounds]
    out["RB_hi"] = [b[1] for b in bounds]
    keys = [c for c in POINT_COLUMNS if c in out.columns] + ["algorithm"]
    if trials is not None and {"J", "meaningful"} <= set(trials.columns) \
            and set(keys) <= set(trials.columns):
        acc = accuracy_intervals(trials, keys, sweep)
        out = out.merge(acc, on=keys, how="left")
    else:
        out["acc_lo"] = out["acc_hi"] = np.nan
    if timing is not None and set(keys) <= set(timing.columns):
        out = out.merge(timing[keys + ["speed_hz"]].rename(columns={"speed_hz": "speed_timed"}),
                        on=keys, how="left")
    else:
        out["speed_timed"] = np.nan
    out["speed"], out["speed_source"] = one_speed(out, timing is not None)
    return out


def one_speed(rich: pd.DataFrame, timed: bool) -> tuple[pd.Series, str]:
    """The report's one speed 1/tau per row, and where it comes from.

    With a timing pass (``timed``) every speed is the pass's, blank where the pass has none
    or where no run was meaningful (RB = 0: eq. (79) has no run to average); without one,
    the per-trial speed of ``summary.csv`` (meaningful runs, wall time during the sweep).
    """
    if timed:
        return rich["speed_timed"].where(rich["RB_pct"] > 0), "timing"
    return rich["speed_hz"], "trials"
