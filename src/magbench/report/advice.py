"""The report's opening: which method to use when, computed from the sweep summaries."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.methods.registry import find_method, method_label
from magbench.report.format import format_number, names, render
from magbench.report.intervals import annotate, cell, rb_interval, significantly_different
from magbench.report.load import load_csv, load_trials
from magbench.report.matched import Paired, paired
from magbench.studies.review import with_coverage_column

__all__ = ["MEDIAN_ALIKE", "RECOMMEND_EFFICIENCY", "RECOMMEND_RB_PCT", "STRESS_CONDITIONS",
           "advice_section", "gyro_line", "recommendations", "stress_line", "tail_note"]

#: A method counts as "as good as any" at the baseline when it is this robust and efficient.
RECOMMEND_RB_PCT, RECOMMEND_EFFICIENCY = 99.0, 0.9
#: (sweep, swept column, condition, figure) of the "which method when" rows read at the
#: sweep's hardest point: the largest offset, the strongest distortion, the fewest samples,
#: the most noise.
STRESS_CONDITIONS = (
    ("gamma", "gamma", "Large offset", "Fig. 2"),
    ("beta", "beta", "Strong non-orthogonality and scale errors", "Fig. 3"),
    ("K", "K", "Few samples", "Fig. 4"),
    ("sigma", "sigma", "Noisy measurements", "Fig. 5"),
)


def advice_section(results_dir: Path) -> str:
    """Markdown of the opening advice ('' when no sweep has results)."""
    load = {s: load_csv(results_dir, s) for s in ("baseline", "coverage", "gamma", "beta", "K",
                                                  "sigma", "gyro")}
    baseline = load["baseline"]
    if baseline is not None:       # Table 2's speed: the timing pass's when there is one
        baseline = annotate(baseline, None, load_csv(results_dir, "baseline", "timing.csv"))
    trials = {key: load_trials(Path(results_dir) / key) for key, *_ in STRESS_CONDITIONS}
    trials["gyro"] = load_csv(results_dir, "gyro", "trials.csv")
    lines = recommendations(baseline, load["coverage"], load, trials)
    return "\n".join([render("advice.title"), "", *lines, ""]) if lines else ""


def _family(name: str) -> str:
    spec = find_method(name)
    return "extra" if spec is None else spec.family


def _needs_gyro(name: str) -> bool:
    spec = find_method(name)
    return spec is not None and spec.needs_gyro


def _advisable(rows: pd.DataFrame) -> pd.DataFrame:
    """``rows`` without the review's printed variants (benchmark rows, never advice)."""
    return rows[[_family(n) != "variant" for n in rows["algorithm"]]]


def _fastest_caveat(name: str, summaries: dict, trials: dict) -> str:
    """Where the fastest of the equally good methods stops being as good: the hardest points
    at which its accuracy, matched, is below 0.9 of the most accurate robust method's."""
    misses = []
    for key, column, _, figure in STRESS_CONDITIONS:
        summary, rows = summaries.get(key), trials.get(key)
        if summary is None or rows is None or column not in summary:
            continue
        hard = _advisable(_hardest(summary, column))
        robust = list(hard[hard["RB_pct"] >= RECOMMEND_RB_PCT]["algorithm"])
        point = rows[rows[column] == hard[column].iloc[0]]
        if name not in robust:
            continue
        best = _most_accurate(point, robust)
        p = paired(point, best, name, key=("advice", best))
        if p.ratio < 0.9:
            misses.append(f"at {column} = {hard[column].iloc[0]:g} ({figure}) it keeps "
                          f"{format_number(p.ratio, 2)} of {method_label(best)}'s accuracy on "
                          f"the same {p.n} datasets")
    return (" But " + "; ".join(misses) + ": see the rows below." if misses else "")


