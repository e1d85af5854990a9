"""Figure of the generalisation study, from ``generalisation_cases.csv`` alone.

(a) the regret of ``calibrate``'s choice per case (its held-out spread, raw when it wrote
nothing, minus the best fixed method's), by protocol; (b) losses per protocol (worse than the
best fixed method in hindsight by more than max(0.25 points, 5 %)) of ``calibrate``, of the
best of its eligible candidates in hindsight (what a perfect ranking would lose, when the
cases carry ``oracle_pct``), of each recording's best fixed fit in hindsight (what any one
method per recording would lose at best, when they carry ``loss_recording_best``), beside
always using one fixed method or one peer.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from magbench.figures.style import method_style, new_figure

__all__ = ["ORACLE", "POLICIES", "RECORDING_BEST", "generalisation_figure",
           "losses_by_protocol"]

#: The fixed methods and peers drawn beside ``calibrate`` in panel (b), when present.
POLICIES = ("sphere", "ellipsoid", "fang", "wu_shi_nm", "navlib.cal_mag_sphere_fit",
            "navlib.cal_mag_ellipsoid_fit_fang", "magcal.ellipsoid_fit")
#: calibrate's colour: not a method's, the same in every figure of this study.
AUTO_COLOUR = "#BB5566"
#: The bar of calibrate's best eligible candidate in hindsight.
ORACLE = "calibrate's best eligible fit in hindsight"
#: The bar of each recording's one best fixed method in hindsight.
RECORDING_BEST = "each recording's best fixed fit in hindsight"


def _tolerance(best: np.ndarray) -> np.ndarray:
    return np.maximum(0.25, 0.05 * best)


def losses_by_protocol(cases: pd.DataFrame) -> pd.DataFrame:
    """Losses of ``calibrate``, of the bounds (:data:`ORACLE`, :data:`RECORDING_BEST`) and of
    each policy of :data:`POLICIES` present, per protocol (rows) and entrant (columns)."""
    best = cases["best_fixed_pct"].to_numpy(float)

    def beyond(score: np.ndarray) -> np.ndarray:
        return score > best + _tolerance(best)

    lost = {"calibrate": beyond(cases["auto_pct"].to_numpy(float))}
    if "oracle_pct" in cases:
        lost[ORACLE] = beyond(cases["oracle_pct"].to_numpy(float))
    if "loss_recording_best" in cases:
        lost[RECORDING_BEST] = cases["loss_recording_best"].astype(bool).to_numpy()
    lost |= {p: beyond(cases[f"pct:{p}"].to_numpy(float)) for p in POLICIES
             if f"pct:{p}" in cases}
    protocols = list(dict.fromkeys(cases["protocol"]))
    out = {name: [int(flags[(cases["protocol"] == p).to_numpy()].sum()) for p in protocols]
           for name, flags in lost.items()}
    return pd.DataFrame(out, index=protocols)


def _label(name: str) -> str:
    return name if "." in name or name in ("calibrate", ORACLE, RECORDING_BEST) \
        else str(method_style(name)["label"])


def _style(name: str) -> tuple[str, str]:
    if name == "calibrate":
        return AUTO_COLOUR, ""
    if name == RECORDING_BEST:          # hollow grey: not an entrant, a bound on any one fit
        return "#555555", "xx"
    if name == ORACLE:                  # hollow: not an entrant, a bound on the ranking
        return AUTO_COLOUR, ".."
    if "." in name:                     # a peer: its paired method's colour, hollow bars
        base = {"navlib.cal_mag_sphere_fit": "sphere", "navlib.cal_mag_ellipsoid_fit_fang":
                "fang", "magcal.ellipsoid_fit": "ellipsoid"}.get(name, "sphere")
        return str(method_style(base)["color"]), "//"
    return str(method_style(name)["color"]), ""


def generalisation_figure(cases: pd.DataFrame) -> Figure:
    """Panels (a) and (b) of the module notes; n per protocol on the x axis."""
    protocols = list(dict.fromkeys(cases["protocol"]))
    n = {p: int((cases["protocol"] == p).sum()) for p in protocols}
    fig = new_figure(11, 7.8)
    ax_a, ax_b = fig.subplots(2, 1)
    x = np.arange(len(protocols))
    ticks = [f"{p}\n(n={n[p]})" for p in protocols]
    gen = np.random.default_rng(0)       # jitter only: no result depends on it
    for i, p in enumerate(protocols):
        g = cases[cases["protocol"] == p]
        regret = g["regret"].to_numpy(float)
        written = g["written"].astype(bool).to_numpy()
        jitter = gen.uniform(-0.25, 0.25, len(g))
        ax_a.scatter(i + jitter[written], regret[written], s=22, color=AUTO_COLOUR,
                     marker="o", label="written (PASS, WARN)" if i == 0 else None, zorder=3)
        ax_a.scatter(i + jitter[~written], regret[~written], s=30, color="#222222",
                     marker="x", label="not written (FAIL: the user keeps raw data)"
                     if i == 0 else None, zorder=3)
    ax_a.axhline(0.0, color="#777777", lw=0.8)
    ax_a.axhline(0.25, color="#777777", lw=0.8, ls="--",
                 label="tolerance: 0.25 points (or 5 %)")
    ax_a.set_yscale("symlog", linthresh=1.0)
    ax_a.set_yticks([-10, -1, 0, 1, 10], ["-10", "-1", "0", "1", "10"])
    ax_a.set_xticks(x, ticks)
    ax_a.set_ylabel("regret, points of held-out spread\n(calibrate - best fixed in hindsight)")
    ax_a.set_title("(a) calibrate against the best fixed method in hindsight, per case",
                   loc="left")
    # a decade and more of headroom above the largest regret holds the legend, which hid
    # the first protocol's points inside the data's own range
    finite = cases["regret"].to_numpy(float)
    finite = finite[np.isfinite(finite)]
    top = max(10.0, float(finite.max()) if finite.size else 10.0)
    bottom = min(-10.0, float(finite.min()) if finite.size else -10.0)
    ax_a.set_ylim(1.5 * bottom, 30 * top)
    ax_a.legend(fontsize=8, ncol=3, loc="upper left")
    losses = losses_by_protocol(cases)
    width = 0.8 / max(1, losses.shape[1])
    for j, name in enumerate(losses.columns):
        colour, hatch = _style(name)
        ax_b.bar(x - 0.4 + width * (j + 0.5), losses[name].to_numpy(), width,
                 color="white" if hatch else colour, edgecolor=colour, hatch=hatch or None,
                 label=f"{_label(name)} ({int(losses[name].sum())} in all)")
    ax_b.set_xticks(x, ticks)
    ax_b.set_ylabel("losses (cases)")
    ax_b.set_title("(b) losses per protocol: calibrate beside always using one fit",
                   loc="left")
    ax_b.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.22))
    return fig
