"""The gyro sweep's figure: median J against gyro noise, one panel per coverage."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.figures.style import method_style, new_figure, save_figure
from magbench.methods.registry import get_method, methods

__all__ = ["figure_table", "write_gyro_figure"]


def figure_table(summary: pd.DataFrame) -> pd.DataFrame:
    """What the figure plots: median J per coverage, gyro noise and algorithm."""
    return summary[["coverage", "gyro_noise", "algorithm", "median_J", "RB_pct"]].copy()


def write_gyro_figure(summary: pd.DataFrame, out_dir: Path | str) -> Path:
    """``gyro_J.png`` (median J against gyro noise, one panel per coverage) and
    ``gyro_J.csv``, the numbers plotted.

    Two rows, each with its own y axis: the gyro-aided methods on top, the magnetometer-only
    methods (same samples; they ignore the gyro, so their lines are flat) below. The gyro noise
    levels are drawn at even positions labelled with their values, so a zero level needs no
    place on a log axis.
    """
    out_dir = Path(out_dir)
    table = figure_table(summary)
    write_csv_atomic(table, out_dir / "gyro_J.csv")
    coverages = list(dict.fromkeys(table["coverage"]))
    levels = sorted(table["gyro_noise"].unique())
    position = {g: i for i, g in enumerate(levels)}
    gyro = {m for m in methods() if get_method(m).needs_gyro}
    fig = new_figure(4.2 * len(coverages) + 3.4, 7.8)
    axes = fig.subplots(2, len(coverages), squeeze=False, sharey="row")
    for row, title in enumerate(["gyro-aided", "magnetometer only"]):
        for ax, cov in zip(axes[row], coverages, strict=True):
            sub = table[table["coverage"] == cov]
            names = [n for n in dict.fromkeys(sub["algorithm"]) if (n in gyro) == (row == 0)]
            for name in names:
                grp = sub[sub["algorithm"] == name].sort_values("gyro_noise")
                ax.plot([position[g] for g in grp["gyro_noise"]], grp["median_J"],
                        **method_style(name))
            ax.set_yscale("log")
            ax.set_xticks(range(len(levels)), [f"{g:g}" for g in levels])
            ax.set_xlim(-0.3, len(levels) - 0.7)
            ax.set_title(f"{title}, coverage: {cov}", fontsize=10)
            ax.set_xlabel("gyro noise std (rad/s)")
            ax.grid(True, which="major", alpha=0.3)
        axes[row][0].set_ylabel("median J (74)")
        if axes[row][-1].get_legend_handles_labels()[0]:
            axes[row][-1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.suptitle("Gyro-aided calibration on simulated manoeuvres")
    return save_figure(fig, out_dir / "gyro_J.png")
