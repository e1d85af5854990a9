"""The review's claims (paper_values ``review.claims``, by id), each with the evidence from
this run's sweeps and a verdict: holds, partly, does not hold."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.reference import paper_values
from magbench.methods.registry import method_label
from magbench.report.baseline import REVIEW
from magbench.report.format import format_number, names, render
from magbench.report.intervals import cell, rb_interval, significantly_different
from magbench.report.load import load_csv, load_trials
from magbench.report.matched import paired
from magbench.report.sweeps import pivot

__all__ = [
    "FAILS",
    "HOLDS",
    "LINEAR_SLOPE",
    "MISSING",
    "PARTLY",
    "ClaimCheck",
    "all_checks",
    "bias_vs_distortion",
    "check_K",
    "check_beta",
    "check_gamma",
    "check_real",
    "check_sigma",
    "claim",
    "claims_section",
]

HOLDS, PARTLY, FAILS, MISSING = "holds", "partly", "does not hold", "not evaluated"
#: A method's time is linear in K when log(time) grows with log(K) at a slope in this range.
LINEAR_SLOPE = (0.7, 1.3)


@dataclass(frozen=True)
class ClaimCheck:
    """One qualitative claim of the paper, the evidence from this run, and the verdict."""

    figure: str
    claim: str
    evidence: str
    verdict: str


def claim(figure: str, key: str) -> str:
    """The text of the review's claim ``key`` about ``figure`` (``fig2_gamma``, ...)."""
    return paper_values()["review"]["claims"][figure][key]


def _verdict(n_ok: int, n_all: int, partly_from: int = 1) -> str:
    if n_ok == n_all:
        return HOLDS
    return PARTLY if n_ok >= partly_from else FAILS


def _fmt_series(values: pd.Series, digits: int = 3) -> str:
    return ", ".join(f"{method_label(k)} {format_number(v, digits)}" for k, v in values.items())


def _speed_table(s: pd.DataFrame, x: str, timing: pd.DataFrame | None) -> tuple[pd.DataFrame,
                                                                                  str]:
    """Methods x values of speed: the timing pass's when there is one, else the per-trial."""
    if timing is not None and set(REVIEW) & set(timing["algorithm"]):
        return pivot(timing, x, "speed_hz", REVIEW), "timing pass"
    return pivot(s, x, "speed_hz", REVIEW), "per-trial times, no timing pass"


def _has(table: pd.DataFrame, needed: tuple[str, ...]) -> bool:
    """The sweep ran every method a claim names (a sweep of a subset leaves it out)."""
    return set(needed) <= set(table.index)


def _at_largest(s: pd.DataFrame, x: str) -> pd.DataFrame:
    """The review methods' summary rows at the sweep's largest value of ``x``, by method."""
    last = s[s[x] == s[x].max()]
    return last[last["algorithm"].isin(REVIEW)].set_index("algorithm")


def _most_robust_at_largest(s: pd.DataFrame, names: tuple[str, ...]) -> tuple[str, int]:
    """Evidence and the number of ``names`` no method beats beyond the Wilson intervals at
    the largest gamma (the claim's 'even for large bias')."""
    last = _at_largest(s, "gamma")
    cells, ok = [], 0
    ranked = last.sort_values("RB_pct")
    for n in names:
        mine = rb_interval(last.loc[n])
        above = [m for m in last.index if m != n and rb_interval(last.loc[m])[0] > mine[1]]
        rank = list(ranked.index).index(n) + 1
        place = {1: "the least robust", 2: "the second least robust"}.get(
            rank, f"{rank}th least robust")
        cells.append(f"{method_label(n)} {cell(last.loc[n, 'RB_pct'], mine, 3)} %"
                     + (f", below {len(above)} method{'s' if len(above) > 1 else ''} beyond "
                        f"the intervals ({place} of {len(last)})" if above else
                        ", no method above it beyond the intervals"))
        ok += not above
    return (f"at the largest gamma ({s['gamma'].max():g}), RB % [95 % Wilson]: "
            + "; ".join(cells)), ok


