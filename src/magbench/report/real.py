"""Report section of the real recordings, from ``<results_dir>/real`` CSV files alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.report.intervals import accuracy_intervals, cell, rb_interval, run_note

__all__ = ["real_report_section"]


def _fmt(x: float, digits: int = 3) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


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
    n_rec = per_rec["dataset"].nunique()
    lines = [
        "## Real recordings (review section 10.2, Figure 6)", "",
        f"{n_rec} public recordings (see the README for their sources), J_r of eq. (81). "
        "*In*: fit and J_r on all samples (at most "
        f"{int(per_rec['K'].max())} per recording, evenly thinned). *Out*: fit on one half in "
        "time, J_r on the other, both ways, mean (when both half-fits gave a non-degenerate "
        "estimate). Meaningful (for RB %): ended normally, J_r at most twice that of the "
        "least-squares sphere fit, and calibrated directions covering at least half of what "
        "the sphere fit's do (J_r alone rewards a degenerate answer that maps every sample "
        "near one point of the sphere). accuracy = 1 / mean J_r over meaningful fits; "
        "ratio = median of J_r / J_r of the sphere fit on the same data. Preprocessing "
        "`scale` divides by the mean norm (the review's); `centre` also removes the "
        "sphere-fit centre and radius.", "",
        f"![Figure 6 on real data]({figure_link})", "",
        f"Per recording: ![Figure 6 per recording]"
        f"({figure_link.replace('fig6_real.png', 'fig6_real_recordings.png')})", "",
        run_note(folder, "recordings"), "",
        "Brackets: 95 % intervals, Wilson's for RB % (meaningful fits out of the recordings the "
        "method applies to), the percentile bootstrap over the meaningful fits' J_r for the "
        "accuracies.", "",
    ]
    # The rows method_summary (studies/real.py) averages: recordings the method applies to.
    single = per_rec[~per_rec["skipped"].astype(bool)] if "skipped" in per_rec else per_rec
    bounds = {}
    for column in ("J_r_in", "J_r_out"):
        if column in single.columns:
            part = single[np.isfinite(single[column].astype(float))]
            acc = accuracy_intervals(part, ["preprocess", "algorithm"], f"real {column}",
                                     value=column)
            bounds[column] = {(r.preprocess, r.algorithm): (r.acc_lo, r.acc_hi)
                              for r in acc.itertuples(index=False)}
    for how, g in per_method.groupby("preprocess", sort=False):
        lines += [f"Preprocessing `{how}`:", "",
                  "| method | RB % [95 %] | accuracy in [95 %] | accuracy out [95 %] | "
                  "ratio in | ratio out | "
                  "n ok / n | time (ms) |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in g.itertuples(index=False):
            rb = rb_interval({"n": r.n_applicable, "n_meaningful": r.n_meaningful,
                              "RB_pct": r.RB_pct})
            acc_in = cell(r.accuracy_in, bounds.get("J_r_in", {}).get(
                (how, r.algorithm), (np.nan, np.nan)))
            acc_out = cell(r.accuracy_out, bounds.get("J_r_out", {}).get(
                (how, r.algorithm), (np.nan, np.nan)))
            lines.append(f"| {r.label} | {cell(r.RB_pct, rb)} | {acc_in} | "
                         f"{acc_out} | {_fmt(r.median_ratio_in, 2)} | "
                         f"{_fmt(r.median_ratio_out, 2)} | "
                         f"{r.n_meaningful} / {r.n_applicable} | {_fmt(1e3 * r.tau_s, 2)} |")
        lines.append("")
    cross = per_rec[per_rec["cross_on"] != ""]
    if len(cross):
        lines += ["Across recordings of the same QMC5883L (fit on one, J_r on the other):", "",
                  "| preprocessing | method | fit on | J_r in | J_r on other | sphere fit in |",
                  "|---|---|---|---:|---:|---:|"]
        for r in cross[cross["meaningful"].astype(bool)].itertuples(index=False):
            lines.append(f"| {r.preprocess} | {r.algorithm} | {r.dataset} | {_fmt(r.J_r_in)} "
                         f"| {_fmt(r.J_r_cross)} | {_fmt(r.J_r_sphere_in)} |")
        lines.append("")
    return "\n".join(lines)
