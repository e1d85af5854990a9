"""The review's Table 4 (its checkmark summary) and its per-method conclusions, as claims with
verdicts, and how every figure verdict moves with the robustness threshold delta.

Table 4 marks each of the review's seven on simplicity, robustness, accuracy and efficiency
(1 to 3 marks, more is better). Simplicity is a judgement this run cannot measure; the other
three are set against marks made from this run's numbers by fixed rules (:data:`MARK_RULES`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.reference import paper_values
from magbench.methods.registry import method_label
from magbench.report.baseline import REVIEW
from magbench.report.claims import (
    FAILS,
    HOLDS,
    PARTLY,
    check_beta,
    check_gamma,
    check_K,
    check_sigma,
)
from magbench.report.format import format_number, md_table
from magbench.report.intervals import annotate
from magbench.report.load import load_csv, load_trials
from magbench.report.matched import paired

__all__ = ["DELTAS", "MARK_RULES", "TABLE4_KEYS", "conclusion_checks", "delta_sensitivity",
           "marks_here", "resummarize", "table4_rows", "table4_section"]

#: Review method -> its key in paper_values' table4_checkmarks.
TABLE4_KEYS = {"twostep": "TWOSTEP", "crassidis": "Crassidis", "dorveaux": "Dorveaux",
               "vasconcelos": "Vasconcelos", "ali": "Ali", "wu_shi": "Wu_Shi",
               "magical": "MAGICAL"}
#: How this run's numbers become 1-3 marks: (lower bounds of 3 and 2 marks).
MARK_RULES = {
    "robustness": ("lowest RB % over the gamma and beta sweeps", 99.0, 80.0),
    "accuracy": ("efficiency at the baseline (Cramer-Rao bound / MSE)", 0.9, 0.5),
    "efficiency": ("speed at the baseline / the fastest of the seven", 0.5, 0.1),
}
#: The thresholds the sensitivity table re-judges every figure verdict at.
DELTAS = (0.25, 0.5, 0.75)


def _mark(value: float, rule: str) -> int:
    _, three, two = MARK_RULES[rule]
    return 0 if not np.isfinite(value) else 3 if value >= three else 2 if value >= two else 1


def marks_here(baseline: pd.DataFrame, gamma: pd.DataFrame | None,
               beta: pd.DataFrame | None) -> pd.DataFrame:
    """This run's measure and mark per review method and category (columns ``algorithm``,
    ``category``, ``value``, ``mark``)."""
    b = baseline.set_index("algorithm")
    speed = b["speed"] if "speed" in b else b["speed_hz"]
    fastest = speed.reindex(REVIEW).max()
    rows = []
    for n in REVIEW:
        if n not in b.index:
            continue
        rbs = [s[s["algorithm"] == n]["RB_pct"].min() for s in (gamma, beta) if s is not None]
        values = {"robustness": min(rbs) if rbs else b.loc[n, "RB_pct"],
                  "accuracy": b.loc[n].get("efficiency", np.nan),
                  "efficiency": speed[n] / fastest}
        rows += [{"algorithm": n, "category": c, "value": float(v), "mark": _mark(v, c)}
                 for c, v in values.items()]
    return pd.DataFrame(rows)


def table4_rows(baseline: pd.DataFrame, gamma: pd.DataFrame | None,
                beta: pd.DataFrame | None) -> pd.DataFrame:
    """Table 4 beside this run: per method, each category's marks (review / here, with the
    measure) and a verdict: holds when every mark agrees, partly when none is off by more
    than one, does not hold otherwise."""
    review = paper_values()["review"]["table4_checkmarks"]
    here = marks_here(baseline, gamma, beta)
    rows = []
    for n, part in here.groupby("algorithm", sort=False):
        theirs = review[TABLE4_KEYS[n]]
        row = {"method": method_label(n), "simplicity (review)": theirs["simplicity"]}
        off = []
        for r in part.itertuples():
            digits = 3 if r.category == "robustness" else 2
            row[f"{r.category}: review / here"] = (f"{theirs[r.category]} / {r.mark} "
                                                   f"({format_number(r.value, digits)})")
            off.append(abs(theirs[r.category] - r.mark))
        row["verdict"] = (f"**{HOLDS}**" if max(off) == 0 else
                          f"**{PARTLY}**" if max(off) <= 1 else f"**{FAILS}**")
        rows.append(row)
    return pd.DataFrame(rows)


def _failures(results_dir: Path, name: str, words: tuple[str, ...]) -> tuple[int, int, int]:
    """Runs of ``name`` over the baseline, gamma and beta sweeps: all, failed, and failed with
    an error naming one of ``words``."""
    total = failed = matched = 0
    for sweep in ("baseline", "gamma", "beta"):
        path = results_dir / sweep / "trials.csv"
        if not path.exists():
            continue
        t = pd.read_csv(path, usecols=["algorithm", "ok", "error"])
        t = t[t["algorithm"] == name]
        err = t["error"].fillna("").str.lower()
        total += len(t)
        failed += int((~t["ok"].astype(bool)).sum())
        matched += int(err.str.contains("|".join(words)).sum())
    return total, failed, matched


def conclusion_checks(results_dir: Path) -> list[tuple[str, str, str]]:
    """The review's per-method conclusions: (claim, evidence, verdict)."""
    results_dir = Path(results_dir)
    base = load_csv(results_dir, "baseline")
    trials = load_trials(results_dir / "baseline")
    gamma, beta = load_csv(results_dir, "gamma"), load_csv(results_dir, "beta")
    if base is None:
        return []
    b = base.set_index("algorithm")
    out = []
    if "twostep" in b.index and "efficiency" in b:
        eff = b.loc["twostep", "efficiency"]
        out.append(("TWOSTEP has low accuracy in general",
                    f"efficiency at the baseline {format_number(eff)} (1 = the Cramer-Rao "
                    f"floor), 1/rho {format_number(b.loc['twostep', 'accuracy'])} against "
                    f"{format_number(b.loc[[n for n in REVIEW if n in b.index], 'accuracy'].max())}"
                    " for the best of the seven",
                    FAILS if eff >= 0.9 else HOLDS))
    if "wu_shi" in b.index:
        total, failed, chol = _failures(results_dir, "wu_shi", ("cholesky", "positive definite"))
        out.append(("Wu-Shi: the initial estimate fails (Cholesky) in about 1 % of runs",
                    f"Wu-Shi as its paper gives it, over the baseline, gamma and beta sweeps: "
                    f"{failed} of {total} runs fail, {chol} of them in a Cholesky "
                    "factorisation",
                    HOLDS if total and 0.5 <= 100 * chol / total <= 2 else FAILS))
    if "ali" in b.index and beta is not None:
        rb = beta[beta["algorithm"] == "ali"].set_index("beta")["RB_pct"]
        worst = rb.min()
        out.append(("Ali (PSO): a couple of repetitions might be needed",
                    f"RB at the baseline {b.loc['ali', 'RB_pct']:.3g} % (one run suffices); "
                    f"over beta its lowest RB is {worst:.3g} % at beta = {rb.idxmin():g}"
                    + (f": independent restarts would need {format_number(100 / worst, 2)} "
                       "runs on average there" if worst > 0 else ""),
                    PARTLY if worst < 99 else FAILS))
    if trials is not None and {"twostep", "crassidis"} <= set(b.index):
        p = paired(trials, "twostep", "crassidis", key=("conclusions", "ekf"))
        gain = 100 * (p.ratio - 1)
        out.append(("The EKF (Crassidis) is a more accurate TWOSTEP",
                    f"accuracy EKF / TWOSTEP at the baseline on the same runs: {p.text(4)}"
                    + (f": {gain:.2g} % more accurate, beyond the interval but slight"
                       if p.different and 0 < gain < 5 else ""),
                    HOLDS if p.different and gain >= 5 else
                    PARTLY if p.different and gain > 0 else FAILS))
    if "vasconcelos" in b.index and gamma is not None and beta is not None:
        lows = {x: s[s["algorithm"] == name]["RB_pct"].min() for x, s in
                (("gamma", gamma), ("beta", beta)) for name in ("vasconcelos",)}
        printed = {x: s[s["algorithm"] == "vasconcelos_printed"]["RB_pct"].min()
                   for x, s in (("gamma", gamma), ("beta", beta))}
        out.append(("Vasconcelos: robustness for small distortions",
                    f"lowest RB % over gamma / beta: Vasconcelos from its paper "
                    f"{lows['gamma']:.3g} / {lows['beta']:.3g}, as the review prints it "
                    f"{printed['gamma']:.3g} / {printed['beta']:.3g}: the limit is the "
                    "printed formulas', not the method's",
                    PARTLY if min(printed.values()) < 90 <= min(lows.values()) else
                    HOLDS if min(lows.values()) < 90 else FAILS))
    return out


