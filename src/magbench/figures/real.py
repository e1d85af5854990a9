"""Figures of the real-data part: Figure 6 and the before/after picture of ``calibrate``.

Both take data frames or arrays that were computed elsewhere; nothing here calibrates.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from magbench.core.intervals import wilson
from magbench.figures.style import method_style, new_figure
from magbench.studies.real import selection_inflation

__all__ = ["figure6", "figure6_recordings", "split_methods"]

#: The review's seven methods, in its order (the paper's Figure 6 shows these).
REVIEW = ("twostep", "crassidis", "dorveaux", "vasconcelos", "ali", "wu_shi", "magical")
#: How each preprocessing is drawn: the review's scaling solid, centring hatched and lighter.
_PREPROCESS = {"scale": ("", 1.0, "scaled by the mean norm (the review's)"),
               "centre": ("///", 0.45, "centred and scaled by the sphere fit first"),
               "none": ("..", 0.3, "as recorded")}


def split_methods(per_method: pd.DataFrame) -> tuple[list[str], list[str], list[str]]:
    """(the review's methods, the others, those left out) in the order of ``per_method``.

    A method is left out when no recording gave it a meaningful fit under any preprocessing:
    it would be an empty column in every panel; the figure names it in a note instead.
    """
    order = list(dict.fromkeys(per_method["algorithm"]))
    useful = set(per_method.loc[per_method["n_meaningful"] > 0, "algorithm"])
    left_out = [n for n in order if n not in useful]
    review = [n for n in REVIEW if n in useful]
    others = [n for n in order if n in useful and n not in REVIEW]
    return review, others, left_out


def _short(name: str, per_method: pd.DataFrame) -> str:
    """A tick label: the printed-formula variants shortened, and the number of recordings
    where a method applies to fewer than the others (the gyro-aided ones)."""
    label = (method_style(name)["label"].replace("review's printed ", "printed ")
             .replace(" (40)-(43)", "").replace(" (57)", ""))
    n = per_method.loc[per_method["algorithm"] == name, "n_applicable"].max()
    most = per_method["n_applicable"].max()
    return label + (f" ({int(n)} rec.)" if np.isfinite(n) and n < most else "")


def _flag_selection(ax, x: np.ndarray, values: np.ndarray, width: float, names: list[str],
                    flags: pd.DataFrame) -> None:
    """Cross-hatch the bars whose value is set by which recordings the method kept, and mark
    the other review methods' accuracy on the same recordings (a black bar)."""
    flagged = flags.loc[flags["set_by_selection"].astype(bool)]
    flagged = flagged.set_index("algorithm").reindex(names)
    hit = flagged["set_by_selection"].eq(True).to_numpy()
    if not hit.any():
        return
    ax.bar(x[hit], values[hit], width, fill=False, hatch="xxx", edgecolor="crimson",
           linewidth=0.8)
    ax.hlines(flagged["others_on_kept"].to_numpy(float)[hit], x[hit] - width / 2,
              x[hit] + width / 2, colors="black", linewidth=2.5)


def _panel(ax, per_method: pd.DataFrame, names: list[str], column: str,
           flags: pd.DataFrame | None = None) -> None:
    hows = [h for h in _PREPROCESS if h in set(per_method["preprocess"])]
    width = 0.8 / max(len(hows), 1)
    x = np.arange(len(names))
    for k, how in enumerate(hows):
        g = per_method[per_method["preprocess"] == how].set_index("algorithm").reindex(names)
        hatch, alpha, _ = _PREPROCESS[how]
        offset = -0.4 + width * (k + 0.5)
        colours = [method_style(n)["color"] for n in names]
        values = g[column].to_numpy(dtype=float)
        ax.bar(x + offset, values, width, color=colours, alpha=alpha, hatch=hatch,
               edgecolor="black", linewidth=0.5)
        if flags is not None:
            _flag_selection(ax, x + offset, values, width, names,
                            flags[flags["preprocess"] == how])
        if column == "RB_pct":
            # Wilson 95 % interval of each share (n = recordings the method applies to).
            bounds = np.array([wilson(int(r.n_meaningful), int(r.n_applicable))
                               if np.isfinite(r.n_applicable) else (np.nan, np.nan)
                               for r in g[["n_meaningful", "n_applicable"]].itertuples()])
            ax.errorbar(x + offset, values, yerr=[values - bounds[:, 0], bounds[:, 1] - values],
                        fmt="none", ecolor="black", elinewidth=0.8, capsize=2)
    ax.set_xticks(x, [_short(n, per_method) for n in names], fontsize=9)
    ax.set_xlim(-0.6, len(names) - 0.4)
    ax.grid(True, axis="y", which="major", alpha=0.3)


def figure6(per_method: pd.DataFrame, per_recording: pd.DataFrame | None = None) -> Figure:
    """Figure 6 of the review on the real recordings, in the paper's layout.

    Top row, the review's seven methods as in the paper: (a) accuracy ``1 / mean J_r`` (81) in
    sample over the meaningful fits, (b) robustness RB % with its Wilson 95 % interval. Bottom
    row, (c) and (d), the same for every other method that gave a meaningful fit. Each method
    keeps its colour of every figure; the review's scaling is a solid bar, centring a hatched
    one. The accuracy axis spans the values drawn (not the out-of-sample extremes, which are
    in the report's table). With ``per_recording``, an accuracy bar set by which recordings
    the method kept (:func:`magbench.studies.real.selection_inflation`) is cross-hatched in
    red, with a black bar at the other review methods' accuracy on the same recordings.
    """
    review, others, left_out = split_methods(per_method)
    rows = [(names, what) for names, what in ((review, "the review's methods (its Figure 6)"),
                                              (others, "the other methods")) if names]
    if not rows:
        fig = new_figure(8, 3)
        fig.text(0.5, 0.5, "No method gave a meaningful fit on any recording: "
                 + ", ".join(method_style(n)["label"] for n in left_out),
                 ha="center", va="center", wrap=True)
        return fig
    fig = new_figure(max(11.0, 0.62 * max(len(review), len(others)) + 4.5), 4.3 * len(rows))
    grid = fig.add_gridspec(len(rows), 2, width_ratios=[1, 1])
    letters = iter("abcdef")
    accuracy = per_method.loc[per_method["algorithm"].isin(review + others), "accuracy_in"]
    accuracy = accuracy[np.isfinite(accuracy) & (accuracy > 0)]
    lo, hi = (10 ** np.floor(np.log10(accuracy.min())), 10 ** np.ceil(np.log10(accuracy.max()))
              ) if len(accuracy) else (1e-1, 1e1)
    flags = None if per_recording is None else selection_inflation(per_recording)
    for i, (names, what) in enumerate(rows):
        ax_a = fig.add_subplot(grid[i, 0])
        _panel(ax_a, per_method, names, "accuracy_in", flags)
        ax_a.set_yscale("log")
        ax_a.set_ylim(lo, hi)
        ax_a.set_ylabel("accuracy 1 / mean J_r (81)")
        ax_a.set_title(f"({next(letters)}) Accuracy in sample, {what}", loc="left", fontsize=10)
        ax_b = fig.add_subplot(grid[i, 1])
        _panel(ax_b, per_method, names, "RB_pct")
        ax_b.set_ylim(0, 105)
        ax_b.set_ylabel("RB (%), bars: Wilson 95 %")
        ax_b.set_title(f"({next(letters)}) Robustness, {what}", loc="left", fontsize=10)
        for ax in (ax_a, ax_b):
            for tick in ax.get_xticklabels():
                tick.set_rotation(30 if len(names) > 7 else 0)
                tick.set_ha("right" if len(names) > 7 else "center")
    handles = _legend_handles(per_method, flags)
    n_rec = int(per_method["n_recordings"].max()) if "n_recordings" in per_method else None
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 3),
               fontsize=9, frameon=False)
    note = ("; not shown (no meaningful fit on any recording): "
            + ", ".join(method_style(n)["label"] for n in left_out)) if left_out else ""
    fig.suptitle("Figure 6 on public real recordings (review section 10.2)"
                 + (f", {n_rec} recordings" if n_rec else "") + note, fontsize=11)
    return fig


