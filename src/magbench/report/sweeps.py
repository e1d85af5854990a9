"""The report's sweep sections (Figures 2-5 of the review and the coverage sweep): the
figure, and accuracy, robustness, speed and efficiency tables, methods x swept values."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.figures.sweeps import FIGURES
from magbench.methods.registry import method_label
from magbench.report.format import format_number, md_table, render
from magbench.report.intervals import annotate, cell, run_note
from magbench.report.load import load_csv, load_trials
from magbench.studies.review import with_coverage_column

__all__ = ["SWEEP_SECTIONS", "figure_title", "pivot", "sweep_section", "sweep_tables"]

#: The sweeps with a section of their own, in report order.
SWEEP_SECTIONS = ("gamma", "beta", "K", "sigma", "coverage")


def figure_title(sweep: str) -> str:
    """'Figure 2' for a figure of the review, else what the sweep is."""
    number = FIGURES[sweep].number
    return f"Figure {number}" if number else f"{sweep.capitalize()} (beyond the review)"


def pivot(summary: pd.DataFrame, x: str, column: str, names: list[str] | None = None
          ) -> pd.DataFrame:
    """Methods x swept values table of one summary column (points in their sweep order)."""
    table = summary.pivot_table(index="algorithm", columns=x, values=column, sort=False,
                                dropna=False)
    rows = [n for n in (names or list(dict.fromkeys(summary["algorithm"]))) if n in table.index]
    return table.loc[rows]


def sweep_section(results_dir: Path, sweep: str) -> str:
    """Markdown of one sweep: run note, figure, panel legend and tables ('' without its
    ``summary.csv``)."""
    results_dir = Path(results_dir)
    summary = load_csv(results_dir, sweep)
    if summary is None:
        return ""
    spec = FIGURES[sweep]
    if spec.categorical:
        summary = with_coverage_column(summary)
    title = figure_title(sweep)
    out = [f"## {title}: sweep `{sweep}`", "", run_note(results_dir / sweep), "",
           f"![{title}]({sweep}/{spec.stem}.png)", "", render("sweeps.panels"), "",
           sweep_tables(summary, spec.x, load_trials(results_dir / sweep),
                        load_csv(results_dir, sweep, "timing.csv"), sweep), ""]
    return "\n".join(out)


def _columns(table: pd.DataFrame, x: str) -> list[str]:
    return ["method"] + [f"{x}={c:g}" if isinstance(c, float | int) else str(c)
                         for c in table.columns]


def _cell_table(rich: pd.DataFrame, x: str, column: str) -> pd.DataFrame:
    table = rich.pivot_table(index="algorithm", columns=x, values=column, sort=False,
                             aggfunc="first")
    order = [n for n in dict.fromkeys(rich["algorithm"]) if n in table.index]
    table = table.loc[order, [c for c in dict.fromkeys(rich[x]) if c in table.columns]]
    frame = table.reset_index()
    frame.insert(0, "method", [method_label(n) for n in frame.pop("algorithm")])
    frame.columns = _columns(table, x)
    return frame.fillna("-")


def _efficiency_table(summary: pd.DataFrame, x: str) -> str:
    floor = summary.groupby(x, sort=False)["crb_accuracy"].first()
    eff = pivot(summary, x, "efficiency")
    frame = eff.reset_index()
    frame.insert(0, "method", [method_label(n) for n in frame.pop("algorithm")])
    frame.columns = _columns(eff, x)
    floors = ", ".join(f"{c if isinstance(c, str) else f'{c:g}'}: {format_number(v)}"
                       for c, v in floor.items())
    return render("sweeps.efficiency_title", floors=floors) + "\n\n" + md_table(frame, 3)


def sweep_tables(summary: pd.DataFrame, x: str, trials: pd.DataFrame | None = None,
                 timing: pd.DataFrame | None = None, sweep: str = "") -> str:
    """Compact Markdown tables of one sweep: accuracy and RB % with their 95 % intervals, and
    speed (from the timing pass when ``timing`` is given), methods x values."""
    rich = annotate(summary, trials, timing, sweep)
    rich["accuracy_cell"] = [cell(r.accuracy, (r.acc_lo, r.acc_hi))
                             for r in rich.itertuples(index=False)]
    rich["RB_cell"] = [cell(r.RB_pct, (r.RB_lo, r.RB_hi), 3) for r in rich.itertuples(index=False)]
    timed = timing is not None
    rich["speed_cell"] = [format_number(r.speed, 2) for r in rich.itertuples(index=False)]
    with_acc = bool(rich["acc_lo"].notna().any())
    titles = [("accuracy_cell", render("sweeps.accuracy_title_interval" if with_acc
                                       else "sweeps.accuracy_title")),
              ("RB_cell", render("sweeps.rb_title")),
              ("speed_cell", render("sweeps.speed_timing_pass" if timed
                                    else "sweeps.speed_per_trial"))]
    parts = [f"*{title}*\n\n" + md_table(_cell_table(rich, x, column))
             for column, title in titles]
    if "crb_accuracy" in summary:
        parts.append(_efficiency_table(summary, x))
    return "\n\n".join(parts)