def _baseline_lines(baseline: pd.DataFrame, summaries: dict | None = None,
                    trials: dict | None = None) -> list[str]:
    b = _advisable(baseline)
    good = b[(b["RB_pct"] >= RECOMMEND_RB_PCT)
             & (b.get("efficiency", pd.Series(1.0, index=b.index)) >= RECOMMEND_EFFICIENCY)]
    lines = []
    if not good.empty:
        speed = "speed" if "speed" in good else "speed_hz"
        fastest = good.sort_values(speed, ascending=False).iloc[0]
        lines.append(render(
            "advice.whole_sphere", n_good=len(good), rb=RECOMMEND_RB_PCT,
            within=100 * (1 - RECOMMEND_EFFICIENCY),
            acc_lo=format_number(good["accuracy"].min()),
            acc_hi=format_number(good["accuracy"].max()), good=names(good["algorithm"]),
            fastest=method_label(fastest["algorithm"]),
            speed=format_number(fastest[speed]), K=int(fastest["K"]),
            source="Table 2's speed" if speed == "speed" else "per-trial times"))
        lines[-1] += _fastest_caveat(fastest["algorithm"], summaries or {}, trials or {})
    poor = b[~b.index.isin(good.index)]
    if not poor.empty:
        lines.append(render("advice.not_full", poor="; ".join(
            f"{method_label(r.algorithm)} (RB {r.RB_pct:.3g} %, 1/rho "
            f"{format_number(r.accuracy)})" for r in poor.itertuples())))
    return lines


def _coverage_line(coverage: pd.DataFrame) -> str:
    c = _advisable(with_coverage_column(coverage))
    # Partial but wide: caps of a hemisphere or more, and every band.
    wide = c[((c["coverage"] != "full sphere") & (c["cap_deg"] >= 90)) | (c["band_deg"] < 90)]
    robust = [cov for cov, rows in wide.groupby("coverage", sort=False)
              if (rows["RB_pct"] >= RECOMMEND_RB_PCT).any()]
    narrow = c[(c["cap_deg"] < 90) & (c["band_deg"] >= 90)]
    best = []
    for cov, rows in narrow.groupby("coverage", sort=False):
        top = rows.sort_values("RB_pct", ascending=False)
        near = [method_label(n) for n in top["algorithm"][1:][top["RB_pct"][1:]
                                                               >= top["RB_pct"].iloc[0] - 10]]
        best.append(f"{cov}: {method_label(top['algorithm'].iloc[0])} "
                    f"{top['RB_pct'].iloc[0]:.3g} %"
                    + (f" ({', '.join(near)} within 10 points)" if near else ""))
    if not best:
        return ""
    prefix = (render("advice.coverage_robust", caps=", ".join(robust), rb=RECOMMEND_RB_PCT) + " "
              if robust else "")
    return render("advice.coverage", robust=prefix, best="; ".join(best))


def recommendations(baseline: pd.DataFrame | None, coverage: pd.DataFrame | None,
                    summaries: dict[str, pd.DataFrame | None] | None = None,
                    trials: dict[str, pd.DataFrame | None] | None = None) -> list[str]:
    """The report's opening: which method to use when, computed from the sweep summaries.

    ``summaries`` holds the other sweeps' summaries by name (``gamma``, ``beta``, ``K``,
    ``gyro``) for their rows, and ``trials`` their trials (accuracies are then compared on
    matched datasets). Only registered methods outside the ``variant`` family (the review's
    printed formulas, kept to explain its numbers) are recommended.
    """
    summaries, trials = summaries or {}, trials or {}
    lines = _baseline_lines(baseline, summaries, trials) if baseline is not None else []
    if coverage is not None:
        lines.append(_coverage_line(coverage))
    lines += [stress_line(summaries.get(key), column, title, figure, trials.get(key))
              for key, column, title, figure in STRESS_CONDITIONS]
    lines.append(gyro_line(summaries.get("gyro"), trials.get("gyro")))
    lines = [line for line in lines if line]
    if lines:
        lines.append(render("advice.own_recording"))
    return lines


def _hardest(summary: pd.DataFrame, column: str) -> pd.DataFrame:
    """The rows of the sweep's hardest point (smallest K, else the largest value)."""
    value = summary[column].min() if column == "K" else summary[column].max()
    return summary[summary[column] == value]