def _gamma_robustness(rb: pd.DataFrame, s: pd.DataFrame) -> list[ClaimCheck]:
    worst = rb.min(axis=1)
    out = []
    if _has(rb, ("magical", "ali")):
        evidence, ok = _most_robust_at_largest(s, ("magical", "ali"))
        out.append(ClaimCheck("Figure 2", claim("fig2_gamma", "most_robust"),
                              f"{evidence}; lowest RB % over gamma: {_fmt_series(worst)}",
                              _verdict(ok, 2)))
    if _has(rb, ("twostep", "wu_shi", "magical", "ali")):
        less = [n for n in ("twostep", "wu_shi")
                if 50 <= worst[n] < min(worst["magical"], worst["ali"])]
        out.append(ClaimCheck("Figure 2", claim("fig2_gamma", "less_stable"),
                              f"lowest RB %: TWOSTEP {worst['twostep']:.3g}, Wu-Shi "
                              f"{worst['wu_shi']:.3g}, against MAG.I.C.AL "
                              f"{worst['magical']:.3g} and Ali {worst['ali']:.3g}",
                              _verdict(len(less), 2)))
    small = [g for g in rb.columns if g <= 0.25]
    if _has(rb, ("dorveaux", "crassidis")) and small:
        reliable = [n for n in ("dorveaux", "crassidis")
                    if rb.loc[n, small].min() >= 95 and rb.loc[n].iloc[-1] < 95]
        out.append(ClaimCheck("Figure 2", claim("fig2_gamma", "small_bias_only"),
                              "RB % at gamma <= 0.25 / at the largest gamma: " + "; ".join(
                                  f"{method_label(n)} {rb.loc[n, small].min():.3g} / "
                                  f"{rb.loc[n].iloc[-1]:.3g}" for n in ("dorveaux",
                                                                        "crassidis")),
                              _verdict(len(reliable), 2)))
    return out


def _gamma_precision(s: pd.DataFrame) -> list[ClaimCheck]:
    if "crb_accuracy" not in s:
        return []
    acc = pivot(s, "gamma", "accuracy", REVIEW)
    if not _has(acc, REVIEW):
        return []
    floor = s.groupby("gamma", sort=False)["crb_accuracy"].first()
    eff = acc.div(floor, axis=1).min(axis=1)
    others = [n for n in REVIEW if n not in ("twostep", "crassidis")]
    precise = [n for n in others if eff[n] >= 0.5]
    exceptions = [n for n in ("twostep", "crassidis") if eff[n] < 0.5]
    verdict = HOLDS if len(precise) == 5 and len(exceptions) == 2 else (
        PARTLY if len(precise) == 5 else FAILS)
    excepted = [n for n in ("twostep", "crassidis") if n not in exceptions]
    note = (f"; {' and '.join(map(method_label, excepted))} "
            f"{'is' if len(excepted) == 1 else 'are'} as close to the "
            "floor as the others, so the exception does not hold" if excepted else "")
    return [ClaimCheck("Figure 2", claim("fig2_gamma", "precise"),
                       "lowest accuracy / Cramer-Rao floor over gamma (1 = optimal): "
                       f"{_fmt_series(eff)}{note}", verdict)]


def check_gamma(s: pd.DataFrame, timing: pd.DataFrame | None = None) -> list[ClaimCheck]:
    """Figure 2's claims (paper_values review.claims.fig2_gamma).

    The speed claim is judged on the sweep's timing pass when ``timing`` is given: the
    per-trial times of the sweep carry its workers' load and warm-up.
    """
    out = _gamma_robustness(pivot(s, "gamma", "RB_pct", REVIEW), s) + _gamma_precision(s)
    speed, source = _speed_table(s, "gamma", timing)
    if not _has(speed, REVIEW):
        return out
    ratio = speed.max(axis=1) / speed.min(axis=1)
    steady = [n for n in REVIEW if n != "magical" and ratio[n] < 1.5]
    verdict = (HOLDS if ratio["magical"] > 2 and len(steady) == 6 else
               PARTLY if ratio["magical"] > 2 else FAILS)
    out.append(ClaimCheck("Figure 2", claim("fig2_gamma", "speed_flat"),
                          f"fastest / slowest speed over gamma ({source}): "
                          f"{_fmt_series(ratio, 2)}", verdict))
    return out


