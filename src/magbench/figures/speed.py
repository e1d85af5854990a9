"""The speed study's figure: time per call against K."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.figures.style import method_style, new_figure, save_figure

__all__ = ["plot_scaling"]


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
