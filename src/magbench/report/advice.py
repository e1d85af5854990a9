"""The report's opening: which method to use when, computed from the sweep summaries."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.methods.registry import find_method, method_label
from magbench.report.format import format_number, names, render
from magbench.report.intervals import annotate
from magbench.report.load import load_csv
from magbench.studies.review import with_coverage_column

__all__ = ["RECOMMEND_EFFICIENCY", "RECOMMEND_RB_PCT", "STRESS_CONDITIONS", "advice_section",
           "gyro_line", "recommendations", "stress_line"]

#: A method counts as "as good as any" at the baseline when it is this robust and efficient.
RECOMMEND_RB_PCT, RECOMMEND_EFFICIENCY = 99.0, 0.9
#: (sweep, swept column, condition, figure) of the "which method when" rows read at the
#: sweep's hardest point: the largest offset, the strongest distortion, the fewest samples.
STRESS_CONDITIONS = (
    ("gamma", "gamma", "Large offset", "Fig. 2"),
    ("beta", "beta", "Strong non-orthogonality and scale errors", "Fig. 3"),
    ("K", "K", "Few samples", "Fig. 4"),
)


def advice_section(results_dir: Path) -> str:
    """Markdown of the opening advice ('' when no sweep has results)."""
    load = {s: load_csv(results_dir, s) for s in ("baseline", "coverage", "gamma", "beta", "K",
                                                  "gyro")}
    baseline = load["baseline"]
    if baseline is not None:       # Table 2's speed: the timing pass's when there is one
        baseline = annotate(baseline, None, load_csv(results_dir, "baseline", "timing.csv"))
    lines = recommendations(baseline, load["coverage"], load)
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


def _baseline_lines(baseline: pd.DataFrame) -> list[str]:
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
                    summaries: dict[str, pd.DataFrame | None] | None = None) -> list[str]:
    """The report's opening: which method to use when, computed from the sweep summaries.

    ``summaries`` holds the other sweeps' summaries by name (``gamma``, ``beta``, ``K``,
    ``gyro``) for their rows. Only registered methods outside the ``variant`` family (the
    review's printed formulas, kept to explain its numbers) are recommended.
    """
    summaries = summaries or {}
    lines = _baseline_lines(baseline) if baseline is not None else []
    if coverage is not None:
        lines.append(_coverage_line(coverage))
    lines += [stress_line(summaries.get(key), column, title, figure)
              for key, column, title, figure in STRESS_CONDITIONS]
    lines.append(gyro_line(summaries.get("gyro")))
    lines = [line for line in lines if line]
    if lines:
        lines.append(render("advice.own_recording"))
    return lines


def _hardest(summary: pd.DataFrame, column: str) -> pd.DataFrame:
    """The rows of the sweep's hardest point (smallest K, else the largest value)."""
    value = summary[column].min() if column == "K" else summary[column].max()
    return summary[summary[column] == value]
def stress_line(summary: pd.DataFrame | None, column: str, title: str, figure: str) -> str:
    """One "which method when" row: who stays robust at the sweep's hardest point, and the most
    accurate of them (or the most robust, when none reaches RB >= 99 %)."""
    if summary is None or summary.empty or column not in summary:
        return ""
    rows = _hardest(summary, column)
    rows = _advisable(rows)
    if rows.empty:
        return ""
    value = rows[column].iloc[0]
    where = f"**{title}** ({figure}, {column} = {value:g}, {int(rows['n'].max())} datasets)"
    robust = rows[rows["RB_pct"] >= RECOMMEND_RB_PCT].sort_values("accuracy", ascending=False)
    if robust.empty:
        top = rows.sort_values("RB_pct", ascending=False).iloc[0]
        return (f"- {where}: no method keeps RB >= {RECOMMEND_RB_PCT:g} %; the most robust is "
                f"{method_label(top['algorithm'])} (RB {top['RB_pct']:.3g} %).")
    best = robust.iloc[0]
    near = robust[robust["accuracy"] >= 0.9 * best["accuracy"]]
    fragile = rows[rows["RB_pct"] < RECOMMEND_RB_PCT].sort_values("RB_pct")
    lo, hi = format_number(near["accuracy"].min()), format_number(best["accuracy"])
    return (f"- {where}: {len(robust)} methods keep RB >= {RECOMMEND_RB_PCT:g} %; the most "
            f"accurate are {', '.join(method_label(n) for n in near['algorithm'])} (1/rho "
            f"{lo if lo == hi else f'{lo}-{hi}'})"
            + (f"; least robust: {_worst(fragile)}" if not fragile.empty else "") + ".")


def _worst(rows: pd.DataFrame, n: int = 3) -> str:
    """The ``n`` least robust methods of ``rows`` (sorted by RB), with their RB %."""
    return ", ".join(f"{method_label(r.algorithm)} (RB {r.RB_pct:.3g} %)"
                     for r in rows.head(n).itertuples())


def gyro_line(summary: pd.DataFrame | None) -> str:
    """The "gyro available" row: on the gyro sweep's narrowest manoeuvre at the largest gyro
    noise, the most robust gyro-aided method beside the most robust magnetometer-only one."""
    if summary is None or summary.empty or "coverage" not in summary:
        return ""
    hard = summary[(summary["coverage"] == summary["coverage"].iloc[-1])
                   & (summary["gyro_noise"] == summary["gyro_noise"].max())]
    hard = _advisable(hard)
    gyro = hard[[_needs_gyro(n) for n in hard["algorithm"]]]
    mag = hard[[not _needs_gyro(n) for n in hard["algorithm"]]]
    if gyro.empty or mag.empty:
        return ""
    g = gyro.sort_values(["RB_pct", "accuracy"], ascending=False).iloc[0]
    m = mag.sort_values(["RB_pct", "accuracy"], ascending=False).iloc[0]
    better = (g["RB_pct"], g["accuracy"]) > (m["RB_pct"], m["accuracy"])
    return (f"- **Gyro available** (gyro sweep, the '{g['coverage']}' manoeuvre, gyro noise "
            f"{g['gyro_noise']:g} rad/s, {int(hard['n'].max())} runs): the best gyro-aided "
            f"method is {method_label(g['algorithm'])} (RB {g['RB_pct']:.3g} %, 1/rho "
            f"{format_number(g['accuracy'])}), the best magnetometer-only one "
            f"{method_label(m['algorithm'])} (RB {m['RB_pct']:.3g} %, 1/rho "
            f"{format_number(m['accuracy'])}): "
            + ("the gyro helps here." if better else
               "no gain from the gyro here over the best magnetometer-only fit."))
