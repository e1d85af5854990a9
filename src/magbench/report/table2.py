"""The baseline beside the review's Table 2: accuracy, robustness and speed, with intervals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_text_atomic
from magbench.core.reference import paper_values
from magbench.methods.registry import find_method, method_label
from magbench.report.format import format_number, render
from magbench.report.intervals import annotate, cell, run_note
from magbench.report.load import load_csv, load_trials

__all__ = ["speed_ranking", "table2", "table2_markdown", "write_sweep_tables"]


def _paper_row(name: str) -> dict:
    spec = find_method(name)
    key = spec.paper_key if spec is not None else None
    return paper_values()["review"]["table2"].get(key, {}) if key else {}


def table2(summary: pd.DataFrame, trials: pd.DataFrame | None = None,
           timing: pd.DataFrame | None = None) -> pd.DataFrame:
    """The baseline summary beside the review's Table 2, one row per method.

    Columns: method, accuracy (1/rho) here with its bootstrap interval (``acc_lo``,
    ``acc_hi``; NaN without ``trials``) and in the paper, their ratio, RB % here with its
    Wilson interval (``RB_lo``, ``RB_hi``) and in the paper, speed (1/tau: the timing pass's
    when ``timing`` is given, else the per-trial mean) here and in the paper, and the speed
    ratio.
    """
    rich = annotate(summary, trials, timing, "baseline")
    rows = []
    for rec in rich.itertuples(index=False):
        ref = _paper_row(rec.algorithm)
        rows.append({
            "algorithm": rec.algorithm, "method": method_label(rec.algorithm),
            "accuracy": rec.accuracy, "acc_lo": rec.acc_lo, "acc_hi": rec.acc_hi,
            "accuracy_paper": ref.get("accuracy", np.nan),
            "RB_pct": rec.RB_pct, "RB_lo": rec.RB_lo, "RB_hi": rec.RB_hi,
            "RB_pct_paper": ref.get("robustness_pct", np.nan),
            "speed_hz": rec.speed, "speed_source": rec.speed_source,
            "speed_hz_paper": ref.get("speed_hz", np.nan),
        })
    out = pd.DataFrame(rows)
    out["accuracy_ratio"] = out["accuracy"] / out["accuracy_paper"]
    out["speed_ratio"] = out["speed_hz"] / out["speed_hz_paper"]
    return out


def table2_markdown(summary: pd.DataFrame, delta: float, trials: pd.DataFrame | None = None,
                    timing: pd.DataFrame | None = None) -> str:
    """Markdown of :func:`table2` with a short legend."""
    t = table2(summary, trials, timing)
    timed = timing is not None
    lines = [
        "| method | accuracy 1/rho [95 %] | paper | ratio | RB % [95 %] | paper | "
        "speed 1/tau (1/s) | paper | ratio |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in t.itertuples(index=False):
        lines.append(
            f"| {r.method} | {cell(r.accuracy, (r.acc_lo, r.acc_hi))} | "
            f"{format_number(r.accuracy_paper)} | "
            f"{format_number(r.accuracy_ratio, 2)} | {cell(r.RB_pct, (r.RB_lo, r.RB_hi))} | "
            f"{format_number(r.RB_pct_paper)} | {format_number(r.speed_hz)} | "
            f"{format_number(r.speed_hz_paper)} | {format_number(r.speed_ratio, 2)} |")
    speed = (render("table2.speed_timing_pass", datasets=int(timing["datasets"].max()))
             if timed else render("table2.speed_per_trial"))
    legend = render("table2.legend", n=int(summary["n"].max()), delta=delta, speed=speed)
    ranking = speed_ranking(t)
    return "\n".join(lines) + "\n\n" + legend + "\n" + (f"\n{ranking}\n" if ranking else "")


def _ordinal(k: int) -> str:
    return {1: "1st", 2: "2nd", 3: "3rd"}.get(k, f"{k}th")


def speed_ranking(t: pd.DataFrame) -> str:
    """The review's speed ranking (Table 2) beside this run's, for the review's seven
    ('' unless all seven have a speed here and in the paper)."""
    review = t[t["speed_hz_paper"].notna()]
    if len(review) < 7 or not review["speed_hz"].notna().all():
        return ""
    paper = review.sort_values("speed_hz_paper", ascending=False)
    ours = review.sort_values("speed_hz", ascending=False).reset_index(drop=True)
    top = paper.iloc[:2]
    ranks = [int(ours.index[ours["algorithm"] == a][0]) + 1 for a in top["algorithm"]]
    return render(
        "table2.ranking",
        paper_decades=np.log10(paper["speed_hz_paper"].iloc[0] / paper["speed_hz_paper"].iloc[-1]),
        paper_fast=" and ".join(top["method"]),
        paper_fast_speeds=", ".join(f"{format_number(v)}/s" for v in top["speed_hz_paper"]),
        paper_slow=paper["method"].iloc[-1],
        paper_slow_speed=format_number(paper["speed_hz_paper"].iloc[-1]),
        span=format_number(ours["speed_hz"].iloc[0] / ours["speed_hz"].iloc[-1], 2),
        fast=ours["method"].iloc[0], fast_speed=format_number(ours["speed_hz"].iloc[0]),
        slow=ours["method"].iloc[-1], slow_speed=format_number(ours["speed_hz"].iloc[-1]),
        ranks=" and ".join(_ordinal(k) for k in ranks))


def write_sweep_tables(name: str, summary: pd.DataFrame, out_dir: Path, delta: float) -> None:
    """Tables a finished sweep writes beside its CSV files (``table2.md`` for the baseline)."""
    if name == "baseline":
        out_dir = Path(out_dir)
        write_text_atomic("# Baseline (Table 2)\n\n" + run_note(out_dir) + "\n\n"
                          + table2_markdown(summary, delta, load_trials(out_dir),
                                            load_csv(out_dir.parent, out_dir.name,
                                                     "timing.csv")),
                          out_dir / "table2.md")
