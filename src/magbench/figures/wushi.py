"""Wu and Shi's Figures 3, 5 and 6 from the study's CSV files."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.figures.style import method_style, new_figure, save_figure
from magbench.studies.wushi import read_settings

__all__ = ["plot_fig3", "plot_fig5", "plot_fig6", "write_wushi_figures"]


def plot_fig3(history: pd.DataFrame, thresholds: dict, path: Path) -> None:
    """Objective per iteration, one thin line per run, ML and NM side by side."""
    fig = new_figure(10, 4)
    axes = fig.subplots(1, 2)
    units = {"ML": "objective (4), gauss$^2$", "NM": "objective (11), dimensionless"}
    colours = (method_style("wu_shi")["color"], method_style("wu_shi_nm")["color"])
    for ax, short, colour in zip(axes, ("ML", "NM"), colours, strict=True):
        sub = history[history["method"] == short]
        for _, g in sub.groupby("run"):
            ax.plot(g["iteration"], g["objective"], color=colour, lw=0.7, alpha=0.6,
                    marker=".", ms=3)
        ax.axhline(thresholds[short], color="k", ls="--", lw=1,
                   label=f"divergence threshold {thresholds[short]:g} (Fig. 6)")
        n = sub["run"].nunique()
        ax.set_title(f"{short} ({'wu_shi' if short == 'ML' else 'wu_shi_nm'}), {n} runs")
        ax.set_xlabel("Gauss-Newton iteration")
        ax.set_ylabel(units[short])
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_ylim(bottom=0)
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle("Wu & Shi Fig. 3: objective per iteration (N = 300, sigma = 0.003 gauss)")
    save_figure(fig, path)


def plot_fig5(times: pd.DataFrame, claimed: float, path: Path) -> None:
    """Time against N (log-log) and the ML/NM ratio."""
    fig = new_figure(10, 4)
    ax, ax2 = fig.subplots(1, 2)
    ml, nm = method_style("wu_shi"), method_style("wu_shi_nm")
    ax.loglog(times["N"], 1e3 * times["ml_time_s"], **{**ml, "label": "ML (wu_shi)"})
    ax.loglog(times["N"], 1e3 * times["nm_time_s"], **{**nm, "label": "NM (wu_shi_nm)"})
    ax.set_xlabel("number of samples N")
    ax.set_ylabel("median execution time (ms)")
    ax.set_title("execution time (initial estimate + Gauss-Newton)")
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    ax2.semilogx(times["N"], times["ml_over_nm"], "o-", color="tab:green",
                 label="measured ML / NM")
    ax2.plot([1000], [claimed], "r*", ms=12, label=f"paper: about {claimed:g}x at N = 1000")
    ax2.axhline(1.0, color="k", lw=0.8, ls=":")
    ax2.set_xlabel("number of samples N")
    ax2.set_ylabel("time ratio ML / NM")
    ax2.set_title("cost of ML relative to NM")
    ax2.set_ylim(bottom=0)
    ax2.legend()
    ax2.grid(alpha=0.3, which="both")
    fig.suptitle("Wu & Shi Fig. 5: execution time against N")
    save_figure(fig, path)


def plot_fig6(div: pd.DataFrame, path: Path) -> None:
    """Divergences out of the runs against the perturbation alpha."""
    fig = new_figure(6, 4)
    ax = fig.subplots()
    runs = int(div["runs"].max())
    ax.plot(div["alpha_pct"], div["ML_divergences"],
            **{**method_style("wu_shi"), "label": "ML (wu_shi), threshold 0.004"})
    ax.plot(div["alpha_pct"], div["NM_divergences"],
            **{**method_style("wu_shi_nm"), "label": "NM (wu_shi_nm), threshold 0.018"})
    ax.set_xlabel("initial-estimate perturbation alpha (%)")
    ax.set_ylabel(f"number of divergent runs (out of {runs})")
    ax.set_ylim(-0.5, runs + 0.5)
    ax.set_title("Wu & Shi Fig. 6: sensitivity to the initial estimate")
    ax.legend()
    ax.grid(alpha=0.3)
    save_figure(fig, path)


# ----------------------------------------------------------------------------------------
# Report section
# ----------------------------------------------------------------------------------------


def write_wushi_figures(folder: Path | str) -> list[Path]:
    """Draw Figures 3, 5 and 6 from ``fig3_objective.csv``, ``fig5_time.csv``,
    ``fig6_divergence.csv`` and the thresholds and claim of ``settings.csv`` in ``folder``."""
    folder = Path(folder)
    settings = read_settings(folder)
    thresholds = {"ML": float(settings["threshold_ML"]), "NM": float(settings["threshold_NM"])}
    paths = [folder / "fig3_objective.png", folder / "fig5_time.png",
             folder / "fig6_divergence.png"]
    plot_fig3(pd.read_csv(folder / "fig3_objective.csv"), thresholds, paths[0])
    plot_fig5(pd.read_csv(folder / "fig5_time.csv"), float(settings["claimed_ratio"]), paths[1])
    plot_fig6(pd.read_csv(folder / "fig6_divergence.csv"), paths[2])
    return paths
