"""Figures 2-5 of the review from the sweep CSV files (never by simulating).

Each figure has the review's three panels against the swept parameter: (a) accuracy 1/rho
(78), (b) execution speed 1/tau (79), (c) robustness RB % (77); one line per method, the
review's seven solid, the extra methods dashed, the review's printed-formula variants
dash-dotted. A fourth panel (d) compares every method with the Cramer-Rao bound on the *same*
runs it is scored on: ``efficiency`` of ``summary.csv``, the bound over a method's meaningful
runs divided by its mean squared error over those runs (1 = on the floor; see
:mod:`magbench.core.crb`). A single floor line averaged over all datasets, beside 1/rho
averaged over the meaningful runs only, puts methods "above the limit" wherever robustness is
below 100 %. The matched ratio removes the datasets' difference but not the selection: the
test (76) keeps the runs whose error happened to be small, so where it rejects many (narrow
caps) even an efficient unbiased estimator scores above 1. Where the sweep's folder holds
``efficient_selection.csv`` (:mod:`magbench.studies.selection`), that estimator under the same
selection is drawn as a black dashed reference in panels (a), (c) and (d): a method near it is
scored by the selection, not by what it does.

The speed panel reads the sweep's timing pass (``timing.csv``, :mod:`magbench.studies.timing`:
the same datasets, warmed up, one thread) when it is there, and the per-trial times of
``summary.csv`` otherwise; the panel's title says which. :func:`figure_data` returns exactly
what is drawn; it is written beside the PNG as CSV.

The coverage sweep's points are of two geometries (a polar cap of shrinking half-angle, an
equatorial band): each is drawn as its own group, a line within a group and never across.

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
from magbench.methods.registry import find_method, methods
from magbench.studies.review import POINT_COLUMNS, coverage_label

__all__ = ["FIGURES", "REFERENCE_STYLE", "FigureSpec", "coverage_group", "figure_data",
           "plot_sweep", "reference_data", "write_figure"]


#: Accuracy and efficiency points averaged over fewer meaningful runs than this are not
#: drawn as part of a line: a line through one or two runs reads as a result.
MIN_MEANINGFUL = 10

#: The columns of a sweep figure's CSV: what is drawn, and the n behind every point.
FIGURE_COLUMNS = ["series", "label", "family", "x", "group", "accuracy", "speed_hz",
                  "speed_source", "RB_pct", "efficiency", "n", "n_meaningful"]


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
    spec = find_method(name)
    return (name, "extra") if spec is None else (spec.label, spec.family)


def _ordered(names: list[str]) -> list[str]:
    order = {n: i for i, n in enumerate(methods())}
    return sorted(names, key=lambda n: (order.get(n, len(order)), n))


def _timing_speed(timing: pd.DataFrame | None, x: str) -> dict | None:
    """(x value, method) -> speed 1/median of the timing pass, or None without one."""
    if timing is None or timing.empty:
        return None
    return {(getattr(r, x), r.algorithm): r.speed_hz for r in timing.itertuples(index=False)}


def coverage_group(label: str) -> str:
    """The geometry of a coverage point's label: ``"band"`` or ``"cap"`` (the full sphere is
    the widest cap)."""
    return "band" if str(label).startswith("band") else "cap"


def figure_data(summary: pd.DataFrame, sweep: str,
                timing: pd.DataFrame | None = None) -> pd.DataFrame:
    """The numbers a sweep's figure draws, one row per (method, x value).

    Parameters
    ----------
    summary : DataFrame
        ``summary.csv`` of the sweep (columns of :func:`magbench.core.metrics.summarize`).
    sweep : str
        A key of :data:`FIGURES`.
    timing : DataFrame, optional
        ``timing.csv`` of the sweep (the timing protocol); its speeds replace the per-trial
        ones (NaN where it has none). For the coverage sweep it must carry the ``coverage``
        label column too.

    Returns
    -------
    DataFrame
        Columns ``series`` (method name), ``label``, ``family``, ``x`` (the swept value),
        ``group`` (the coverage geometry, ``cap`` or ``band``; empty elsewhere), ``accuracy``
        (1/rho), ``speed_hz`` (1/tau; NaN where RB is 0, as eq. (79) averages over
        meaningful runs), ``speed_source`` (``timing`` or ``trials``),
        ``RB_pct``, ``efficiency`` (Cramer-Rao bound / mean squared error over the same
        meaningful runs; NaN without the Cramer-Rao columns), ``n`` (runs at the point) and
        ``n_meaningful`` (the runs accuracy and efficiency average over).
    """
    spec = FIGURES[sweep]
    speeds = _timing_speed(timing, spec.x)
    rows = []
    for name in _ordered(list(summary["algorithm"].unique())):
        label, family = _method_info(name)
        part = summary[summary["algorithm"] == name]
        if not spec.categorical:
            part = part.sort_values(spec.x)
        for rec in part.itertuples(index=False):
            x = getattr(rec, spec.x)
            speed = rec.speed_hz if speeds is None else speeds.get((x, name), np.nan)
            rows.append({"series": name, "label": label, "family": family, "x": x,
                         "group": coverage_group(x) if spec.categorical else "",
                         "accuracy": rec.accuracy,
                         # eq. (79) times meaningful runs: no speed where there is none
                         "speed_hz": speed if rec.RB_pct > 0 else np.nan,
                         "speed_source": "trials" if speeds is None else "timing",
                         "RB_pct": rec.RB_pct,
                         "efficiency": getattr(rec, "efficiency", np.nan),
                         "n": getattr(rec, "n", np.nan),
                         "n_meaningful": getattr(rec, "n_meaningful", np.nan)})
    return pd.DataFrame(rows, columns=FIGURE_COLUMNS)


#: How the simulated efficient estimator under the same selection is drawn.
REFERENCE_STYLE = {"color": "0.35", "linestyle": (0, (5, 2)), "linewidth": 3.0, "marker": "o",
                   "markersize": 7, "markerfacecolor": "none", "alpha": 0.85, "zorder": 5,
                   "label": "efficient unbiased estimator,\nsame selection (simulated)"}


def reference_data(reference: pd.DataFrame | None, sweep: str) -> pd.DataFrame:
    """Rows of :func:`figure_data` for ``efficient_selection.csv`` (the efficient estimator
    scored on its meaningful runs), ``family`` ``reference``; empty without it."""
    columns = FIGURE_COLUMNS
    if reference is None or reference.empty:
        return pd.DataFrame(columns=columns)
    spec = FIGURES[sweep]
    xs = ([coverage_label(c, b) for c, b in zip(reference["cap_deg"], reference["band_deg"],
                                                strict=True)]
          if spec.categorical else list(reference[spec.x]))
    return pd.DataFrame({"series": "efficient_selection", "label": REFERENCE_STYLE["label"],
                         "family": "reference", "x": xs,
                         "group": [coverage_group(x) if spec.categorical else "" for x in xs],
                         "accuracy": reference["accuracy"].to_numpy(), "speed_hz": np.nan,
                         "speed_source": "", "RB_pct": reference["RB_pct"].to_numpy(),
                         "efficiency": reference["efficiency"].to_numpy(),
                         "n": reference.get("n", np.nan),
                         "n_meaningful": reference.get("n_meaningful", np.nan)},
                        columns=columns)


def plot_sweep(data: pd.DataFrame, sweep: str) -> Figure:
    """Draw :func:`figure_data` output: the review's three panels and the matched
    Cramer-Rao comparison, legend on the right."""
    spec = FIGURES[sweep]
    fig = new_figure(13.5, 8.2)
    grid = fig.subplots(2, 2)
    axes = [grid[0, 0], grid[0, 1], grid[1, 0], grid[1, 1]]
    methods_rows = data[data["family"] != "reference"]
    timed = bool(len(methods_rows)) and (methods_rows["speed_source"] == "timing").all()
    speed_label = (r"execution speed $1/\tau$ (1/s), timing pass" if timed else
                   r"execution speed $1/\tau$ (1/s), per-trial times")
    panels = [("accuracy", r"accuracy $1/\rho$ (1 / field units)", True),
              ("speed_hz", speed_label, True),
              ("RB_pct", "robustness RB (%)", False),
              ("efficiency", "Cramer-Rao bound / mean squared error,\nsame meaningful runs "
               "(1 = on the floor)", True)]
    methods_here = list(dict.fromkeys(data["series"]))
    categories = list(dict.fromkeys(data["x"])) if spec.categorical else None
    position = _positions(categories) if categories else {}

    for name in methods_here:
        part = data[data["series"] == name]
        style = (REFERENCE_STYLE if (part["family"] == "reference").all()
                 else method_style(name))
        groups = part.groupby("group", sort=False) if categories else [("", part)]
        for gi, (_, g) in enumerate(groups):
            xs = [position[v] for v in g["x"]] if categories else list(g["x"])
            few = (g["n_meaningful"] < MIN_MEANINGFUL).to_numpy() if "n_meaningful" in g \
                else np.zeros(len(g), bool)
            for ax, (column, _, _) in zip(axes, panels, strict=True):
                values = g[column].to_numpy(dtype=float).copy()
                if column in ("accuracy", "efficiency"):
                    values[few] = np.nan             # too few runs to average: no line
                if np.isfinite(values).any():
                    ax.plot(xs, values, **{**style, "label": style["label"] if gi == 0
                                           else "_nolegend_"})
    for k, (ax, (column, ylabel, logy)) in enumerate(zip(axes, panels, strict=True)):
        values = data[column].to_numpy(dtype=float)
        if logy and np.any(values[np.isfinite(values)] > 0):
            ax.set_yscale("log")
        _x_axis(ax, spec, data, position)
        ax.set_ylabel(ylabel)
        ax.set_title(f"({'abcd'[k]})", loc="left")
        if panels[k][0] in ("accuracy", "efficiency"):
            ax.set_title(f"points from < {MIN_MEANINGFUL} meaningful runs not drawn",
                         loc="right", fontsize=8)
        ax.grid(True, which="major", alpha=0.3)
    axes[2].set_ylim(-3, 103)
    axes[3].axhline(1.0, color="black", linestyle=":", linewidth=2,
                    label="Cramer-Rao floor (same runs)")
    handles, labels = axes[0].get_legend_handles_labels()
    h3, l3 = axes[3].get_legend_handles_labels()
    fig.legend(handles + h3[-1:], labels + l3[-1:], loc="outside right center", fontsize=9,
               frameon=False)
    fig.suptitle(spec.title + (" (polar caps | equatorial bands: two geometries, never joined)"
                               if categories else ""))
    return fig


def _positions(categories: list[str]) -> dict[str, int]:
    """x positions of categorical points (coverage): caps, then a gap, then bands."""
    position, k = {}, 0
    for i, c in enumerate(categories):
        if i and coverage_group(c) != coverage_group(categories[i - 1]):
            k += 1                                    # a gap between the geometries
        position[c] = k
        k += 1
    return position


def _x_axis(ax: object, spec: FigureSpec, data: pd.DataFrame, position: dict) -> None:
    """Ticks, scale and label of the swept parameter; a dashed line between geometries."""
    if spec.logx:
        ax.set_xscale("log")
    if position:
        categories = list(position)
        ax.set_xticks([position[c] for c in categories], categories, rotation=35, ha="right")
        for i, c in enumerate(categories):
            if i and coverage_group(c) != coverage_group(categories[i - 1]):
                ax.axvline(position[c] - 1, color="0.6", linestyle="--", linewidth=1)
    else:
        ticks = sorted(data["x"].unique())
        ax.set_xticks(ticks, [f"{v:g}" for v in ticks])
    ax.set_xlabel(spec.xlabel)


def write_figure(summary: pd.DataFrame, sweep: str, out_dir: Path | str,
                 timing: pd.DataFrame | None = None) -> tuple[Path, Path]:
    """Write ``fig<N>_<x>.png`` and the CSV of what it plots into ``out_dir`` (speeds from
    ``timing``, the sweep's timing pass, when given; the efficient estimator under the same
    selection when ``out_dir`` holds ``efficient_selection.csv``)."""
    out_dir = Path(out_dir)
    spec = FIGURES[sweep]
    reference = out_dir / "efficient_selection.csv"
    data = figure_data(summary, sweep, timing)
    if reference.exists():
        # Only the points of this summary: the file describes the folder's own sweep.
        points = summary[POINT_COLUMNS].drop_duplicates()
        rows = pd.read_csv(reference).merge(points, on=POINT_COLUMNS)
        data = pd.concat([data, reference_data(rows, sweep)], ignore_index=True)
    fig = plot_sweep(data, sweep)
    png, csv = out_dir / f"{spec.stem}.png", out_dir / f"{spec.stem}.csv"
    save_figure(fig, png)
    write_csv_atomic(data, csv)
    return png, csv