def stress_line(summary: pd.DataFrame | None, column: str, title: str, figure: str,
                trials: pd.DataFrame | None = None) -> str:
    """One "which method when" row: who stays robust at the sweep's hardest point, and the most
    accurate of them (or the most robust, when none reaches RB >= 99 %).

    With the sweep's ``trials``, accuracies are compared on matched datasets
    (:func:`_matched_top`): each method against the most accurate on the runs meaningful for
    both, with the paired interval saying whether the difference is real.
    """
    if summary is None or summary.empty or column not in summary:
        return ""
    rows = _advisable(_hardest(summary, column))
    if rows.empty:
        return ""
    value = rows[column].iloc[0]
    where = f"**{title}** ({figure}, {column} = {value:g}, {int(rows['n'].max())} datasets)"
    robust = rows[rows["RB_pct"] >= RECOMMEND_RB_PCT].sort_values("accuracy", ascending=False)
    if robust.empty:
        top = rows.sort_values("RB_pct", ascending=False).iloc[0]
        return (f"- {where}: no method keeps RB >= {RECOMMEND_RB_PCT:g} %; the most robust is "
                f"{method_label(top['algorithm'])} (RB {top['RB_pct']:.3g} %).")
    fragile = rows[rows["RB_pct"] < RECOMMEND_RB_PCT].sort_values("RB_pct")
    if trials is None:
        best = robust.iloc[0]
        near = robust[robust["accuracy"] >= 0.9 * best["accuracy"]]
        lo, hi = format_number(near["accuracy"].min()), format_number(best["accuracy"])
        top = (f"the most accurate are {names(near['algorithm'])} (1/rho "
               f"{lo if lo == hi else f'{lo}-{hi}'})")
    else:
        top = _matched_top(robust, fragile, trials[trials[column] == value])
        tail = tail_note(trials[trials[column] == value], list(robust["algorithm"]))
        top += f" ({tail})" if tail else ""
    return (f"- {where}: {len(robust)} methods keep RB >= {RECOMMEND_RB_PCT:g} %; {top}"
            + (f"; least robust: {_worst(fragile)}" if not fragile.empty else "") + ".")


#: Robust methods whose median J (on the runs meaningful for all) differ by less than this
#: (relative) are alike in the typical run.
MEDIAN_ALIKE = 0.05


def tail_note(point: pd.DataFrame, candidates: list[str]) -> str:
    """'' unless the candidates' median J on the runs meaningful for all of them are alike
    (within :data:`MEDIAN_ALIKE`) while their mean J spread at least twice as wide: then the
    ranking by the mean (1/rho) rests on the tail runs, and the note says so with both
    spreads."""
    rows = point[point["algorithm"].isin(candidates)]
    if rows.empty or len(candidates) < 2:
        return ""
    ok = rows.assign(meaningful=rows["meaningful"].astype(bool)).pivot(
        index="trial", columns="algorithm", values="meaningful").eq(True).all(axis=1)
    J = rows.pivot(index="trial", columns="algorithm", values="J").loc[ok[ok].index]
    if len(J) < 2:
        return ""
    med, mean = J.median(), J.mean()
    med_spread, mean_spread = med.max() / med.min() - 1, mean.max() / mean.min() - 1
    if med_spread >= MEDIAN_ALIKE or mean_spread < 2 * med_spread:
        return ""
    return (f"median J {format_number(med.min())}-{format_number(med.max())} for all "
            f"{len(med)} on the {len(J)} runs meaningful for all (within "
            f"{100 * med_spread:.2g} %), mean J {100 * mean_spread:.2g} % apart: the ranking "
            "rests on the tail runs")


def _span(values: list[float], digits: int = 3) -> str:
    lo, hi = format_number(min(values), digits), format_number(max(values), digits)
    return lo if lo == hi else f"{lo}-{hi}"


def _most_accurate(point: pd.DataFrame, candidates: list[str]) -> str:
    """The method of ``candidates`` with the lowest mean J on the datasets meaningful for all
    of them (the first candidate when they share none)."""
    rows = point[point["algorithm"].isin(candidates)]
    ok = rows.assign(meaningful=rows["meaningful"].astype(bool)).pivot(
        index="trial", columns="algorithm", values="meaningful")
    common = ok.reindex(columns=candidates).eq(True).all(axis=1)
    J = rows.pivot(index="trial", columns="algorithm", values="J").loc[common[common].index]
    return str(J.mean().idxmin()) if len(J) else candidates[0]