def accuracy_ratios(s: pd.DataFrame, trials: pd.DataFrame | None, x: str, a: str, b: str
                    ) -> pd.DataFrame:
    """Accuracy of ``a`` over accuracy of ``b`` at every point of a sweep, with the runs it
    rests on: on the runs meaningful for both (``n``) when ``trials`` is given; else each
    over its own meaningful runs (``n`` = -1, unmatched)."""
    rows = []
    for v in dict.fromkeys(s[x]):
        if trials is not None:
            p = paired(trials[trials[x] == v], b, a, key=(x, v))
            rows.append({x: v, "ratio": p.ratio, "n": p.n})
        else:
            acc = s[s[x] == v].set_index("algorithm")["accuracy"]
            rows.append({x: v, "ratio": acc.get(a, np.nan) / acc.get(b, np.nan), "n": -1})
    return pd.DataFrame(rows).dropna(subset=["ratio"])


def _ratio_text(ratios: pd.DataFrame) -> str:
    if (ratios["n"] < 0).all():
        return (", ".join(format_number(v, 3) for v in ratios["ratio"])
                + " (each over its own meaningful runs: no trials.csv)")
    return (", ".join(f"{format_number(r.ratio, 3)} ({r.n})" for r in ratios.itertuples())
            + " (in brackets: runs meaningful for both)")


def _beta_robustness(rb: pd.DataFrame, s: pd.DataFrame, trials: pd.DataFrame | None
                     ) -> list[ClaimCheck]:
    worst = rb.min(axis=1)
    second = worst.sort_values(ascending=False).iloc[1]
    ratio = accuracy_ratios(s, trials, "beta", "magical", "dorveaux")
    top = [n for n in ("magical", "dorveaux") if worst[n] >= second]
    similar = bool(len(ratio)) and bool(ratio["ratio"].between(2 / 3, 1.5).all())
    out = [ClaimCheck("Figure 3", claim("fig3_beta", "most_robust"),
                      f"lowest RB % over beta: {_fmt_series(worst)}; accuracy MAG.I.C.AL / "
                      f"Dorveaux per beta: {_ratio_text(ratio)}",
                      _verdict(len(top) + similar, 3))]
    small = [b for b in rb.columns if b <= 0.25]
    only_small = [n for n in ("vasconcelos", "ali", "crassidis")
                  if rb.loc[n, small].min() >= 90 and rb.loc[n].iloc[-1] < 90]
    out.append(ClaimCheck("Figure 3", claim("fig3_beta", "small_beta_only"),
                          "RB % at beta <= 0.25 / at the largest beta: " + "; ".join(
                              f"{method_label(n)} {rb.loc[n, small].min():.3g} / "
                              f"{rb.loc[n].iloc[-1]:.3g}"
                              for n in ("vasconcelos", "ali", "crassidis")),
                          _verdict(len(only_small), 3)))
    return out


def _wu_shi_lowest(s: pd.DataFrame, trials: pd.DataFrame | None) -> pd.DataFrame:
    """Per beta, Wu-Shi's accuracy over each other review method's (matched when ``trials``
    is given): the lowest ratio, against whom, on how many runs."""
    rows = []
    for n in REVIEW:
        if n != "wu_shi":
            rows.append(accuracy_ratios(s, trials, "beta", "wu_shi", n).assign(other=n))
    every = pd.concat(rows, ignore_index=True)
    return every.loc[every.groupby("beta", sort=False)["ratio"].idxmin().to_numpy()]


def _wu_shi_claim(rb: pd.DataFrame, s: pd.DataFrame, trials: pd.DataFrame | None,
                  gamma: pd.DataFrame | None) -> ClaimCheck:
    lowest = _wu_shi_lowest(s, trials)
    most = bool((lowest["ratio"] >= 0.99).all())
    low = bool(rb.min(axis=1)["wu_shi"] <= 70)
    per = "; ".join(f"{r.beta:g}: {format_number(r.ratio, 3)} against {method_label(r.other)}"
                    + (f" ({r.n})" if r.n >= 0 else "") for r in lowest.itertuples())
    runs = ("on the runs meaningful for both, in brackets" if trials is not None
            else "each over its own meaningful runs")
    evidence = (f"Wu-Shi's accuracy over each other review method's, the lowest per beta "
                f"({runs}): {per}; its lowest RB % {rb.min(axis=1)['wu_shi']:.3g}. "
                + ("The accuracy half holds, the robustness half does not. " if most and not low
                   else "") + printed_wu_shi(s, trials, gamma))
    return ClaimCheck("Figure 3", claim("fig3_beta", "wu_shi_accurate"), evidence.strip(),
                      _verdict(most + low, 2))