def _legend_handles(per_method: pd.DataFrame, flags: pd.DataFrame | None) -> list:
    """The preprocessings' bar styles, and the selection flag's when a bar carries it."""
    hows = [h for h in _PREPROCESS if h in set(per_method["preprocess"])]
    handles = [Patch(facecolor="0.55", alpha=_PREPROCESS[h][1], hatch=_PREPROCESS[h][0],
                     edgecolor="black", label=_PREPROCESS[h][2]) for h in hows]
    if flags is not None and flags["set_by_selection"].astype(bool).any():
        handles += [Patch(fill=False, hatch="xxx", edgecolor="crimson",
                          label="set by which recordings were kept"),
                    Line2D([], [], color="black", linewidth=2.5,
                           label="other review methods on the same recordings")]
    return handles


def figure6_recordings(per_method: pd.DataFrame, per_recording: pd.DataFrame) -> Figure:
    """Per recording and method, ``log10`` of J_r in sample over the sphere fit's J_r, one
    panel per preprocessing (blank: not meaningful, or the method does not apply).

    Methods with no meaningful fit anywhere are left out (as in :func:`figure6`).
    """
    review, others, _ = split_methods(per_method)
    order = review + others or list(dict.fromkeys(per_method["algorithm"]))
    hows = list(dict.fromkeys(per_method["preprocess"]))
    datasets = list(dict.fromkeys(per_recording["dataset"]))
    fig = new_figure(6.2 * len(hows) + 1.5, 0.26 * len(datasets) + 3.2)
    axes = fig.subplots(1, len(hows), squeeze=False, sharey=True)[0]
    image = None
    for ax, how, letter in zip(axes, hows, "abcdef", strict=False):
        g = per_recording[per_recording["preprocess"] == how]
        with np.errstate(divide="ignore"):       # a degenerate J_r of 0: masked, not meaningful
            ratio = np.log10(g["J_r_in"] / g["J_r_sphere_in"]).where(
                g["meaningful"].astype(bool))
        table = (g.assign(ratio=ratio).pivot(index="dataset", columns="algorithm",
                                             values="ratio")
                 .reindex(columns=order).reindex(index=datasets))
        image = ax.imshow(table.to_numpy(dtype=float), aspect="auto", cmap="viridis",
                          vmin=-4, vmax=1)
        ax.set_xticks(range(len(order)), [_short(a, per_method) for a in order], rotation=60,
                      ha="right", fontsize=8)
        ax.set_yticks(range(len(datasets)), datasets, fontsize=8)
        ax.axvline(len(review) - 0.5, color="white", linewidth=2)
        ax.set_title(f"({letter}) preprocessing '{how}'", loc="left", fontsize=10)
    if image is not None:
        fig.colorbar(image, ax=list(axes), shrink=0.8,
                     label="log10 J_r / J_r(sphere fit), in sample (blank: not meaningful)")
    fig.suptitle("Real recordings, per recording (left of the white line: the review's "
                 "methods)", fontsize=11)
    return fig
