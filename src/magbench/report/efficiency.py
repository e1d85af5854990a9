"""Large K: efficiency (Cramer-Rao bound / MSE) per method and K, from ``largeK/efficiency.csv``.

The adjusted least squares fit (``als``) is consistent for the full model (Kukush, Markovsky
and Van Huffel, CSDA 47 (2004), their consistency theorem); the algebraic ellipsoid fit and
Fang's are ordinary least squares on noisy monomials, biased at any K. With the bias fixed and
the variance shrinking as 1/K, a biased method's efficiency falls as K grows while a
consistent one's stays at 1: the section shows which is which, from the numbers alone.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.methods.registry import method_label
from magbench.report.format import compact_number, format_number, names, render
from magbench.report.intervals import cell, rb_interval, run_note
from magbench.report.load import load_csv

__all__ = ["CONSISTENT", "DROP", "INCONSISTENT", "efficiency_section", "efficiency_table",
           "efficiency_verdicts", "growth_lines"]

#: The sweep the section reads.
SWEEP = "largeK"
#: The consistent fit and the algebraic fits it is set beside.
CONSISTENT = "als"
INCONSISTENT = ("ellipsoid", "fang")
#: Below this efficiency a method has left the floor by more than Monte Carlo scatter could hide.
DROP = 0.9


def _cell(row: pd.Series) -> str:
    return (f"{format_number(row['efficiency'])} [{format_number(row['eff_lo'])}, "
            f"{format_number(row['eff_hi'])}]")


def efficiency_table(eff: pd.DataFrame) -> str:
    """Markdown table, one row per method and one column per K: efficiency [95 % interval]."""
    Ks = sorted(eff["K"].unique())
    lines = ["| method | " + " | ".join(f"K = {int(k)}" for k in Ks) + " |",
             "|---|" + "---:|" * len(Ks)]
    for name, g in eff.groupby("algorithm", sort=False):
        by_k = g.set_index("K")
        cells = [_cell(by_k.loc[k]) if k in by_k.index else "-" for k in Ks]
        lines.append(f"| {method_label(name)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def efficiency_verdicts(eff: pd.DataFrame) -> str:
    """Sentences on the largest K: who stays within its interval of 1, who falls below
    :data:`DROP`, and the consistent fit beside the algebraic ones."""
    top = eff[eff["K"] == eff["K"].max()].set_index("algorithm")
    on = [n for n, r in top.iterrows() if r["eff_lo"] <= 1 <= r["eff_hi"]]
    low = [n for n, r in top.iterrows() if r["efficiency"] < DROP]
    between = [n for n in top.index if n not in on and n not in low]
    drop = ", ".join(f"{method_label(n)} {compact_number(top.loc[n, 'efficiency'], 2)}"
                     for n in low)
    text = [render("efficiency.floor", K=int(top["K"].iloc[0]), on=names(on) or "none",
                   n_on=len(on), n=len(top), drop=DROP,
                   low=drop or "none", between=names(between) or "none")]
    if CONSISTENT in top.index and any(n in top.index for n in INCONSISTENT):
        text.append(_consistency(eff, top))
    return "\n\n".join(text)


def _consistency(eff: pd.DataFrame, top: pd.DataFrame) -> str:
    """ALS beside the algebraic fits at the smallest and the largest K."""
    first = eff[eff["K"] == eff["K"].min()].set_index("algorithm")
    fits = [n for n in INCONSISTENT if n in top.index]
    als = top.loc[CONSISTENT]
    als_on = als["eff_lo"] <= 1 <= als["eff_hi"]
    fits_off = [n for n in fits if top.loc[n, "eff_hi"] < 1]
    others = "; ".join(f"{method_label(n)} {format_number(first.loc[n, 'efficiency'], 2)} -> "
                       f"{_cell(top.loc[n])}" for n in fits if n in first.index)
    if als_on and len(fits_off) == len(fits):
        verdict = ("Here ALS stays on the floor and the algebraic fits leave it (their "
                   "intervals exclude 1), as the theory says.")
    elif als_on and not fits_off:
        verdict = ("Here ALS and the algebraic fits all stay within their intervals of 1 at "
                   "this K: the run cannot tell them apart.")
    elif als_on:
        verdict = (f"Here ALS stays on the floor, but of the algebraic fits only "
                   f"{names(fits_off)} has left it at this K.")
    else:
        verdict = ("Here ALS is below the floor too at this K (its interval excludes 1): the "
                   "run does not show the difference the theory predicts.")
    return render("efficiency.consistency", K=int(als["K"]), K0=int(eff["K"].min()),
                  als_first=format_number(first.loc[CONSISTENT, "efficiency"], 2)
                  if CONSISTENT in first.index else "-", als=_cell(als), others=others,
                  verdict=verdict)


def growth_lines(summary: pd.DataFrame) -> str:
    """What more samples do to each method (``largeK/summary.csv``): 1/rho from the smallest
    to the largest K for the methods that stay robust, set against the review's section
    10.1.1 ('bigger datasets do not improve any algorithm'), and every method whose RB %
    falls below 99 % beyond its Wilson interval, with its 1/rho over the last two K."""
    Ks = sorted(summary["K"].unique())
    if len(Ks) < 2:
        return ""
    by = summary.set_index(["algorithm", "K"])
    k0, k1 = Ks[0], Ks[-1]
    names_ = list(dict.fromkeys(summary["algorithm"]))
    steady = [n for n in names_ if (n, k1) in by.index and by.loc[(n, k1), "RB_pct"] >= 99]
    gain = {n: by.loc[(n, k1), "accuracy"] / by.loc[(n, k0), "accuracy"] for n in steady
            if (n, k0) in by.index}
    better = [n for n, g in gain.items() if g > 1]
    acc0 = [by.loc[(n, k0), "accuracy"] for n in gain]
    acc1 = [by.loc[(n, k1), "accuracy"] for n in gain]
    text = (f"More samples: from K = {int(k0)} to K = {int(k1)}, 1/rho of the {len(gain)} "
            f"methods that stay at RB >= 99 % goes from {format_number(min(acc0))}-"
            f"{format_number(max(acc0))} to {format_number(min(acc1))}-"
            f"{format_number(max(acc1))} ({len(better)} of {len(gain)} improve, by "
            f"{format_number(min(gain.values()), 2)}-{format_number(max(gain.values()), 2)}x). "
            + ("The review's section 10.1.1, 'bigger datasets do not improve any algorithm', "
               "is contradicted by these numbers." if better else
               "No method improves, as the review's section 10.1.1 says."))
    drops = []
    for n in names_:
        rows = summary[summary["algorithm"] == n].sort_values("K")
        last = rows.iloc[-1]
        lo, hi = rb_interval(last)
        if last["RB_pct"] < 99 and hi < 99:
            prev = rows.iloc[-2]
            drops.append(f"{method_label(n)}: RB {rows['RB_pct'].iloc[0]:.3g} % at K = "
                         f"{int(k0)} -> {cell(last['RB_pct'], (lo, hi), 3)} % at K = {int(k1)}, "
                         f"and 1/rho {format_number(prev['accuracy'])} -> "
                         f"{format_number(last['accuracy'])} from K = {int(prev['K'])} to "
                         f"{int(k1)} ({int(last['n'])} datasets)")
    if drops:
        text += (" Methods that lose robustness as K grows (beyond the 95 % Wilson interval): "
                 + "; ".join(drops) + ".")
    return text


def efficiency_section(results_dir: Path | str) -> str:
    """Markdown of the large-K section ('' without ``largeK/efficiency.csv``)."""
    eff = load_csv(Path(results_dir), SWEEP, "efficiency.csv")
    if eff is None or eff.empty:
        return ""
    summary = load_csv(Path(results_dir), SWEEP)
    return "\n".join(["## Large K: who stays on the Cramer-Rao floor", "",
                      run_note(Path(results_dir) / SWEEP), "", render("efficiency.intro"), "",
                      efficiency_table(eff), "", efficiency_verdicts(eff), "",
                      growth_lines(summary) if summary is not None else "", ""])