def printed_wu_shi(beta: pd.DataFrame, trials: pd.DataFrame | None,
                   gamma: pd.DataFrame | None) -> str:
    """What the review's printed (57) (``wu_shi_printed``) shows of its Wu-Shi claim: its RB
    over beta (and gamma) and, where it converges, its accuracy beside Wu-Shi's."""
    name = "wu_shi_printed"
    if name not in set(beta["algorithm"]):
        return ""
    rb = beta[beta["algorithm"] == name].set_index("beta")["RB_pct"]
    text = (f"The review's printed (57) (`{name}`) reproduces both halves: its RB falls from "
            f"{rb.iloc[0]:.3g} % to {rb.iloc[-1]:.3g} % over beta")
    if gamma is not None and name in set(gamma["algorithm"]):
        g = gamma[gamma["algorithm"] == name].set_index("gamma")["RB_pct"]
        text += f" (from {g.iloc[0]:.3g} % to {g.iloc[-1]:.3g} % over gamma)"
    if trials is not None:
        same = accuracy_ratios(beta, trials, "beta", name, "wu_shi")
        if len(same) and bool(np.allclose(same["ratio"], 1.0, atol=1e-3)):
            text += (", and where it converges it returns Wu-Shi's estimate, the most "
                     f"accurate (accuracy ratio 1.00 at every beta, on {same['n'].max()} to "
                     f"{same['n'].min()} shared runs)")
    return text + "."


def _vasconcelos_claim(s: pd.DataFrame, trials: pd.DataFrame | None) -> ClaimCheck:
    vm = accuracy_ratios(s, trials, "beta", "vasconcelos", "magical")["ratio"]
    return ClaimCheck("Figure 3", claim("fig3_beta", "vasconcelos_accuracy"),
                      "accuracy Vasconcelos / MAG.I.C.AL per beta: "
                      + _ratio_text(accuracy_ratios(s, trials, "beta", "vasconcelos",
                                                    "magical")),
                      HOLDS if vm.between(0.5, 2).all() else
                      PARTLY if vm.between(0.5, 2).any() else FAILS)


def check_beta(s: pd.DataFrame, gamma: pd.DataFrame | None,
               trials: pd.DataFrame | None = None) -> list[ClaimCheck]:
    """Figure 3's claims (paper_values review.claims.fig3_beta).

    Accuracies of two methods are compared on the runs meaningful for both when the sweep's
    ``trials`` are given (:func:`accuracy_ratios`).
    """
    rb = pivot(s, "beta", "RB_pct", REVIEW)
    out = _beta_robustness(rb, s, trials)
    out += [_vasconcelos_claim(s, trials), _wu_shi_claim(rb, s, trials, gamma)]
    if gamma is not None:
        out.append(check_bias_vs_distortion(gamma, s))
    return out


def bias_vs_distortion(gamma: pd.DataFrame, beta: pd.DataFrame
                       ) -> tuple[dict[str, str], list[float]]:
    """Which review method is more robust to bias (gamma) than to non-orthogonality (beta).

    The two sweeps share their values (half-widths of the same uniform law). At each shared
    value a method's RB % under gamma and under beta are compared with their Wilson 95 %
    intervals; a difference counts only where the intervals are apart. A method is
    ``"bias"`` (handles bias better) when every such difference favours gamma, ``"beta"``
    when every one favours beta, ``"mixed"`` when both occur and ``"tie"`` when none does.

    Returns
    -------
    (classes, shared) : dict, list
        Method -> class, and the shared values compared.
    """
    shared = sorted(set(gamma["gamma"]) & set(beta["beta"]))
    g = gamma.set_index(["algorithm", "gamma"])
    b = beta.set_index(["algorithm", "beta"])
    classes = {}
    for n in REVIEW:
        signs = set()
        for v in shared:
            if (n, v) not in g.index or (n, v) not in b.index:
                continue
            rg, rb_ = g.loc[(n, v)], b.loc[(n, v)]
            if significantly_different(rb_interval(rg), rb_interval(rb_)):
                signs.add("bias" if rg["RB_pct"] > rb_["RB_pct"] else "beta")
        classes[n] = signs.pop() if len(signs) == 1 else ("mixed" if signs else "tie")
    return classes, shared


