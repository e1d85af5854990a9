"""Figures 2-5 of the review from the sweep CSV files (never by simulating).

Each figure has the review's three panels against the swept parameter: (a) accuracy 1/rho
(78), (b) execution speed 1/tau (79), (c) robustness RB % (77); one line per method, the
review's seven solid, the extra methods dashed, the review's printed-formula variants
dash-dotted. The accuracy panel also carries the
Cramer-Rao limit: 1/E[J] of an efficient unbiased estimator (column ``crb_accuracy`` of
``summary.csv``, see :mod:`magbench.core.crb`), the accuracy no unbiased method can beat on average
in the small-noise regime. :func:`figure_data` returns exactly what is drawn; it is written
beside the PNG as CSV.

Figures are built as bare ``matplotlib.figure.Figure`` objects, rendered by the Agg canvas,
without pyplot: no global backend state, nothing opens a window, nothing leaks between calls.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from magbench.core.files import write_csv_atomic
from magbench.figures.style import method_style, new_figure, save_figure
from magbench.methods.registry import get_method, methods

__all__ = ["FIGURES", "FigureSpec", "figure_data", "plot_sweep", "write_figure"]

#: The series name of the Cramer-Rao limit in :func:`figure_data`.
CRB_SERIES = "crb"
CRB_LABEL = "Cramer-Rao limit (1/E[J], efficient estimator)"


@dataclass(frozen=True)
class FigureSpec:
    """How one sweep is drawn: the review's figure number, the x column, its label and scale."""

    number: int | None
    x: str
    xlabel: str
    logx: bool = False
    categorical: bool = False  # x values are labels, drawn in the sweep's order

    @property
    def stem(self) -> str:
        """File name stem, e.g. ``fig2_gamma`` (``fig_coverage`` beyond the review)."""
        return f"fig{self.number}_{self.x}" if self.number else f"fig_{self.x}"

    @property
    def title(self) -> str:
        return (f"Figure {self.number}: performance against {self.x}" if self.number else
                f"Beyond the review: performance against {self.x}")


FIGURES = {
    "gamma": FigureSpec(2, "gamma", r"offset perturbation $\gamma$, $e_i \sim U[-\gamma, \gamma]$"
                        " (field units)"),
    "beta": FigureSpec(3, "beta", r"matrix perturbation $\beta$, $E_{ij} \sim U[-\beta, \beta]$"),
    "K": FigureSpec(4, "K", "dataset size K (samples)"),
    "sigma": FigureSpec(5, "sigma", r"noise standard deviation $\sigma$ (field units)",
                        logx=True),
    "coverage": FigureSpec(None, "coverage", "field directions covered", categorical=True),
}

def _method_info(name: str) -> tuple[str, str]:
    try:
        spec = get_method(name)
        return spec.label, spec.family
    except ValueError:  # a method of an older run, no longer registered
        return name, "extra"


def _ordered(names: list[str]) -> list[str]:
    order = {n: i for i, n in enumerate(methods())}
    return sorted(names, key=lambda n: (order.get(n, len(order)), n))


def figure_data(summary: pd.DataFrame, sweep: str) -> pd.DataFrame:
    """The numbers a sweep's figure draws, one row per (series, x value).

    Parameters
    ----------
    summary : DataFrame
        ``summary.csv`` of the sweep (columns of :func:`magbench.core.metrics.summarize`).
    sweep : str
        A key of :data:`FIGURES`.

    Returns
    -------
    DataFrame
        Columns ``series`` (method name, or ``"crb"`` for the Cramer-Rao limit), ``label``,
        ``family`` ("review", "extra" or "bound"), ``x`` (the swept value), ``accuracy``
        (1/rho), ``speed_hz`` (1/tau) and ``RB_pct``. The ``crb`` rows carry only accuracy.
    """
    spec = FIGURES[sweep]
    rows = []
    for name in _ordered(list(summary["algorithm"].unique())):
        label, family = _method_info(name)
        part = summary[summary["algorithm"] == name]
        if not spec.categorical:
            part = part.sort_values(spec.x)
        for rec in part.itertuples(index=False):
            rows.append({"series": name, "label": label, "family": family,
                         "x": getattr(rec, spec.x), "accuracy": rec.accuracy,
                         "speed_hz": rec.speed_hz, "RB_pct": rec.RB_pct})
    if "crb_accuracy" in summary.columns:
        # The same datasets feed every method: the bound is one number per point.
        floor = summary.groupby(spec.x, sort=not spec.categorical)["crb_accuracy"].first()
        rows += [{"series": CRB_SERIES, "label": CRB_LABEL, "family": "bound", "x": x,
                  "accuracy": v, "speed_hz": np.nan, "RB_pct": np.nan}
                 for x, v in floor.items()]
    return pd.DataFrame(rows, columns=["series", "label", "family", "x", "accuracy",
                                       "speed_hz", "RB_pct"])


def plot_sweep(data: pd.DataFrame, sweep: str) -> Figure:
    """Draw :func:`figure_data` output as the review's three panels, legend on the right."""
    spec = FIGURES[sweep]
    fig = new_figure(16.5, 4.8)
    axes = fig.subplots(1, 3)
    panels = [("accuracy", r"accuracy $1/\rho$ (1 / field units)", True),
              ("speed_hz", r"execution speed $1/\tau$ (1/s)", True),
              ("RB_pct", "robustness RB (%)", False)]
    methods_here = [s for s in dict.fromkeys(data["series"]) if s != CRB_SERIES]
    # Categorical x (coverage labels): positions in the sweep's order, labels as ticks.
    categories = list(dict.fromkeys(data["x"])) if spec.categorical else None

    def xs(values: pd.Series) -> list:
        return [categories.index(v) for v in values] if categories else list(values)

    for name in methods_here:
        part = data[data["series"] == name]
        style = method_style(name)
        for ax, (column, _, _) in zip(axes, panels, strict=True):
            ax.plot(xs(part["x"]), part[column], **style)
    floor = data[data["series"] == CRB_SERIES]
    if len(floor):
        axes[0].plot(xs(floor["x"]), floor["accuracy"], color="black", linestyle=":",
                     linewidth=2.5, label=CRB_LABEL)
    letters = "abc"
    for k, (ax, (column, ylabel, logy)) in enumerate(zip(axes, panels, strict=True)):
        if logy and np.any(data[column].to_numpy(dtype=float) > 0):
            ax.set_yscale("log")
        if spec.logx:
            ax.set_xscale("log")
        if categories:
            ax.set_xticks(range(len(categories)), categories, rotation=35, ha="right")
        else:
            ax.set_xticks(sorted(data["x"].unique()))
        ax.set_xlabel(spec.xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(f"({letters[k]})", loc="left")
        ax.grid(True, which="major", alpha=0.3)
    axes[2].set_ylim(-3, 103)
    if spec.logx:
        for ax in axes:
            ax.set_xticks(sorted(data["x"].unique()))
            ax.set_xticklabels([f"{v:g}" for v in sorted(data["x"].unique())])
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize=9, frameon=False)
    fig.suptitle(spec.title)
    return fig


def write_figure(summary: pd.DataFrame, sweep: str, out_dir: Path | str) -> tuple[Path, Path]:
    """Write ``fig<N>_<x>.png`` and the CSV of what it plots into ``out_dir``."""
    out_dir = Path(out_dir)
    spec = FIGURES[sweep]
    data = figure_data(summary, sweep)
    fig = plot_sweep(data, sweep)
    png, csv = out_dir / f"{spec.stem}.png", out_dir / f"{spec.stem}.csv"
    save_figure(fig, png)
    write_csv_atomic(data, csv)
    return png, csv
