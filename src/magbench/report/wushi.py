"""Wu and Shi's claims and the report section of their study, from ``<results_dir>/wushi``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.reference import paper_values
from magbench.report.format import format_number, render
from magbench.report.intervals import run_note
from magbench.sources.wushi_sim import truth
from magbench.studies.wushi import CRB_ROW, ML, NM, SHORT, iterations_to_converge

__all__ = ["evaluate_claims", "paired_ml_nm", "verdict_convergence", "verdict_divergence",
           "verdict_ml_better", "verdict_time_ratio", "wushi_report_section"]


# ----------------------------------------------------------------------------------------
# Claims and verdicts
# ----------------------------------------------------------------------------------------

def verdict_convergence(histories: pd.DataFrame, within: int = 5) -> tuple[str, str]:
    """Claim: both estimations converge within ``within`` Gauss-Newton iterations (Fig. 3).

    Holds when every run of both settles (objective within 1e-6 of its final value) by
    iteration ``within``; partly when at least 90 % of each method's runs do; else not.
    """
    if histories.empty:
        return "does not hold", "no run produced an objective history"
    parts, shares = [], []
    for short in ("ML", "NM"):
        sub = histories[histories["method"] == short]
        its = [iterations_to_converge(g.sort_values("iteration")["objective"].to_numpy())
               for _, g in sub.groupby("run")]
        n_ok = sum(i <= within for i in its)
        shares.append(n_ok / len(its) if its else 0.0)
        parts.append(f"{short}: {n_ok}/{len(its)} runs settled by iteration {within} "
                     f"(max {max(its) if its else '-'})")
    verdict = ("holds" if min(shares) == 1.0 else
               "partly" if min(shares) >= 0.9 else "does not hold")
    return verdict, "; ".join(parts)


def verdict_time_ratio(times: pd.DataFrame, claimed: float = 10.0, at_N: int = 1000,
                       ) -> tuple[str, str]:
    """Claim: at N = 1000 ML costs about ``claimed`` times NM (Fig. 5).

    Holds when the measured ratio is within a factor 2 of the claim; partly when ML is slower
    than NM but not within that factor; does not hold when ML is not slower.
    """
    valid = times.dropna(subset=["ml_over_nm"])
    if valid.empty:
        return "does not hold", "no timing available"
    row = valid.iloc[int(np.argmin(np.abs(valid["N"].to_numpy() - at_N)))]
    ratio = float(row["ml_over_nm"])
    evidence = (f"ML/NM time ratio {ratio:.2f} at N = {int(row['N'])} (ML "
                f"{1e3 * row['ml_time_s']:.2f} ms, NM {1e3 * row['nm_time_s']:.2f} ms); over "
                f"N = {int(valid['N'].min())}..{int(valid['N'].max())} the ratio is "
                f"{valid['ml_over_nm'].min():.2f}..{valid['ml_over_nm'].max():.2f}")
    if len(valid) >= 2:
        slopes = [np.polyfit(np.log(valid["N"]), np.log(valid[c]), 1)[0]
                  for c in ("ml_time_s", "nm_time_s")]
        evidence += (f"; time grows as N^{slopes[0]:.2f} (ML) and N^{slopes[1]:.2f} (NM). Our "
                     "ML eliminates the per-sample blocks of the (4N+9)-square Newton system by "
                     "a Schur complement (O(N) per iteration); the paper does not say how its "
                     "Matlab code solved that system")
    if claimed / 2.0 <= ratio <= claimed * 2.0:
        return "holds", evidence
    return ("partly" if ratio > 1.0 else "does not hold"), evidence


def verdict_divergence(div: pd.DataFrame) -> tuple[str, str]:
    """Claim (Fig. 6): NM starts to diverge at 1 %, diverges in over half the runs at 3 %,
    completely by 6 %; ML does not diverge within 5 %.

    Holds when all four parts hold; partly when the main conclusion holds (ML never diverges
    more often than NM, and NM diverges more often than ML at some alpha) but not every number;
    does not hold otherwise.
    """
    d = div.set_index("alpha_pct")
    runs = int(d["runs"].max())

    def at(short: str, alpha: float) -> int | None:
        return int(d.loc[alpha, f"{short}_divergences"]) if alpha in d.index else None

    nm1, nm3, nm6 = at("NM", 1.0), at("NM", 3.0), at("NM", 6.0)
    ml_upto5 = d.loc[d.index <= 5.0, "ML_divergences"]
    parts = {
        f"NM diverges at 1 % ({nm1})": nm1 is not None and nm1 > 0,
        f"NM diverges in over half the runs at 3 % ({nm3}/{runs})":
            nm3 is not None and nm3 > runs / 2,
        f"NM diverges in every run by 6 % ({nm6}/{runs})": nm6 is not None and nm6 == runs,
        f"ML has no divergence up to 5 % ({int(ml_upto5.sum())} in all)":
            bool((ml_upto5 == 0).all()) and len(ml_upto5) > 0,
    }
    ordered = bool((d["ML_divergences"] <= d["NM_divergences"]).all())
    separated = bool((d["ML_divergences"] < d["NM_divergences"]).any())
    counts = ", ".join(f"{a:g} %: ML {int(r['ML_divergences'])}, NM {int(r['NM_divergences'])}"
                       for a, r in d.iterrows())
    evidence = (f"divergences out of {runs} ({counts}); "
                + "; ".join(f"{k}: {'yes' if v else 'no'}" for k, v in parts.items()))
    if all(parts.values()):
        return "holds", evidence
    return ("partly" if ordered and separated else "does not hold"), evidence


def paired_ml_nm(runs: pd.DataFrame) -> pd.DataFrame:
    """ML against NM run by run (same datasets, the offset kept): per error metric the paired
    t statistic of ML - NM, its two-sided p-value, the share of runs in which ML's error is
    the smaller, and n."""
    from scipy.stats import ttest_rel

    r = runs[~runs["offset_removed"].astype(bool) & runs["ok"].astype(bool)]
    wide = {m: r[r["algorithm"] == m].set_index("run") for m in (ML, NM)}
    common = wide[ML].index.intersection(wide[NM].index)
    rows = []
    for metric in ("e_s", "e_o"):
        a, b = wide[ML].loc[common, metric], wide[NM].loc[common, metric]
        test = ttest_rel(a, b)
        rows.append({"metric": metric, "t": float(test.statistic),
                     "p": float(test.pvalue), "ml_wins_pct": 100.0 * float((a < b).mean()),
                     "n": len(common)})
    return pd.DataFrame(rows)


def verdict_ml_better(table: pd.DataFrame, runs: pd.DataFrame | None = None
                      ) -> tuple[str, str]:
    """Section IV text: ML performs slightly better than NM in both mean and standard deviation
    (Table I). Compared on e_s and e_o (e_h is 0.0002 (0.0001) for both in the paper).

    With the per-run errors (``runs.csv``), the means are compared run by run (paired t over
    the Monte Carlo runs): holds when ML's mean and std are at most NM's for e_s and e_o and
    both paired differences are significant (p < 0.05); partly when the point estimates agree
    but the differences are not significant (or only some agree); does not hold when none
    agree. Without ``runs``: on the point estimates alone.
    """
    t = table.set_index("algorithm")
    if ML not in t.index or NM not in t.index:
        return "does not hold", "ML or NM missing from Table I"
    columns = [f"{metric}_{stat}" for metric in ("e_s", "e_o") for stat in ("mean", "std")]
    ml = {c: float(t.loc[ML, c]) for c in columns}
    nm = {c: float(t.loc[NM, c]) for c in columns}
    n = sum(ml[c] <= nm[c] for c in columns)
    evidence = (f"ML <= NM in {n} of 4 point estimates (" + "; ".join(
        f"{c}: ML {ml[c]:.4f}, NM {nm[c]:.4f}" for c in columns) + ")")
    if runs is None or not {ML, NM} <= set(runs["algorithm"]):
        return ("holds" if n == len(columns) else "partly" if n else "does not hold"), evidence
    paired = paired_ml_nm(runs)
    significant = bool(((paired["t"] < 0) & (paired["p"] < 0.05)).all())
    evidence += ("; paired over the same " + str(int(paired["n"].max())) + " runs: "
                 + "; ".join(f"{r.metric} t = {r.t:.2g} (p = {r.p:.2g}), ML smaller in "
                             f"{r.ml_wins_pct:.0f} % of runs" for r in paired.itertuples())
                 + (": significant" if significant else
                    ": not significant, the difference is within the runs' scatter"))
    verdict = ("holds" if n == len(columns) and significant else
               "partly" if n else "does not hold")
    return verdict, evidence


def evaluate_claims(results_dir: Path | str, within: int = 5,
                    claimed_ratio: float = 10.0) -> pd.DataFrame:
    """Every claim with evidence and verdict, from the CSV files in ``<results_dir>/wushi``."""
    folder = Path(results_dir) / "wushi"
    claims = paper_values()["wu_shi"]["claims"]
    out = []
    history = pd.read_csv(folder / "fig3_objective.csv")
    out.append((claims["converge_in_five"], *verdict_convergence(history, within)))
    out.append((claims["ml_costs_ten_nm"],
                *verdict_time_ratio(pd.read_csv(folder / "fig5_time.csv"), claimed_ratio)))
    out.append((claims["nm_diverges"],
                *verdict_divergence(pd.read_csv(folder / "fig6_divergence.csv"))))
    runs = folder / "runs.csv"
    out.append((claims["ml_better"], *verdict_ml_better(
        pd.read_csv(folder / "table1.csv"), pd.read_csv(runs) if runs.exists() else None)))
    return pd.DataFrame(out, columns=["claim", "verdict", "evidence"])


def _cell(mean: float, std: float, digits: int = 4) -> str:
    if not np.isfinite(mean):
        return "-"
    return f"{mean:.{digits}f} ({std:.{digits}f})" if np.isfinite(std) else f"{mean:.{digits}f}"


def wushi_report_section(results_dir: Path | str, link_prefix: str = "wushi/") -> str:
    """Markdown: Table I beside the paper, extra rows, the figures and the claims with verdicts.

    Reads only the CSV files of ``<results_dir>/wushi``; ``link_prefix`` is prepended to the
    figure file names (``""`` when the Markdown lives in that folder).
    """
    folder = Path(results_dir) / "wushi"
    if not (folder / "table1.csv").exists():
        return render("wushi.missing") + "\n"
    t = pd.read_csv(folder / "table1.csv", keep_default_na=False, na_values=[""])
    settings = (pd.read_csv(folder / "settings.csv").set_index("key")["value"]
                if (folder / "settings.csv").exists() else pd.Series(dtype=object))
    N, sigma = (f"{float(settings[k]):g}" if k in settings else "?" for k in ("N", "sigma"))
    lines = ["## Wu and Shi (2015), section IV: their simulation reproduced", "",
             render("wushi.intro", runs=int(t["runs"].max()), sigma=sigma, N=N), "",
             run_note(folder, "Monte Carlo runs"), "", "### Table I", "",
             *_table1_lines(t), "", render("wushi.ratios", ratios=_ratios(t)), "",
             render("wushi.all_methods"), "", *_all_methods_lines(t), *_offset_lines(t),
             *_figure_lines(link_prefix), "", "### Claims", "", "| claim | verdict | evidence |",
             "|---|---|---|"]
    for _, c in evaluate_claims(results_dir).iterrows():
        lines.append(f"| {c['claim']} | **{c['verdict']}** | {c['evidence']} |")
    return "\n".join(lines) + "\n"


def _table1_lines(t: pd.DataFrame) -> list[str]:
    lines = ["| estimator | e_s % (ours) | e_s % (paper) | e_o deg (ours) | e_o deg (paper) "
             "| e_h gauss (ours) | e_h gauss (paper) | J (ours) |",
             "|---|---|---|---|---|---|---|---|"]
    names = {ML: "ML (`wu_shi`)", NM: "NM (`wu_shi_nm`)",
             CRB_ROW: "efficient estimator (Cramer-Rao bound)"}
    for _, r in t[t["algorithm"].isin(list(names))].iterrows():
        lines.append(
            f"| {names[r['algorithm']]} "
            f"| {_cell(r['e_s_mean'], r['e_s_std'])} "
            f"| {_cell(r['paper_e_s_mean'], r['paper_e_s_std'])} "
            f"| {_cell(r['e_o_mean'], r['e_o_std'])} "
            f"| {_cell(r['paper_e_o_mean'], r['paper_e_o_std'])} "
            f"| {_cell(r['e_h_mean'], r['e_h_std'], 5)} "
            f"| {_cell(r['paper_e_h_mean'], r['paper_e_h_std'])} "
            f"| {_cell(r['J_mean'], r['J_std'], 5)} |")
    return lines


def _ratios(t: pd.DataFrame) -> str:
    ratios = []
    for name in (ML, NM):
        r = t[t["algorithm"] == name]
        if len(r):
            r = r.iloc[0]
            ratios.append(f"{SHORT[name]} " + ", ".join(
                f"{m} {r[f'{m}_mean'] / r[f'paper_{m}_mean']:.2f}" for m in ("e_s", "e_o", "e_h")))
    return "; ".join(ratios)


def _all_methods_lines(t: pd.DataFrame) -> list[str]:
    lines = ["| method | estimates | at cap | e_s % | e_o deg | e_h gauss | J mean (std) "
             "| J median | J median, offset removed (control) | median time ms | note |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in t[t["algorithm"] != CRB_ROW].iterrows():
        note = str(r["note"]).replace("|", "/")[:90] if pd.notna(r["note"]) else ""
        lines.append(
            f"| {r['label']} (`{r['algorithm']}`) | {int(r['estimates'])}/{int(r['runs'])} "
            f"| {int(r['at_cap'])} | {_cell(r['e_s_mean'], r['e_s_std'], 3)} "
            f"| {_cell(r['e_o_mean'], r['e_o_std'], 3)} "
            f"| {_cell(r['e_h_mean'], r['e_h_std'], 5)} | {_cell(r['J_mean'], r['J_std'], 4)} "
            f"| {format_number(r['J_median'], 4)} "
            f"| {format_number(r['J_median_offset_removed'], 4)} "
            f"| {format_number(r['time_ms_median'], 3)} | {note} |")
    return lines


def _offset_lines(t: pd.DataFrame) -> list[str]:
    """The methods defeated by Wu and Shi's large offset rather than by their coverage."""
    ml_J = t.loc[t["algorithm"] == ML, "J_median"]
    good_J = 10.0 * float(ml_J.iloc[0]) if len(ml_J) else np.nan
    bound = t[(t["algorithm"] != CRB_ROW) & (t["J_median"] > 0.1)
              & (t["J_median_offset_removed"] < good_J)]
    if not len(bound):
        return []
    _, S_true, h_true = truth()
    axes = np.linalg.svd(S_true, compute_uv=False)
    methods = ", ".join(f"{r['label']} ({format_number(r['J_median'])} -> "
                        f"{format_number(r['J_median_offset_removed'])})"
                        for _, r in bound.iterrows())
    return ["", render("wushi.offset_bound", methods=methods, h_norm=np.linalg.norm(h_true),
                       axis_lo=axes.min(), axis_hi=axes.max())]


def _figure_lines(link_prefix: str) -> list[str]:
    return ["", "### Figures", "",
            f"![Fig. 3](<{link_prefix}fig3_objective.png>) (numbers: `fig3_objective.csv`)",
            "", f"![Fig. 5](<{link_prefix}fig5_time.png>) (numbers: `fig5_time.csv`)", "",
            f"![Fig. 6](<{link_prefix}fig6_divergence.png>) (numbers: "
            "`fig6_divergence.csv`, per run: `perturbation_runs.csv`)"]