def _matched_top(robust: pd.DataFrame, fragile: pd.DataFrame, point: pd.DataFrame) -> str:
    """The most accurate robust methods on matched datasets, and any less robust method that
    is more accurate on the datasets it solves."""
    best = _most_accurate(point, list(robust["algorithm"]))
    versus = {n: paired(point, best, n, key=("advice", best)) for n in robust["algorithm"]}
    near = sorted((n for n, p in versus.items() if p.ratio >= 0.9),
                  key=lambda n: -versus[n].ratio)
    ns = [versus[n].n for n in near if n != best] or [versus[best].n]
    apart = [n for n in near if n != best and versus[n].different]
    ratios = [versus[n].ratio for n in near]
    text = (f"the most accurate are {names(near)} (accuracy {_span(ratios, 2)} of "
            f"{method_label(best)}'s on the {_span(ns)} datasets meaningful for both; "
            + (f"apart beyond the 95 % paired intervals: {names(apart)})" if apart else
               "no difference beyond the 95 % paired intervals: a tie)"))
    better = []
    for r in fragile[fragile["RB_pct"] >= 90].itertuples():
        p = paired(point, best, r.algorithm, key=("advice", best))
        if p.different and p.ratio > 1:
            better.append(f"{method_label(r.algorithm)} (RB {r.RB_pct:.3g} %) is "
                          f"{format_number(p.ratio, 2)}x as accurate as {method_label(best)} "
                          f"on the {p.n} datasets both solve")
    return text + ("; " + "; ".join(better) if better else "")


def _worst(rows: pd.DataFrame, n: int = 3) -> str:
    """The ``n`` least robust methods of ``rows`` (sorted by RB), with their RB %."""
    return ", ".join(f"{method_label(r.algorithm)} (RB {r.RB_pct:.3g} %)"
                     for r in rows.head(n).itertuples())


def gyro_line(summary: pd.DataFrame | None, trials: pd.DataFrame | None = None) -> str:
    """The "gyro available" row: at the gyro sweep's largest gyro noise, on every manoeuvre,
    the most robust gyro-aided method beside the most robust magnetometer-only one, RB % with
    Wilson intervals (a difference counts beyond them) and, with ``trials``, their accuracy on
    the manoeuvres both solve (paired)."""
    if summary is None or summary.empty or "coverage" not in summary:
        return ""
    noisy = _advisable(summary[summary["gyro_noise"] == summary["gyro_noise"].max()])
    parts, robust, accurate = [], [], []
    for cov, hard in noisy.groupby("coverage", sort=False):
        gyro = hard[[_needs_gyro(n) for n in hard["algorithm"]]]
        mag = hard[[not _needs_gyro(n) for n in hard["algorithm"]]]
        if gyro.empty or mag.empty:
            continue
        g = gyro.sort_values(["RB_pct", "accuracy"], ascending=False).iloc[0]
        m = mag.sort_values(["RB_pct", "accuracy"], ascending=False).iloc[0]
        apart = significantly_different(rb_interval(g), rb_interval(m))
        parts.append(f"'{cov}': {method_label(g['algorithm'])} RB "
                     f"{cell(g['RB_pct'], rb_interval(g), 3)} % against "
                     f"{method_label(m['algorithm'])} {cell(m['RB_pct'], rb_interval(m), 3)} %"
                     + ("" if apart else " (within the intervals)"))
        if apart and g["RB_pct"] > m["RB_pct"]:
            robust.append(f"'{cov}'")
        p = _gyro_accuracy(trials, cov, g, m)
        if p is not None and p.n:
            parts[-1] += (f", accuracy {format_number(p.ratio, 2)}x "
                          f"{method_label(m['algorithm'])}'s [{format_number(p.low, 2)}, "
                          f"{format_number(p.high, 2)}] on the {p.n} manoeuvres both solve")
            if p.different and p.ratio > 1:
                accurate.append(f"'{cov}'")
    if not parts:
        return ""
    return (f"- **Gyro available** (gyro sweep, gyro noise {noisy['gyro_noise'].iloc[0]:g} "
            f"rad/s, {int(noisy['n'].max())} runs per manoeuvre; the most robust gyro-aided "
            "method against the most robust magnetometer-only one, RB with its 95 % Wilson "
            "interval, accuracy with its 95 % paired interval): " + "; ".join(parts) + ". "
            f"The gyro raises RB beyond the intervals on: {', '.join(robust) or 'no manoeuvre'}"
            f"; accuracy on: {', '.join(accurate) or 'no manoeuvre'}.")


def _gyro_accuracy(trials: pd.DataFrame | None, cov: str, g: pd.Series, m: pd.Series
                   ) -> Paired | None:
    """Accuracy of the gyro-aided ``g`` over the magnetometer-only ``m`` on the manoeuvres
    both solve (None without trials)."""
    if trials is None:
        return None
    point = trials[(trials["coverage"] == cov) & (trials["gyro_noise"] == g["gyro_noise"])]
    return paired(point, m["algorithm"], g["algorithm"], key=("gyro", cov))