def resummarize(summary: pd.DataFrame, trials: pd.DataFrame, x: str, delta: float
                ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A sweep's summary and trials with meaningful runs re-judged at ``delta`` (76):
    RB %, 1/rho, the MSE and efficiency recomputed; timing columns kept."""
    t = trials.assign(meaningful=np.isfinite(trials["J"]) & (trials["J"] < delta * trials["J0"]))
    ok = t[t["meaningful"]]
    by = [x, "algorithm"]
    n_ok = t.groupby(by)["meaningful"].sum().rename("n_meaningful")
    rho = ok.groupby(by)["J"].mean()
    new = pd.DataFrame({"n_meaningful": n_ok}).join(rho.rename("rho"))
    if {"sq_err", "crb"} <= set(ok.columns):
        new = new.join(ok.groupby(by)["sq_err"].mean().rename("mse")).join(
            ok.groupby(by)["crb"].mean().rename("crb_mse"))
        new["efficiency"] = new["crb_mse"] / new["mse"]
    out = summary.drop(columns=[c for c in new.columns if c in summary]).merge(
        new.reset_index(), on=by, how="left")
    out["n_meaningful"] = out["n_meaningful"].fillna(0)
    out["RB_pct"] = 100.0 * out["n_meaningful"] / out["n"]
    out["accuracy"] = 1.0 / out["rho"]
    return out, t


def delta_sensitivity(results_dir: Path) -> pd.DataFrame:
    """Every figure claim's verdict at each delta of :data:`DELTAS` (one row per claim)."""
    results_dir = Path(results_dir)
    data = {}
    for sweep in ("gamma", "beta", "K", "sigma"):
        s, t = load_csv(results_dir, sweep), load_trials(results_dir / sweep)
        if s is None or t is None or not set(REVIEW) <= set(s["algorithm"]):
            continue
        data[sweep] = (s, t)
    if not data:
        return pd.DataFrame()
    verdicts: dict[tuple[str, str], dict[str, str]] = {}
    for delta in DELTAS:
        again = {k: resummarize(s, t, k, delta) for k, (s, t) in data.items()}
        checks = []
        if "gamma" in again:
            checks += check_gamma(again["gamma"][0], load_csv(results_dir, "gamma",
                                                              "timing.csv"))
        if "beta" in again:
            checks += check_beta(*again["beta"][:1], again.get("gamma", (None,))[0],
                                 again["beta"][1])
        if "K" in again:
            checks += check_K(again["K"][0], load_csv(results_dir, "K", "timing.csv"),
                              load_csv(results_dir, "bench", "calls.csv"))
        if "sigma" in again:
            checks += check_sigma(again["sigma"][0])
        for c in checks:
            verdicts.setdefault((c.figure, c.claim), {})[f"delta = {delta:g}"] = c.verdict
    rows = [{"figure": f, "claim": c, **v} for (f, c), v in verdicts.items()]
    frame = pd.DataFrame(rows)
    cols = [f"delta = {d:g}" for d in DELTAS]
    frame["moves"] = ["yes" if len(set(r[cols])) > 1 else "" for _, r in frame.iterrows()]
    return frame


def table4_section(results_dir: Path) -> str:
    """Markdown: Table 4 and the conclusions with verdicts, and the verdicts' sensitivity to
    delta ('' without a baseline)."""
    results_dir = Path(results_dir)
    base = load_csv(results_dir, "baseline")
    if base is None or not set(TABLE4_KEYS) & set(base["algorithm"]):
        return ""
    base = annotate(base, None, load_csv(results_dir, "baseline", "timing.csv"))
    gamma, beta = load_csv(results_dir, "gamma"), load_csv(results_dir, "beta")
    rules = "; ".join(f"{c}: {what}, 3 marks from {three:g}, 2 from {two:g}"
                      for c, (what, three, two) in MARK_RULES.items())
    out = ["## The review's Table 4 and conclusions, checked", "",
           "Table 4 marks each method 1-3 (more is better); here the same categories from "
           f"this run's numbers ({rules}). Simplicity is a judgement, not measured.", "",
           md_table(table4_rows(base, gamma, beta)), ""]
    concl = conclusion_checks(results_dir)
    if concl:
        out += ["The review's per-method conclusions:", "",
                md_table(pd.DataFrame([{"conclusion": c, "evidence": e, "verdict": f"**{v}**"}
                                       for c, e, v in concl])), ""]
    sens = delta_sensitivity(results_dir)
    if not sens.empty:
        moved = int((sens["moves"] == "yes").sum())
        out += [f"Every figure verdict re-judged with the robustness threshold delta of eq. "
                f"(76) at {', '.join(f'{d:g}' for d in DELTAS)} (the review does not give "
                f"delta; this run uses 0.5): {moved} of {len(sens)} verdicts move.", "",
                md_table(sens), ""]
    return "\n".join(out)

