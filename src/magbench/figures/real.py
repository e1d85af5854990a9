"""Figures of the real-data part: Figure 6 and the before/after picture of ``calibrate``.

Both take data frames or arrays that were computed elsewhere; nothing here calibrates.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from magbench.figures.style import new_figure

__all__ = ["calibration_picture", "figure6"]

_COLOURS = {"none": "#9e9e9e", "scale": "#4c72b0", "centre": "#dd8452"}


def _bars(ax, per_method: pd.DataFrame, order: list[str], column: str, hatch_out: str = ""):
    hows = list(dict.fromkeys(per_method["preprocess"]))
    cols = [column] if isinstance(column, str) else column
    n = len(hows) * len(cols)
    width = 0.8 / n
    x = np.arange(len(order))
    k = 0
    for how in hows:
        g = per_method[per_method["preprocess"] == how].set_index("algorithm").reindex(order)
        for col in cols:
            out = col.endswith("_out")
            ax.bar(x - 0.4 + width * (k + 0.5), g[col].to_numpy(dtype=float), width,
                   color=_COLOURS.get(how, None), alpha=0.55 if out else 1.0,
                   hatch=hatch_out if out else "", edgecolor="black", linewidth=0.4,
                   label=f"{how}" + (", out of sample" if out else
                                     (", in sample" if len(cols) > 1 else "")))
            k += 1
    return x


def figure6(per_method: pd.DataFrame, per_recording: pd.DataFrame | None = None) -> Figure:
    """Figure 6 of the review on the real recordings.

    (a) accuracy ``1 / mean J_r`` in and out of sample per method and preprocessing (log
    scale); (b) robustness RB %; (c) when ``per_recording`` is given, J_r in sample over the
    sphere fit's J_r per recording and method (log10; blank = not meaningful or skipped).
    """
    labels = dict(zip(per_method["algorithm"], per_method["label"], strict=False))
    order = list(dict.fromkeys(per_method["algorithm"]))
    rows = 3 if per_recording is not None else 2
    fig = new_figure(max(9.0, 0.55 * len(order) + 3), 4.2 * rows)
    grid = fig.add_gridspec(rows, len(set(per_method["preprocess"])) if rows == 3 else 1)
    ax_a = fig.add_subplot(grid[0, :])
    x = _bars(ax_a, per_method, order, ["accuracy_in", "accuracy_out"], hatch_out="//")
    ax_a.set_yscale("log")
    ax_a.set_ylabel("accuracy 1 / J_r (81)")
    ax_a.set_title("(a) Accuracy on real recordings (mean J_r over meaningful fits)")
    ax_a.set_xticks(x, [labels[a] for a in order], rotation=45, ha="right")
    # Above the axes, so the legend never covers a bar.
    ax_a.legend(fontsize=8, ncols=4, loc="lower center", bbox_to_anchor=(0.5, 1.1),
                frameon=False)
    ax_b = fig.add_subplot(grid[1, :])
    _bars(ax_b, per_method, order, "RB_pct")
    ax_b.set_ylim(0, 105)
    ax_b.set_ylabel("RB (%)")
    ax_b.set_title("(b) Robustness: share of recordings with a meaningful fit")
    ax_b.set_xticks(x, [labels[a] for a in order], rotation=45, ha="right")
    ax_b.legend(fontsize=8, ncols=2, loc="lower center", bbox_to_anchor=(0.5, 1.1),
                frameon=False)
    if per_recording is not None:
        hows = list(dict.fromkeys(per_method["preprocess"]))
        for i, how in enumerate(hows):
            g = per_recording[per_recording["preprocess"] == how]
            ratio = np.log10(g["J_r_in"] / g["J_r_sphere_in"]).where(
                g["meaningful"].astype(bool))
            table = (g.assign(ratio=ratio)
                     .pivot(index="dataset", columns="algorithm", values="ratio")
                     .reindex(columns=order).reindex(index=list(dict.fromkeys(g["dataset"]))))
            ax = fig.add_subplot(grid[2, i])
            image = ax.imshow(table.to_numpy(dtype=float), aspect="auto", cmap="viridis",
                              vmin=-4, vmax=0)
            ax.set_xticks(range(len(order)), [labels[a] for a in order], rotation=90,
                          fontsize=6)
            ax.set_yticks(range(len(table.index)), table.index, fontsize=6)
            ax.set_title(f"(c) log10 J_r / J_r(sphere fit), preprocessing '{how}'", fontsize=9)
        fig.colorbar(image, ax=fig.axes[-len(hows):], shrink=0.8,
                     label="log10 ratio (blank: not meaningful)")
    fig.suptitle("Figure 6 on public real recordings (review section 10.2)")
    return fig


def calibration_picture(before: np.ndarray, after: np.ndarray, title: str = "") -> Figure:
    """The three 2-D projections of the data before and after calibration, with unit circles.

    ``before`` should already be scaled to unit mean norm, so both rows share the unit circle
    as reference: a good calibration puts the points of every projection inside the circle and
    the outermost ones on it (a sphere's projection is a filled disc).
    """
    fig = new_figure(11, 7.5)
    axes = fig.subplots(2, 3)
    circle = np.linspace(0, 2 * np.pi, 361)
    pairs = [(0, 1, "x", "y"), (0, 2, "x", "z"), (1, 2, "y", "z")]
    for row, (data, what) in enumerate([(before, "before (scaled to unit mean norm)"),
                                        (after, "after: m = T^-1 (y - h)")]):
        lim = max(1.2, 1.05 * float(np.abs(data).max()))
        for col, (i, j, a, b) in enumerate(pairs):
            ax = axes[row, col]
            ax.plot(np.cos(circle), np.sin(circle), color="crimson", lw=1.0, label="unit circle")
            ax.scatter(data[:, i], data[:, j], s=3, alpha=0.5, color="#4c72b0", lw=0)
            ax.plot([0], [0], "+", color="black")
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            ax.set_aspect("equal")
            ax.set_xlabel(a)
            ax.set_ylabel(b)
            ax.set_title(f"{what}: {a}-{b}", fontsize=9)
    axes[0, 0].legend(fontsize=8, loc="upper right")
    if title:
        fig.suptitle(title)
    return fig
