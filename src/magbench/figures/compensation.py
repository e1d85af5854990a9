"""The compensation sweep's figure: field error and J against the disturbance strength."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.figures.style import method_style, new_figure, save_figure

__all__ = ["write_compensation_figures"]

#: Line style of each variant (the colour is the method's).
VARIANT_STYLE = {"static": {"linestyle": "-", "marker": "o"},
                 "compensated": {"linestyle": "--", "marker": "s"},
                 "selected": {"linestyle": ":", "marker": "^"}}


def write_compensation_figures(out_dir: Path | str) -> list[Path]:
    """``compensation.png`` (median held-out field error and median J against the disturbance
    strength, static, compensated and selected per method) and ``compensation.csv``, the
    numbers plotted; from ``summary.csv`` alone. Strengths are categories at even positions
    (a zero strength needs no place on a log axis)."""
    out_dir = Path(out_dir)
    path = out_dir / "summary.csv"
    if not path.exists():
        return []
    summary = pd.read_csv(path)
    table = summary[["strength", "algorithm", "variant", "median_field_err_pct", "median_J",
                     "kept_pct"]]
    write_csv_atomic(table, out_dir / "compensation.csv")
    levels = sorted(table["strength"].unique())
    position = {s: i for i, s in enumerate(levels)}
    fig = new_figure(11.5, 4.6)
    axes = fig.subplots(1, 2)
    panels = [("median_field_err_pct", "(a) field magnitude error on fresh samples",
               "median RMS of |m| - 1 (%)"),
              ("median_J", "(b) accuracy of T and h", "median J (74)")]
    for ax, (column, title, ylabel) in zip(axes, panels, strict=True):
        for (name, variant), grp in table.groupby(["algorithm", "variant"], sort=False):
            grp = grp.sort_values("strength")
            style = dict(method_style(name))
            style.update(VARIANT_STYLE[variant])
            style["label"] = f"{style['label']}, {variant}"
            ax.plot([position[s] for s in grp["strength"]], grp[column].to_numpy(float),
                    **style)
        ax.set_yscale("log")
        ax.set_xticks(range(len(levels)), [f"{s:g}" for s in levels])
        ax.set_xlabel("disturbance |C| at full current (field = 1)")
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=10, loc="left")
        ax.grid(True, which="major", alpha=0.3)
    kept = table[table["variant"] == "selected"].groupby("strength")["kept_pct"].mean()
    axes[0].text(0.02, 0.98, "terms kept (selected): " + ", ".join(
        f"{kept[s]:.0f} %" for s in levels if s in kept.index),
        transform=axes[0].transAxes, va="top", fontsize=7, color="0.25")
    axes[1].text(0.02, 0.98, "compensated fits of different methods end at the same joint "
                 "fit\n(their lines coincide)", transform=axes[1].transAxes, va="top",
                 fontsize=7, color="0.25")
    axes[1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.suptitle("Current-proportional disturbance: static against compensated calibration")
    if not np.isfinite(table["median_J"]).any():
        axes[1].set_yscale("linear")
    return [save_figure(fig, out_dir / "compensation.png")]
