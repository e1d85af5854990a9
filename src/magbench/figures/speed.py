"""The speed study's figure: time per call against K."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.figures.style import method_style, new_figure, save_figure

__all__ = ["plot_scale", "plot_scaling"]

#: ``scale.csv`` columns drawn by :func:`plot_scale`: (column, label) per panel.
SCALE_TIMES = (("run_s", "sweep (trials, merge)"), ("summarize_s", "summary.csv"),
               ("intervals_s", "bootstrap intervals"))
SCALE_MEMORY = (("peak_rss_mb", "main process"), ("worker_peak_rss_mb", "largest worker"))


def plot_scaling(calls: pd.DataFrame, path: Path) -> Path:
    """Log-log time per call against K, one line per method, with a slope-1 guide."""
    fig = new_figure(8, 5.5)
    ax = fig.subplots()
    for name, g in calls.dropna(subset=["median_s"]).groupby("algorithm", sort=False):
        ax.errorbar(g["K"], g["median_s"] * 1e3,
                    yerr=[(g["median_s"] - g["q25_s"]) * 1e3, (g["q75_s"] - g["median_s"]) * 1e3],
                    capsize=2, **method_style(name))
    K = np.array([calls["K"].min(), calls["K"].max()], dtype=float)
    ax.plot(K, 0.05 * K / K[0], color="0.6", linestyle=":", label="slope 1 (linear in K)")
    ax.set(xscale="log", yscale="log", xlabel="samples per dataset K",
           ylabel="time per calibration call (ms)",
           title="Cost of one calibration call (median, bars: quartiles)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    return save_figure(fig, path)


def plot_scale(scale: pd.DataFrame, path: Path) -> Path:
    """Log-log wall time per phase and peak resident memory against the trials of one sweep
    point (``bench/scale.csv``), each with a slope-1 guide through its first point."""
    fig = new_figure(10, 4.2)
    trials = scale["trials"].to_numpy(float)
    span = np.array([trials.min(), trials.max()])
    for ax, columns, ylabel, title in zip(
            fig.subplots(1, 2), (SCALE_TIMES, SCALE_MEMORY), ("wall time (s)", "peak RSS (MB)"),
            ("(a) time per phase", "(b) peak resident memory"), strict=True):
        for column, label in columns:
            ax.plot(trials, scale[column], marker="o", label=label)
        first = scale[columns[0][0]].iloc[int(np.argmin(trials))]
        ax.plot(span, first * span / span[0], color="0.6", linestyle=":",
                label="slope 1 (linear in trials)")
        ax.set(xscale="log", yscale="log", xlabel="trials (datasets x "
               f"{int(scale['methods'].iloc[0])} methods)", ylabel=ylabel, title=title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(fig, path)
