"""Report section of the real recordings, from ``<results_dir>/real`` CSV files alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.methods.registry import method_label
from magbench.report.format import format_number, render
from magbench.report.intervals import accuracy_intervals, cell, rb_interval, run_note
from magbench.studies.real import selection_inflation

__all__ = ["real_report_section"]


def real_report_section(results_dir: Path | str, figure_link: str = "real/fig6_real.png") -> str:
    """Markdown section on the real recordings, from ``<results_dir>/real/`` CSV files alone.

    ``figure_link`` is the figure's path relative to where the Markdown is written (the
    default suits ``<results_dir>/report.md``). Returns an empty string when the real sweep
    has not been run.
    """
    folder = Path(results_dir) / "real"
    if not (folder / "fig6_real.csv").exists() or not (folder / "real_summary.csv").exists():
        return ""
    per_method = pd.read_csv(folder / "fig6_real.csv")
    per_rec = pd.read_csv(folder / "real_summary.csv", dtype={"cross_on": str, "error": str})
    per_rec["cross_on"] = per_rec["cross_on"].fillna("")
    lines = [
        "## Real recordings (review section 10.2, Figure 6)", "",
        render("real.intro", n_rec=per_rec["dataset"].nunique(), K_max=int(per_rec["K"].max())),
        "", f"![Figure 6 on real data]({figure_link})", "",
        f"Per recording: ![Figure 6 per recording]"
        f"({figure_link.replace('fig6_real.png', 'fig6_real_recordings.png')})", "",
        run_note(folder, "recordings"), "", render("real.brackets"), "",
        *_selection_lines(per_method, per_rec),
    ]
    bounds = _accuracy_bounds(per_rec)
    for how, g in per_method.groupby("preprocess", sort=False):
        lines += _method_table(how, g, bounds)
    return "\n".join(lines + _cross_table(per_rec))


def _selection_lines(per_method: pd.DataFrame, per_rec: pd.DataFrame) -> list[str]:
    """The accuracies set by which recordings a method kept (as Figure 6 hatches them)."""
    flags = selection_inflation(per_rec)
    flags = flags.loc[flags["set_by_selection"].astype(bool)].merge(
        per_method[["preprocess", "algorithm", "accuracy_in"]], on=["preprocess", "algorithm"])
    if flags.empty:
        return []
    flagged = "; ".join(
        f"{method_label(r.algorithm)} (`{r.preprocess}`) {format_number(r.accuracy_in)} on its "
        f"{r.n_kept} recordings, where the others score {format_number(r.others_on_kept)} "
        f"({format_number(r.inflation, 2)}x their accuracy on all they solve)"
        for r in flags.itertuples())
    return [render("real.selection", flagged=flagged), ""]


def _accuracy_bounds(per_rec: pd.DataFrame) -> dict[str, dict]:
    """Bootstrap intervals of the in- and out-of-sample accuracies, by (preprocess, method),
    over the rows method_summary (studies/real.py) averages: recordings the method applies
    to."""
    single = per_rec[~per_rec["skipped"].astype(bool)] if "skipped" in per_rec else per_rec
    bounds = {}
    for column in ("J_r_in", "J_r_out"):
        if column in single.columns:
            part = single[np.isfinite(single[column].astype(float))]
            acc = accuracy_intervals(part, ["preprocess", "algorithm"], f"real {column}",
                                     value=column)
            bounds[column] = {(r.preprocess, r.algorithm): (r.acc_lo, r.acc_hi)
                              for r in acc.itertuples(index=False)}
    return bounds


def _method_table(how: str, g: pd.DataFrame, bounds: dict[str, dict]) -> list[str]:
    lines = [f"Preprocessing `{how}`:", "",
             "| method | RB % [95 %] | accuracy in [95 %] | accuracy out [95 %] | "
             "ratio in | ratio out | n ok / n | time (ms) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    none = (np.nan, np.nan)
    for r in g.itertuples(index=False):
        rb = rb_interval({"n": r.n_applicable, "n_meaningful": r.n_meaningful,
                          "RB_pct": r.RB_pct})
        acc_in = cell(r.accuracy_in, bounds.get("J_r_in", {}).get((how, r.algorithm), none))
        acc_out = cell(r.accuracy_out, bounds.get("J_r_out", {}).get((how, r.algorithm), none))
        lines.append(f"| {r.label} | {cell(r.RB_pct, rb)} | {acc_in} | {acc_out} | "
                     f"{format_number(r.median_ratio_in, 2)} | "
                     f"{format_number(r.median_ratio_out, 2)} | {r.n_meaningful} / "
                     f"{r.n_applicable} | {format_number(1e3 * r.tau_s, 2)} |")
    return lines + [""]


def _cross_table(per_rec: pd.DataFrame) -> list[str]:
    cross = per_rec[per_rec["cross_on"] != ""]
    if not len(cross):
        return []
    lines = [render("real.cross"), "",
             "| preprocessing | method | fit on | J_r in | J_r on other | sphere fit in |",
             "|---|---|---|---:|---:|---:|"]
    for r in cross[cross["meaningful"].astype(bool)].itertuples(index=False):
        lines.append(f"| {r.preprocess} | {r.algorithm} | {r.dataset} | "
                     f"{format_number(r.J_r_in)} | {format_number(r.J_r_cross)} | "
                     f"{format_number(r.J_r_sphere_in)} |")
    return lines + [""]
