"""The heading study's figures, from ``heading_trials.csv`` and ``correlation.csv`` alone.

``heading_error.png``: each method's heading RMS per unit (points) and median (bar), one panel
per part, with the floor of the true calibration (and, for the simulation, the Cramer-Rao-type
floor of a calibration that knows the attitude). ``heading_vs_J.png``: heading RMS against
the magnitude metric (J where the truth is known, J_r on the recordings as given), with
Spearman's rank correlation. Each PNG has the CSV of what it plots beside it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.figures.style import method_style, new_figure, save_figure

__all__ = ["PART_TITLES", "write_heading_figures"]

PART_TITLES = {"mc": "simulated (0-10 deg mounting, lag)",
               "semi": "BROAD + known distortion (3 deg mounting)",
               "given": "BROAD as given"}
#: Heading errors are drawn on a log axis between these (degrees); larger ones on the edge.
_RANGE = (0.3, 180.0)


def _ok_rows(trials: pd.DataFrame) -> pd.DataFrame:
    ok = trials[trials["ok"].astype(bool) & np.isfinite(trials["heading_rms"])].copy()
    ok["dataset"] = ok["dataset"].astype(object).fillna("")
    return ok


def _order(ok: pd.DataFrame) -> list[str]:
    """Methods by median heading RMS on the semi-synthetic part (else any part), best first."""
    key = "semi" if (ok["part"] == "semi").any() else ok["part"].iloc[0]
    med = ok[ok["part"] == key].groupby("algorithm")["heading_rms"].median()
    rest = [n for n in dict.fromkeys(ok["algorithm"]) if n not in med.index]
    return list(med.sort_values().index) + rest


def _error_panel(ax, part_rows: pd.DataFrame, names: list[str], part: str) -> None:
    rng = np.random.default_rng(0)     # jitter only, same picture every time
    for i, name in enumerate(names):
        values = part_rows.loc[part_rows["algorithm"] == name, "heading_rms"].to_numpy()
        if not values.size:
            continue
        style = method_style(name)
        shown = np.clip(values, *_RANGE)
        ax.plot(shown, i + rng.uniform(-0.18, 0.18, values.size), linestyle="none",
                marker=style["marker"], color=style["color"], markersize=3.5, alpha=0.7)
        ax.plot([np.median(shown)] * 2, [i - 0.35, i + 0.35], color=style["color"],
                linewidth=2.2)
    floor = part_rows["heading_floor"].median()
    if np.isfinite(floor):
        ax.axvline(floor, color="0.3", linestyle="--", linewidth=1,
                   label="true calibration" if part != "given" else "as given")
    crb = part_rows["crb_heading"].median()
    if np.isfinite(crb):
        ax.axvline(crb, color="0.3", linestyle=":", linewidth=1.2,
                   label="floor with attitude known")
    ax.set_xscale("log")
    ax.set_xlim(*_RANGE)
    ax.set_title(PART_TITLES.get(part, part), fontsize=9, loc="left")
    ax.set_xlabel("heading error, RMS over movement (deg)")
    ax.grid(True, axis="x", which="both", alpha=0.25)
    ax.legend(fontsize=7, loc="lower right")


def heading_error_figure(trials: pd.DataFrame, out_dir: Path) -> Path:
    """``heading_error.png`` and ``heading_error.csv`` (one row per point drawn)."""
    ok = _ok_rows(trials)
    write_csv_atomic(ok[["part", "dataset", "distortion", "trial", "algorithm", "heading_rms",
                         "heading_floor", "crb_heading"]], out_dir / "heading_error.csv")
    parts = [p for p in PART_TITLES if (ok["part"] == p).any()]
    names = _order(ok)
    fig = new_figure(4.2 * len(parts) + 1.8, 0.26 * len(names) + 1.6)
    axes = fig.subplots(1, len(parts), sharey=True, squeeze=False)[0]
    for ax, part in zip(axes, parts, strict=True):
        _error_panel(ax, ok[ok["part"] == part], names, part)
    axes[0].set_yticks(range(len(names)), [method_style(n)["label"] for n in names],
                       fontsize=8)
    axes[0].set_ylim(len(names) - 0.5, -0.5)
    fig.suptitle("Heading error per method (points: units; bars: medians; edge: beyond "
                 f"{_RANGE[1]:g} deg or below {_RANGE[0]:g})", fontsize=10)
    return save_figure(fig, out_dir / "heading_error.png")


def _x_limits(values: np.ndarray) -> tuple[float, float]:
    """A log range spanning the 2nd to 98th percentile of the positive values (times 3 either
    way), at most three decades either side of the median: a few diverged fits (J of 1e30)
    must not squeeze every other point into a line."""
    v = values[np.isfinite(values) & (values > 0)]
    if not v.size:
        return 1e-3, 1.0
    median = float(np.median(v))
    return (max(float(np.percentile(v, 2)) / 3.0, median / 1e3),
            min(float(np.percentile(v, 98)) * 3.0, median * 1e3))


def _scatter_panel(ax, rows: pd.DataFrame, metric: str, rho: float, title: str) -> None:
    low, high = _x_limits(rows[metric].to_numpy(dtype=float))
    for name in dict.fromkeys(rows["algorithm"]):
        sub = rows[rows["algorithm"] == name]
        style = method_style(name)
        ax.plot(np.clip(sub[metric], low, high), np.clip(sub["heading_rms"], *_RANGE),
                linestyle="none", marker=style["marker"], color=style["color"], markersize=4,
                alpha=0.75, label=style["label"])
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(low / 1.3, high * 1.3)
    ax.set_ylim(*_RANGE)
    ax.set_xlabel("J (eq. 74)" if metric == "J" else "J_r (eq. 81)")
    ax.set_title(f"{title}\nSpearman rho = {rho:.2f} (pooled)", fontsize=9, loc="left")
    ax.grid(True, which="major", alpha=0.25)


def heading_vs_J_figure(trials: pd.DataFrame, corr: pd.DataFrame, out_dir: Path) -> Path:
    """``heading_vs_J.png`` and ``heading_vs_J.csv``: heading RMS against J (simulation and
    semi-synthetic) and J_r (as given)."""
    ok = _ok_rows(trials)
    panels = [(p, "J" if p != "given" else "J_r") for p in PART_TITLES
              if (ok["part"] == p).any()]
    panels = [(p, m) for p, m in panels if np.isfinite(ok.loc[ok["part"] == p, m]).any()]
    plotted = pd.concat([ok.loc[ok["part"] == p, ["part", "dataset", "algorithm",
                                                  "heading_rms"]].assign(metric=m,
                                                                         value=ok[m])
                         for p, m in panels], ignore_index=True) if panels else pd.DataFrame()
    write_csv_atomic(plotted, out_dir / "heading_vs_J.csv")
    fig = new_figure(4.0 * max(len(panels), 1) + 2.4, 4.2)
    axes = fig.subplots(1, max(len(panels), 1), sharey=True, squeeze=False)[0]
    for ax, (part, metric) in zip(axes, panels, strict=False):
        sel = corr[(corr["part"] == part)]
        pooled = sel[sel["dataset"] == "pooled"]
        row = pooled if len(pooled) else sel
        rho = float(row[f"spearman_{metric}"].iloc[0]) if len(row) else np.nan
        _scatter_panel(ax, ok[ok["part"] == part], metric, rho, PART_TITLES[part])
    axes[0].set_ylabel("heading error, RMS (deg)")
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, fontsize=7, loc="outside right center")
    fig.suptitle("Is the magnitude metric a proxy for the heading? (values beyond the axes "
                 "drawn on their edges)", fontsize=10)
    return save_figure(fig, out_dir / "heading_vs_J.png")


def write_heading_figures(out_dir: Path | str) -> list[Path]:
    """Both figures from ``<out_dir>/heading_trials.csv`` and ``correlation.csv``."""
    out_dir = Path(out_dir)
    trials = pd.read_csv(out_dir / "heading_trials.csv")
    corr = pd.read_csv(out_dir / "correlation.csv")
    if not _ok_rows(trials).shape[0]:
        return []
    return [heading_error_figure(trials, out_dir), heading_vs_J_figure(trials, corr, out_dir)]
