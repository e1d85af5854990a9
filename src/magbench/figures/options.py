"""A method-option sweep (``vary: options.<method>.<option>``) from its ``summary.csv``.

Two panels against the option's value: (a) accuracy in the squared form the report argues the
review uses, ``1/mean(J_h^2 + J_T^2)`` over meaningful runs (column ``mse`` of the summary), and
(b) robustness RB % (77). The swept method is a line in its fixed style; its run at the default
value and every other method of the sweep are horizontal lines in theirs; the review's Table 2
value of the swept method is a black dashed line. :func:`option_figure_data` returns exactly
what is drawn, written beside the PNG as CSV.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from magbench.core.files import write_csv_atomic
from magbench.core.reference import paper_values
from magbench.figures.style import method_style, new_figure, save_figure
from magbench.methods.registry import find_method

__all__ = ["option_column", "option_figure", "option_figure_data", "write_option_figure"]

#: Axis labels of known option axes; others are labelled by their column.
XLABELS = {"crassidis.P0": r"EKF initial covariance $P_0 = s\,I$: $s$ (field units$^2$)"}


def option_column(summary: pd.DataFrame) -> str | None:
    """The option-axis column of a summary (``<method>.<option>``), or None."""
    found = [c for c in summary.columns if "." in c]
    return found[0] if found else None


def _paper(method: str) -> dict:
    spec = find_method(method)
    key = spec.paper_key if spec is not None else None
    return paper_values()["review"]["table2"].get(key, {}) if key else {}


def option_figure_data(summary: pd.DataFrame) -> pd.DataFrame:
    """What :func:`option_figure` draws: series, value (NaN for a horizontal line), accuracy
    (squared form), RB %, and the paper's values of the swept method."""
    column = option_column(summary)
    if column is None:
        raise ValueError("the summary has no option-axis column (<method>.<option>)")
    method = column.split(".")[0]
    rows = []
    for value, rec in zip(summary[column], summary.itertuples(index=False), strict=True):
        on_axis = rec.algorithm == method and pd.notna(value)
        series = rec.algorithm if on_axis or rec.algorithm != method else f"{method} (default)"
        rows.append({"series": series, "algorithm": rec.algorithm,
                     "value": float(value) if on_axis else np.nan,
                     "accuracy_sq": 1.0 / rec.mse if rec.mse > 0 else np.nan,
                     "RB_pct": rec.RB_pct})
    out = pd.DataFrame(rows)
    paper = _paper(method)
    out["accuracy_paper"] = paper.get("accuracy", np.nan)
    out["RB_pct_paper"] = paper.get("robustness_pct", np.nan)
    return out


def option_figure(summary: pd.DataFrame) -> Figure:
    """Accuracy (squared form) and RB % against the swept option's value."""
    data = option_figure_data(summary)
    column = option_column(summary)
    method = column.split(".")[0]
    fig = new_figure(10.0, 4.2)
    axes = fig.subplots(1, 2)
    swept = data[data["value"].notna()].sort_values("value")
    style = method_style(method)
    for ax, y, title in [(axes[0], "accuracy_sq", "(a) accuracy 1/mean($J_h^2 + J_T^2$)"),
                         (axes[1], "RB_pct", "(b) robustness RB %")]:
        ax.plot(swept["value"], swept[y], **{**style, "label": f"{style['label']}, $P_0 = s I$"
                                             if column == "crassidis.P0" else style["label"]})
        for rec in data[data["value"].isna()].itertuples(index=False):
            line = method_style(rec.algorithm)
            label = line["label"] + (" (default)" if rec.series.endswith("(default)") else "")
            ax.axhline(getattr(rec, y), color=line["color"], linestyle=line["linestyle"]
                       if rec.algorithm != method else ":", linewidth=1.2, label=label)
        paper = data[f"{'accuracy' if y == 'accuracy_sq' else 'RB_pct'}_paper"].iloc[0]
        if np.isfinite(paper):
            ax.axhline(paper, color="black", linestyle="--", linewidth=1.0,
                       label=f"review, Table 2 ({paper:.3g})")
        ax.set_xscale("log")
        ax.set_xlabel(XLABELS.get(column, column))
        ax.set_title(title)
        ax.grid(True, which="major", alpha=0.3)
    axes[0].set_yscale("log")
    axes[1].set_ylim(-3, 103)
    axes[0].legend(fontsize=7, loc="lower center")
    axes[1].legend(fontsize=7, loc="center")
    n = int(summary["n"].max())
    fig.suptitle(f"{style['label']}: performance against {column.split('.')[1]} "
                 f"(nominal point, {n} trials)")
    return fig


def write_option_figure(summary: pd.DataFrame, out_dir: Path | str, name: str) -> Path:
    """Write ``fig_<name>.png`` and ``fig_<name>.csv`` (what is drawn) into ``out_dir``."""
    out_dir = Path(out_dir)
    write_csv_atomic(option_figure_data(summary), out_dir / f"fig_{name}.csv")
    return save_figure(option_figure(summary), out_dir / f"fig_{name}.png")