def check_bias_vs_distortion(gamma: pd.DataFrame, beta: pd.DataFrame) -> ClaimCheck:
    """'Most algorithms handle bias distortion better than non-orthogonality errors'.

    Holds when more than half of the review's seven are more robust to bias
    (:func:`bias_vs_distortion`); partly when more are better with bias than with
    non-orthogonality, though not most; does not hold otherwise.
    """
    classes, shared = bias_vs_distortion(gamma, beta)
    groups = {k: [n for n in REVIEW if classes.get(n) == k]
              for k in ("bias", "beta", "tie", "mixed")}
    rb_g = pivot(gamma, "gamma", "RB_pct", REVIEW)
    rb_b = pivot(beta, "beta", "RB_pct", REVIEW)
    lowest = "; ".join(f"{method_label(n)} {rb_g.loc[n].min():.3g} / {rb_b.loc[n].min():.3g}"
                       for n in REVIEW if n in rb_g.index and n in rb_b.index)
    listed = {k: names(v) or "none" for k, v in groups.items()}
    evidence = (f"comparing RB % at the shared half-widths {', '.join(f'{v:g}' for v in shared)}"
                " with 95 % Wilson intervals: more robust to bias: "
                f"{listed['bias']}; more robust to non-orthogonality: {listed['beta']}; no "
                f"difference outside the intervals: {listed['tie']}"
                + (f"; either way at different values: {listed['mixed']}" if groups["mixed"]
                   else "") + f" (lowest RB % over gamma / over beta: {lowest})")
    n_bias, n_beta = len(groups["bias"]), len(groups["beta"])
    verdict = (HOLDS if n_bias > len(REVIEW) / 2 else PARTLY if n_bias > n_beta else FAILS)
    return ClaimCheck("Figure 3", claim("fig3_beta", "bias_vs_distortion"), evidence, verdict)


def _flat_robustness(s: pd.DataFrame, x: str, figure: str, text: str) -> ClaimCheck:
    """'Robustness does not depend on x': a method's RB % changes with x when the Wilson 95 %
    intervals of its highest and lowest points are apart. Holds when no review method changes,
    partly when at most half do, does not hold otherwise."""
    rb = pivot(s, x, "RB_pct", REVIEW)
    spread = rb.max(axis=1) - rb.min(axis=1)
    moved = []
    for n in rb.index:
        rows = s[s["algorithm"] == n]
        if rows.empty:
            continue
        hi, lo = rows.loc[rows["RB_pct"].idxmax()], rows.loc[rows["RB_pct"].idxmin()]
        if significantly_different(rb_interval(hi), rb_interval(lo)):
            moved.append(n)
    verdict = HOLDS if not moved else PARTLY if len(moved) <= len(rb) / 2 else FAILS
    return ClaimCheck(figure, text,
                      f"RB % range over {x} (points): {_fmt_series(spread)}; changes beyond "
                      f"the 95 % Wilson intervals: {names(moved) or 'none'}", verdict)


def _K_accuracy(s: pd.DataFrame) -> list[ClaimCheck]:
    if "crb_accuracy" not in s:
        return []
    acc = pivot(s, "K", "accuracy", REVIEW)
    floor = s.groupby("K")["crb_accuracy"].first()
    k50 = (acc[min(acc.columns)] / floor[min(acc.columns)])
    n_high = int((k50 >= 0.5).sum())
    return [ClaimCheck("Figure 4", claim("fig4_K", "accurate_at_50"),
                       f"accuracy / Cramer-Rao floor at K = {min(acc.columns)}: "
                       f"{_fmt_series(k50)} (the floor itself falls as sqrt(K))",
                       HOLDS if n_high >= 5 else PARTLY if n_high >= 3 else FAILS)]


