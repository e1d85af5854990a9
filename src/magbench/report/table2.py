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

__all__ = ["table2", "table2_markdown", "write_sweep_tables"]


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
        timed = np.isfinite(rec.speed_timed)
        rows.append({
            "algorithm": rec.algorithm, "method": method_label(rec.algorithm),
            "accuracy": rec.accuracy, "acc_lo": rec.acc_lo, "acc_hi": rec.acc_hi,
            "accuracy_paper": ref.get("accuracy", np.nan),
            "RB_pct": rec.RB_pct, "RB_lo": rec.RB_lo, "RB_hi": rec.RB_hi,
            "RB_pct_paper": ref.get("robustness_pct", np.nan),
            "speed_hz": rec.speed_timed if timed else rec.speed_hz,
            "speed_source": "timing" if timed else "trials",
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
    timed = bool(len(t)) and (t["speed_source"] == "timing").all()
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
    speed = render("table2.speed_timing_pass" if timed else "table2.speed_per_trial")
    legend = render("table2.legend", n=int(summary["n"].max()), delta=delta, speed=speed)
    return "\n".join(lines) + "\n\n" + legend + "\n"


def write_sweep_tables(name: str, summary: pd.DataFrame, out_dir: Path, delta: float) -> None:
    """Tables a finished sweep writes beside its CSV files (``table2.md`` for the baseline)."""
    if name == "baseline":
        out_dir = Path(out_dir)
        write_text_atomic("# Baseline (Table 2)\n\n" + run_note(out_dir) + "\n\n"
                          + table2_markdown(summary, delta, load_trials(out_dir),
                                            load_csv(out_dir.parent, out_dir.name,
                                                     "timing.csv")),
                          out_dir / "table2.md")
