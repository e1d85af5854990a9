"""The gyro sweep's figure: median J against gyro noise, one panel per coverage."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.figures.style import method_style, new_figure, save_figure
from magbench.methods.registry import get_method, methods

__all__ = ["figure_table", "write_gyro_figure"]


def figure_table(summary: pd.DataFrame) -> pd.DataFrame:
    """What the figure plots: median J per coverage, gyro noise and algorithm, with the runs
    behind each point (``n``, and ``n_ok`` when the summary has it)."""
    cols = ["coverage", "gyro_noise", "algorithm", "median_J", "RB_pct", "n", "n_ok"]
    return summary[[c for c in cols if c in summary]].copy()


#: Median J above this is off the scale of the figure (J_0 of the trivial answer is about 1
#: here): such a point is drawn on the top edge and listed with its value in the panel.
OFF_SCALE_J = 5.0


def write_gyro_figure(summary: pd.DataFrame, out_dir: Path | str) -> Path:
    """``gyro_J.png`` (median J against gyro noise, one panel per coverage) and
    ``gyro_J.csv``, the numbers plotted.

    Two rows: the gyro-aided methods on top, the magnetometer-only methods below. These ignore
    the gyro, and each gyro level has its own datasets: their points are drawn unjoined, with
    a dashed line at their median over the levels, since a swing between levels is sampling
    noise, not an effect. The panels of a row share one y axis, spanning the row's values up
    to :data:`OFF_SCALE_J`; larger medians (a method that
    failed on most runs) sit on the top edge as open triangles and are listed with their values,
    so one failure cannot squeeze every other line into a corner. The gyro noise levels are
    categories at even positions labelled with their values: a zero level needs no place on
    a log axis.
    """
    out_dir = Path(out_dir)
    table = figure_table(summary)
    write_csv_atomic(table, out_dir / "gyro_J.csv")
    coverages = list(dict.fromkeys(table["coverage"]))
    levels = sorted(table["gyro_noise"].unique())
    position = {g: i for i, g in enumerate(levels)}
    gyro = {m for m in methods() if get_method(m).needs_gyro}
    fig = new_figure(4.4 * len(coverages) + 3.6, 8.2)
    axes = fig.subplots(2, len(coverages), squeeze=False)
    letters = iter("abcdefghijkl")
    for row, title in enumerate(["gyro-aided", "magnetometer only"]):
        in_row = table[[(n in gyro) == (row == 0) for n in table["algorithm"]]]["median_J"]
        in_row = in_row[np.isfinite(in_row) & (in_row > 0)]
        top = min(float(in_row.max()) * 1.6, OFF_SCALE_J) if len(in_row) else OFF_SCALE_J
        bottom = float(in_row[in_row <= top].min()) / 1.6 if len(in_row) else 1e-3
        for ax, cov in zip(axes[row], coverages, strict=True):
            sub = table[table["coverage"] == cov]
            names = [n for n in dict.fromkeys(sub["algorithm"]) if (n in gyro) == (row == 0)]
            off = []
            for name in names:
                grp = sub[sub["algorithm"] == name].sort_values("gyro_noise")
                style = method_style(name)
                xs = [position[g] for g in grp["gyro_noise"]]
                ys = grp["median_J"].to_numpy(dtype=float)
                if row == 0:
                    ax.plot(xs, np.minimum(ys, top), **style)
                else:              # no gyro used: unjoined points, their median dashed
                    ax.plot(xs, np.minimum(ys, top), **{**style, "linestyle": "none"})
                    ax.axhline(min(float(np.nanmedian(ys)), top), color=style["color"],
                               linestyle="--", linewidth=1)
                above = ys > top
                if above.any():
                    ax.plot(np.asarray(xs)[above], np.full(above.sum(), top), linestyle="none",
                            marker="^", markersize=9, markerfacecolor="none",
                            markeredgecolor=style["color"], clip_on=False)
                    off.append(f"{style['label']} up to {format(float(ys.max()), '.2g')}")
            ax.set_yscale("log")
            ax.set_ylim(bottom, top)
            ax.set_xticks(range(len(levels)), [f"{g:g}" for g in levels])
            ax.set_xlim(-0.3, len(levels) - 0.7)
            ax.set_title(f"({next(letters)}) {title}, coverage: {cov}", fontsize=10, loc="left")
            ax.set_xlabel("gyro noise std (rad/s)")
            ax.grid(True, which="major", alpha=0.3)
            if off:
                ax.text(0.02, 0.98, "off scale (top edge, open triangles):\n" + "\n".join(off),
                        transform=ax.transAxes, va="top", fontsize=7, color="0.25")
        axes[row][0].set_ylabel("median J (74)")
        if axes[row][-1].get_legend_handles_labels()[0]:
            axes[row][-1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    n = int(table["n"].max()) if "n" in table else None
    fig.suptitle("Gyro-aided calibration on simulated manoeuvres (one scale per row"
                 + (f"; {n} runs per point" if n else "") + "; bottom row: the methods "
                 "ignore the gyro and each level has its own datasets, so their scatter is "
                 "sampling noise)", fontsize=10)
    return save_figure(fig, out_dir / "gyro_J.png")
