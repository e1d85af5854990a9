"""The report's sweep sections (Figures 2-5 of the review and the coverage sweep): the
figure, and accuracy, robustness, speed and efficiency tables, methods x swept values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.figures.sweeps import FIGURES
from magbench.methods.registry import method_label
from magbench.report.format import format_number, html_only, md_table, render
from magbench.report.intervals import annotate, cell, run_note
from magbench.report.load import load_csv, load_trials, sweep_delta
from magbench.studies.review import coverage_label, with_coverage_column

#: The review's seven methods, whose scores the selection paragraph sets beside the
#: efficient estimator's.
REVIEW = ("twostep", "crassidis", "dorveaux", "vasconcelos", "ali", "wu_shi", "magical")

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
           sweep_tables(summary, spec.x, trials := load_trials(results_dir / sweep),
                        load_csv(results_dir, sweep, "timing.csv"), sweep), ""]
    out += selection_lines(summary, load_csv(results_dir, sweep, "efficient_selection.csv"),
                           trials, sweep_delta(results_dir / sweep))
    return "\n".join(out)


def _labelled(frame: pd.DataFrame) -> pd.DataFrame:
    return frame.assign(coverage=[coverage_label(c, b) for c, b in
                                  zip(frame["cap_deg"], frame["band_deg"], strict=True)])


def selection_lines(summary: pd.DataFrame, reference: pd.DataFrame | None,
                    trials: pd.DataFrame | None, delta: float) -> list[str]:
    """Where the robustness test sets the scores: the efficient estimator under the same
    selection (``efficient_selection.csv``) beside the review's methods, at the points where
    it keeps fewer than 99 % of its runs ('' without the file or such points)."""
    if reference is None:
        return []
    ref = _labelled(reference)
    ref = ref[ref["RB_pct"] < 99]
    if ref.empty:
        return []
    rows = _labelled(summary)
    rows = rows[rows["coverage"].isin(ref["coverage"]) & rows["algorithm"].isin(REVIEW)
                & (rows["RB_pct"] > 0)]
    methods = rows.groupby("coverage")["efficiency"]
    lo, hi = methods.min(), methods.max()
    efficient = "; ".join(f"{r.coverage}: {format_number(r.efficiency, 2)} ({r.RB_pct:.3g} % "
                          f"kept; methods {format_number(lo.get(r.coverage, np.nan), 2)}-"
                          f"{format_number(hi.get(r.coverage, np.nan), 2)})"
                          for r in ref.itertuples())
    text = render("sweeps.selection", efficient=efficient,
                  accuracy=_threshold_sentence(rows, ref, trials, delta))
    return [text.strip(), ""]


def _threshold_sentence(rows: pd.DataFrame, ref: pd.DataFrame, trials: pd.DataFrame | None,
                        delta: float) -> str:
    """The points whose accuracies sit within 2x of the selection threshold 1/(delta J0)."""
    if trials is None or "J0" not in trials:
        return ""
    J0 = _labelled(trials.drop_duplicates(["cap_deg", "band_deg", "trial"])).groupby(
        "coverage", sort=False)["J0"].mean()
    threshold = 1.0 / (delta * J0)
    near = [c for c in ref["coverage"]
            if (rows.loc[rows["coverage"] == c, "accuracy"] < 2 * threshold[c]).all()]
    if not near:
        return ""
    acc = rows[rows["coverage"].isin(near)]["accuracy"]
    eff = ref.set_index("coverage")["accuracy"]
    return render("sweeps.threshold", where=" and ".join(near),
                  acc=f"{format_number(acc.min(), 2)}-{format_number(acc.max(), 2)}",
                  threshold=", ".join(f"{format_number(threshold[c], 2)}" for c in near),
                  efficient=", ".join(f"{format_number(eff[c], 3)}" for c in near))


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
    # accuracy and robustness stay in the Markdown report; speed and efficiency on the page
    return "\n\n".join(parts[:2] + ([html_only("\n\n".join(parts[2:]),
                                                "The speed and efficiency tables")]
                                     if parts[2:] else []))
