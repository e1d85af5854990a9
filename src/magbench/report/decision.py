"""The answer first: one row per setting, the method to use, why, with n and an interval.

The rows are the opening advice (:mod:`magbench.report.advice`) reduced to a table a reader
takes in at a glance; the reasoning in full is folded under it in ``report.html``. Every row
says how many datasets it rests on and carries a 95 % interval: Wilson's for RB %, the paired
bootstrap for an accuracy ratio on matched datasets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.methods.registry import method_label
from magbench.report.advice import (
    RECOMMEND_EFFICIENCY,
    RECOMMEND_RB_PCT,
    STRESS_CONDITIONS,
    _advisable,
    _hardest,
    _most_accurate,
    _needs_gyro,
    tail_note,
)
from magbench.report.format import format_number, md_table
from magbench.report.intervals import accuracy_intervals, annotate, cell, rb_interval
from magbench.report.load import load_csv, load_trials
from magbench.report.matched import paired
from magbench.studies.review import with_coverage_column

__all__ = ["DECISION_COLUMNS", "decision_rows", "decision_section", "median_spread"]

DECISION_COLUMNS = ["setting", "method", "why", "n", "interval"]


def median_spread(point: pd.DataFrame, candidates: list[str]) -> tuple[float, float]:
    """The lowest and highest median J over the meaningful runs of ``candidates`` at one
    sweep point."""
    rows = point[point["algorithm"].isin(candidates) & point["meaningful"].astype(bool)]
    med = rows.groupby("algorithm")["J"].median()
    return (float(med.min()), float(med.max())) if len(med) else (np.nan, np.nan)


def _rb(row: pd.Series) -> str:
    return f"RB {cell(row['RB_pct'], rb_interval(row), 3)} %"


def _baseline_row(baseline: pd.DataFrame) -> dict | None:
    b = _advisable(baseline)
    good = b[(b["RB_pct"] >= RECOMMEND_RB_PCT)
             & (b.get("efficiency", pd.Series(1.0, index=b.index)) >= RECOMMEND_EFFICIENCY)]
    if good.empty:
        return None
    speed = "speed" if "speed" in good else "speed_hz"
    fast = good.sort_values(speed, ascending=False).iloc[0]
    interval = (f"{_rb(fast)}; 1/rho {format_number(good['accuracy'].min())}-"
                f"{format_number(good['accuracy'].max())} for all {len(good)}")
    return {"setting": "Whole sphere of directions (Table 2)",
            "method": f"any of {len(good)}; fastest {method_label(fast['algorithm'])}",
            "why": (f"{len(good)} methods at RB >= {RECOMMEND_RB_PCT:g} % and within "
                    f"{100 * (1 - RECOMMEND_EFFICIENCY):.0f} % of the Cramer-Rao floor; "
                    f"{method_label(fast['algorithm'])} is the fastest "
                    f"({format_number(fast[speed])} calls/s)"),
            "n": int(fast["n"]), "interval": interval}


def _coverage_rows(coverage: pd.DataFrame) -> list[dict]:
    c = _advisable(with_coverage_column(coverage))
    rows = []
    for cov, part in c[(c["cap_deg"] < 90) & (c["band_deg"] >= 90)].groupby("coverage",
                                                                          sort=False):
        top = part.sort_values(["RB_pct", "accuracy"], ascending=False).iloc[0]
        tied = [method_label(n) for n in part["algorithm"]
                if n != top["algorithm"] and not (rb_interval(part[part["algorithm"] == n]
                                                              .iloc[0])[1] < rb_interval(top)[0])]
        rows.append({"setting": f"Partial coverage, {cov}",
                     "method": method_label(top["algorithm"]),
                     "why": ("most robust" + (f"; within its interval: {', '.join(tied)}"
                                              if tied else "")
                             + ("; turn the sensor more" if top["RB_pct"] < 90 else "")),
                     "n": int(top["n"]), "interval": _rb(top)})
    return rows


def _stress_row(summary: pd.DataFrame, column: str, title: str, figure: str,
                trials: pd.DataFrame | None) -> dict | None:
    rows = _advisable(_hardest(summary, column))
    if rows.empty:
        return None
    value = rows[column].iloc[0]
    setting = f"{title} ({figure}, {column} = {value:g})"
    robust = rows[rows["RB_pct"] >= RECOMMEND_RB_PCT].sort_values("accuracy", ascending=False)
    if robust.empty:
        top = rows.sort_values("RB_pct", ascending=False).iloc[0]
        return {"setting": setting, "method": method_label(top["algorithm"]),
                "why": f"no method keeps RB >= {RECOMMEND_RB_PCT:g} %; the most robust",
                "n": int(top["n"]), "interval": _rb(top)}
    if trials is None:
        best = robust.iloc[0]
        return {"setting": setting, "method": method_label(best["algorithm"]),
                "why": f"most accurate of {len(robust)} robust methods (unmatched)",
                "n": int(best["n"]), "interval": _rb(best)}
    point = trials[trials[column] == value]
    names = list(robust["algorithm"])
    best = _most_accurate(point, names)
    best_row = robust[robust["algorithm"] == best].iloc[0]
    versus = {n: paired(point, best, n, key=("advice", best)) for n in names if n != best}

    tied = [n for n, p in versus.items() if not p.different]
    why = f"most accurate (mean J) of the {len(robust)} at RB >= {RECOMMEND_RB_PCT:g} %"
    if tied:
        why += (f"; {len(tied)} other{'s' if len(tied) > 1 else ''} within the 95 % paired "
                "interval (a tie)")
    tail = tail_note(point, names)
    if tail:
        why += f"; {tail}"
    flip = _previous_best(summary, trials, column, value)
    if flip and flip[0] != best:
        why += f"; at {column} = {flip[1]:g} the most accurate is {method_label(flip[0])}"
    sub = point[point["algorithm"] == best]
    acc = accuracy_intervals(sub, ["algorithm"], f"decision {column}={value}").iloc[0]
    interval = (_rb(best_row) + "; 1/rho "
                + cell(best_row["accuracy"], (acc["acc_lo"], acc["acc_hi"]), 3))
    return {"setting": setting, "method": method_label(best), "why": why,
            "n": int(best_row["n"]), "interval": interval}


def _previous_best(summary: pd.DataFrame, trials: pd.DataFrame, column: str,
                   value: float) -> tuple[str, float] | None:
    """The most accurate robust method at the sweep point next to the hardest, and that
    point (None when there is none)."""
    values = sorted(summary[column].unique())
    i = values.index(value)
    j = i + 1 if column == "K" else i - 1
    if not 0 <= j < len(values):
        return None
    rows = _advisable(summary[summary[column] == values[j]])
    robust = list(rows[rows["RB_pct"] >= RECOMMEND_RB_PCT]["algorithm"])
    return ((_most_accurate(trials[trials[column] == values[j]], robust), values[j])
            if robust else None)


def _gyro_rows(summary: pd.DataFrame) -> list[dict]:
    noisy = _advisable(summary[summary["gyro_noise"] == summary["gyro_noise"].max()])
    rows = []
    for cov, hard in noisy.groupby("coverage", sort=False):
        top = hard.sort_values(["RB_pct", "accuracy"], ascending=False).iloc[0]
        kind = "gyro-aided" if _needs_gyro(top["algorithm"]) else "magnetometer-only"
        rows.append({"setting": f"Gyro available, manoeuvre '{cov}' (gyro noise "
                                f"{top['gyro_noise']:g} rad/s)",
                     "method": method_label(top["algorithm"]),
                     "why": f"most robust, then most accurate ({kind})",
                     "n": int(top["n"]), "interval": _rb(top)})
    return rows


def decision_rows(results_dir: Path) -> pd.DataFrame:
    """The decision table: setting, method, why, n (datasets or runs), interval."""
    results_dir = Path(results_dir)
    rows: list[dict] = []
    baseline = load_csv(results_dir, "baseline")
    if baseline is not None:
        baseline = annotate(baseline, None, load_csv(results_dir, "baseline", "timing.csv"))
        rows.append(_baseline_row(baseline))
    coverage = load_csv(results_dir, "coverage")
    if coverage is not None:
        rows += _coverage_rows(coverage)
    for key, column, title, figure in STRESS_CONDITIONS:
        summary = load_csv(results_dir, key)
        if summary is not None and column in summary and not summary.empty:
            rows.append(_stress_row(summary, column, title, figure,
                                    load_trials(results_dir / key)))
    gyro = load_csv(results_dir, "gyro")
    if gyro is not None and "coverage" in gyro:
        rows += _gyro_rows(gyro)
    return pd.DataFrame([r for r in rows if r], columns=DECISION_COLUMNS)


def decision_section(results_dir: Path) -> str:
    """Markdown of the answer: the decision table ('' without results), and where the
    reasoning is."""
    table = decision_rows(results_dir)
    if table.empty:
        return ""
    own = ("\n\nYour own recording: `python -m magbench calibrate file=...` fits every "
           "applicable method, ranks them out of sample and writes the chosen correction.")
    return ("## In short: which method to use\n\n" + md_table(table) + "\n\n"
            "n: datasets (runs) at the setting; intervals 95 %, Wilson's for RB %. The "
            "reasoning per setting, with matched comparisons, is folded under this table in "
            "`report.html`." + own)