def _small_K_slopes(s: pd.DataFrame, timing: pd.DataFrame | None) -> tuple[pd.Series, str]:
    """Slope of log(time) against log(K) over the sweep's points, and its sentence."""
    if timing is not None and set(REVIEW) & set(timing["algorithm"]):
        tau, source = pivot(timing, "K", "tau_s", REVIEW), "timing pass"
    else:
        tau, source = pivot(s, "K", "tau_s", REVIEW), "per-trial times"
    ks = np.log(np.asarray(tau.columns, dtype=float))
    slope = tau.apply(lambda r: np.polyfit(ks, np.log(r.to_numpy(float)), 1)[0]
                      if r.notna().all() else np.nan, axis=1)
    return slope, (f"slope of log(time) against log(K) over K = {int(min(tau.columns))}-"
                   f"{int(max(tau.columns))} ({source}; 1 = linear): {_fmt_series(slope, 2)}")


def _large_K_ratios(calls: pd.DataFrame | None) -> dict[str, float]:
    """Time at K = 10000 over time at K = 1000 per review method (scaling benchmark)."""
    big = {}
    for n in REVIEW if calls is not None else ():
        c = calls[calls["algorithm"] == n].set_index("K")["median_s"]
        if {1000, 10000} <= set(c.index) and np.isfinite(c[[1000, 10000]]).all():
            big[n] = float(c[10000] / c[1000])
    return big


def _K_time(s: pd.DataFrame, timing: pd.DataFrame | None,
            calls: pd.DataFrame | None) -> ClaimCheck:
    """The review's claim is about its Figure 4, K = 50-300: judged there (slopes of
    log(time) against log(K)); the scaling benchmark's K = 1000-10000 says where time does
    become near linear, beside it."""
    slope, small = _small_K_slopes(s, timing)
    n_small = int(slope.between(*LINEAR_SLOPE).sum())
    k0, k1 = int(s["K"].min()), int(s["K"].max())
    evidence = (f"{small}; {n_small} of {len(slope)} near linear (slope "
                f"{LINEAR_SLOPE[0]}-{LINEAR_SLOPE[1]}) at the review's K = {k0}-{k1}, where "
                "the fixed cost of a call dominates")
    big = _large_K_ratios(calls)
    if big:
        slopes = {n: np.log10(r) for n, r in big.items()}
        n_lin = sum(LINEAR_SLOPE[0] <= v <= LINEAR_SLOPE[1] for v in slopes.values())
        evidence += ("; scaling benchmark, time at K = 10000 / K = 1000 (10 = linear): "
                     + ", ".join(f"{method_label(n)} {big[n]:.2g} (slope {slopes[n]:.2f})"
                                 for n in big)
                     + f": {n_lin} of {len(big)} near linear, so time is affine in K (a fixed "
                     "cost per call plus a cost per sample) and near linear only from "
                     "K >= 1000")
    verdict = (HOLDS if n_small >= len(slope) - 1 else
               PARTLY if n_small >= len(slope) / 2 else FAILS)
    return ClaimCheck("Figure 4", claim("fig4_K", "time_linear"), evidence, verdict)


def check_K(s: pd.DataFrame, timing: pd.DataFrame | None = None,
            calls: pd.DataFrame | None = None) -> list[ClaimCheck]:
    """Figure 4's claims (paper_values review.claims.fig4_K).

    The time claim is judged on the scaling benchmark (``bench/calls.csv``: K = 1000 to
    10000, where a call's fixed overhead is small) when ``calls`` is given; the sweep's own
    K <= 300 (timing pass, or per-trial times) is reported beside it, since there the fixed
    overhead dominates and no slope says much about the growth.
    """
    return [_flat_robustness(s, "K", "Figure 4", claim("fig4_K", "robustness_flat")),
            *_K_accuracy(s), _K_time(s, timing, calls)]


def _decades_per_decade(s: pd.DataFrame, column: str, names: list[str]) -> pd.Series:
    """Slope of log10(column) against log10(sigma^2) per method (the review's axis)."""
    acc = pivot(s, "sigma", column, names)
    xs = np.log10(np.asarray(acc.columns, dtype=float) ** 2)
    return acc.apply(lambda r: np.polyfit(xs, np.log10(r.to_numpy(float)), 1)[0]
                     if r.notna().all() else np.nan, axis=1)


def check_sigma(s: pd.DataFrame) -> list[ClaimCheck]:
    """Figure 5's claims (paper_values review.claims.fig5_sigma).

    The review's text and Figure 5's axis speak of the variance sigma^2: 'an increase of one
    order in variance resulted to a decrease of one order in accuracy'. 1/rho (mean J) falls
    half a decade per decade of sigma^2; the squared metric 1/mean(J_h^2 + J_T^2) (``mse``)
    one. The claim is judged on the squared metric, the reading of the review's accuracy
    column that Table 2 supports, with 1/rho beside it.
    """
    out = [_flat_robustness(s, "sigma", "Figure 5", claim("fig5_sigma", "robustness_flat"))]
    five = ["magical", "ali", "vasconcelos", "dorveaux", "wu_shi"]
    plain = _decades_per_decade(s, "accuracy", five)
    squared = (-_decades_per_decade(s, "mse", five) if "mse" in s
               else pd.Series(np.nan, index=plain.index))
    n_ok = int(squared.between(-1.2, -0.8).sum())
    out.append(ClaimCheck(
        "Figure 5", claim("fig5_sigma", "decade_per_decade"),
        "decades of accuracy per decade of the variance sigma^2 (the review's axis and "
        f"word): squared metric 1/mean(J_h^2 + J_T^2) {_fmt_series(squared, 3)}; 1/rho "
        f"{_fmt_series(plain, 3)}. One for one in the squared metric, half in 1/rho: the "
        "review's statement supports the squared reading of its accuracy (Table 2)",
        _verdict(n_ok, 5)))
    return out


def check_real(results_dir: Path, baseline: pd.DataFrame | None) -> list[ClaimCheck]:
    """Figure 6's claim: real-data robustness agrees with the synthetic baseline."""
    path = Path(results_dir) / "real" / "fig6_real.csv"
    text = claim("fig6_real", "agrees_with_synthetic")
    if not path.exists() or baseline is None:
        return [ClaimCheck("Figure 6", text, "no real-data results in this run", MISSING)]
    # Exactly what Figure 6 (b) plots, under the review's preprocessing (scaling only).
    per_method = pd.read_csv(path)
    real_rb = per_method[per_method["preprocess"] == "scale"].set_index("algorithm")["RB_pct"]
    synth_rb = baseline.set_index("algorithm")["RB_pct"]
    shown = [n for n in REVIEW if n in real_rb.index]
    agree = [n for n in shown if abs(real_rb[n] - synth_rb[n]) <= 10]
    return [ClaimCheck("Figure 6", text,
                       "RB % on the real recordings (the review's scaling) / synthetic "
                       "baseline: " + "; ".join(f"{method_label(n)} {real_rb[n]:.3g} / "
                                                f"{synth_rb[n]:.3g}" for n in shown),
                       HOLDS if len(agree) == len(shown) else
                       PARTLY if len(agree) >= len(shown) / 2 else FAILS)]


def _all_review(summary: pd.DataFrame | None) -> bool:
    return summary is not None and set(REVIEW) <= set(summary["algorithm"])


def all_checks(results_dir: Path) -> list[ClaimCheck]:
    """Every claim of the review checked on the sweeps under ``results_dir`` (a claim whose
    sweep is absent is left out; Figure 6's says it was not evaluated)."""
    results_dir = Path(results_dir)
    load = partial(load_csv, results_dir)
    gamma, beta, K, sigma = (load(s) for s in ("gamma", "beta", "K", "sigma"))
    checks: list[ClaimCheck] = []
    if gamma is not None:
        checks += check_gamma(gamma, load("gamma", "timing.csv"))
    # the other figures' claims name most of the review's seven: judged on sweeps of all
    if _all_review(beta):
        checks += check_beta(beta, gamma if _all_review(gamma) else None,
                             load_trials(results_dir / "beta"))
    if _all_review(K):
        checks += check_K(K, load("K", "timing.csv"), load("bench", "calls.csv"))
    if _all_review(sigma):
        checks += check_sigma(sigma)
    return checks + check_real(results_dir, load("baseline"))


def claims_section(results_dir: Path) -> str:
    """Markdown: the table of the review's claims with evidence and verdicts."""
    rows = [f"| {c.figure} | {c.claim} | {c.evidence} | **{c.verdict}** |"
            for c in all_checks(results_dir)]
    return "\n".join(["## The paper's claims, checked", "", render("claims.intro"), "",
                      "| figure | claim | evidence | verdict |", "|---|---|---|---|",
                      *rows, ""])
