"""Report section of the heading study, from ``<results_dir>/heading`` CSV files alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.intervals import median_interval
from magbench.methods.registry import get_method

__all__ = ["heading_report_section", "proxy_verdict"]

_TITLE = "## Heading truth: the direction a calibration gives"


def _label(name: str) -> str:
    try:
        spec = get_method(name)
    except ValueError:
        return name
    return spec.label + (" *" if spec.needs_gyro else "")


def _cell(value: float, fmt: str = ".2f") -> str:
    return "-" if not np.isfinite(value) else format(value, fmt)


def proxy_verdict(rho: float) -> str:
    """How well a rank correlation lets a magnitude metric stand for the heading error."""
    if not np.isfinite(rho):
        return "cannot be judged (too few runs)"
    if rho >= 0.7:
        return "a fair proxy"
    if rho >= 0.3:
        return "a weak proxy"
    return "no proxy"


def _median_cell(trials: pd.DataFrame, part: str, name: str, median: float) -> str:
    """The median heading RMS with its 95 % interval over the units that ran
    (:func:`~magbench.core.intervals.median_interval`)."""
    rows = trials[(trials["part"] == part) & (trials["algorithm"] == name)
                  & trials["ok"].astype(bool)]
    lo, hi = median_interval(rows["heading_rms"].to_numpy(float))
    if not np.isfinite(median) or not np.isfinite(lo):
        return _cell(median)
    return f"{median:.2f} [{lo:.2f}, {hi:.2f}]"


def _method_table(summary: pd.DataFrame, trials: pd.DataFrame) -> list[str]:
    parts = [p for p in ("semi", "given", "mc") if (summary["part"] == p).any()]
    wide = {p: summary[summary["part"] == p].set_index("algorithm") for p in parts}
    order = (wide["semi"]["heading_rms"].sort_values().index.tolist() if "semi" in wide
             else list(dict.fromkeys(summary["algorithm"])))
    order += [n for n in dict.fromkeys(summary["algorithm"]) if n not in order]
    head = {"semi": ["semi heading (deg)", "semi J", "semi ok"],
            "given": ["as given heading (deg)", "as given J_r", "as given ok"],
            "mc": ["simulated heading (deg)", "simulated J", "simulated ok"]}
    lines = ["| method | " + " | ".join(c for p in parts for c in head[p]) + " |",
             "|---|" + "---:|" * (3 * len(parts))]
    for name in order:
        cells = []
        for p in parts:
            r = wide[p].loc[name] if name in wide[p].index else None
            if r is None:
                cells += ["-", "-", "-"]
                continue
            metric = "J_r" if p == "given" else "J"
            cells += [_median_cell(trials, p, name, float(r["heading_rms"])),
                      _cell(r[metric], ".2g"),
                      f"{int(r['n_ok'])}/{int(r['n'])}"]
        lines.append(f"| {_label(name)} | " + " | ".join(cells) + " |")
    floors = []
    for p in parts:
        floors += [_cell(wide[p]["heading_floor"].median()), "", ""]
    lines.append("| *true calibration (semi, simulated) / as given* | " + " | ".join(floors)
                 + " |")
    return lines


def _correlation_lines(corr: pd.DataFrame) -> list[str]:
    lines = ["| part | dataset | Spearman (heading, J) | n | Spearman (heading, J_r) | n |",
             "|---|---|---:|---:|---:|---:|"]
    for _, r in corr.iterrows():
        lines.append(f"| {r['part']} | {r['dataset']} | {_cell(r['spearman_J'])} | "
                     f"{int(r['n_J'])} | {_cell(r['spearman_J_r'])} | {int(r['n_J_r'])} |")
    return lines


def _best(summary: pd.DataFrame, part: str) -> str:
    """The method with the lowest median heading RMS among those that ran on every unit, the
    methods within 5 % of it (a tie at this size), and how far it is from the floor."""
    s = summary[(summary["part"] == part) & (summary["n_ok"] == summary["n"])]
    s = s[np.isfinite(s["heading_rms"])].sort_values("heading_rms")
    if s.empty:
        return ""
    top = s.iloc[0]
    tied = [_label(n) for n in s["algorithm"].iloc[1:][s["heading_rms"].iloc[1:]
                                                        <= 1.05 * top["heading_rms"]]]
    text = f"{_label(top['algorithm'])} at {top['heading_rms']:.2f} deg"
    if tied:
        shown = ", ".join(tied[:4]) + (f" and {len(tied) - 4} more" if len(tied) > 4 else "")
        text += f", tied within 5 % with {shown}"
    floor = top["heading_floor"]
    if np.isfinite(floor) and floor > 0:
        text += f" ({top['heading_rms'] / floor:.1f} x the {floor:.2f} deg floor)"
    return text


def _answer(summary: pd.DataFrame, corr: pd.DataFrame) -> list[str]:
    names = {"semi": "the semi-synthetic BROAD data", "given": "the BROAD recordings as given",
             "mc": "the simulated manoeuvres"}
    best = [f"on {names[p]} {b}" for p in ("semi", "given", "mc") if (b := _best(summary, p))]
    lines = []
    if best:
        lines.append("**Best heading** (median heading RMS over the units, among methods "
                     "that ran on every unit): " + "; ".join(best) + ".")
    for part, metric in (("semi", "J"), ("mc", "J"), ("given", "J_r")):
        sel = corr[(corr["part"] == part)]
        pooled = sel[sel["dataset"] == "pooled"]
        row = pooled if len(pooled) else sel
        if not len(row):
            continue
        rho = float(row[f"spearman_{metric}"].iloc[0])
        per = sel[sel["dataset"] != "pooled"][f"spearman_{metric}"]
        spread = (f" (per dataset {per.min():.2f} to {per.max():.2f})"
                  if len(per) > 1 and per.notna().any() else "")
        verdict = proxy_verdict(rho)
        kinds = {proxy_verdict(v) for v in per.dropna()} if len(per) > 1 else set()
        if len(kinds) > 1:        # the pooled figure hides datasets on either side
            fair = per[per >= 0.7]
            verdict = (f"pooled {verdict}, but it depends on the dataset: "
                       + (f"a fair proxy on {len(fair)} of {per.notna().sum()} "
                          f"({', '.join(f'{v:.2f}' for v in fair)}), "
                          f"{' or '.join(sorted(kinds - {'a fair proxy'}))} on the others"
                          if len(fair) else " or ".join(sorted(kinds)) + " by dataset"))
        lines.append(f"**Is {metric} a proxy for the heading error** on {names[part]}? "
                     f"Spearman rho = {rho:.2f}{spread}: {verdict}."
                     + (" Structurally so: a magnetometer-only heading follows the "
                        "mounting rotation, which no magnetometer-only fit can observe and "
                        "J (74), invariant to that rotation, cannot see; J ranks the "
                        "magnitude errors only." if part == "mc" and rho < 0.7 else ""))
    return lines


def _lag_line(trials: pd.DataFrame) -> str:
    if "gyro_lag_ms" not in trials:          # results of a version without it
        trials = trials.assign(gyro_lag_ms=np.nan)
    recorded = trials[trials["part"] != "mc"].groupby("dataset")[["lag_ms", "gyro_lag_ms"]]
    lags = recorded.first()
    if lags.empty:
        return ""
    shown = ", ".join(f"{d} {r['lag_ms']:.1f} ms" + (f" (gyro {r['gyro_lag_ms']:.1f} ms)"
                                                     if np.isfinite(r["gyro_lag_ms"]) else "")
                      for d, r in lags.iterrows())
    return ("Measured lag behind the optical reference, magnetometer (gyro), removed by "
            f"resampling before fitting and scoring: {shown}.")


def heading_report_section(results_dir: Path | str) -> str:
    """Markdown for the report: per method the heading error on the semi-synthetic BROAD data
    beside J (and on the recordings as given beside J_r, and on the simulation), the rank
    correlation of heading error with J, which method points best on what data, and the
    figures. Reads only ``<results_dir>/heading``."""
    folder = Path(results_dir) / "heading"
    if not (folder / "summary.csv").exists():
        return f"{_TITLE}\n\nNo results yet: run `python -m magbench sweep=heading`.\n"
    summary = pd.read_csv(folder / "summary.csv")
    corr = pd.read_csv(folder / "correlation.csv")
    trials = pd.read_csv(folder / "heading_trials.csv")
    lines = [_TITLE, "",
             "Heading error: BROAD's definition (2 atan(|z/w|) of the world-frame error "
             "quaternion), RMS over the movement phase, median over units. A "
             "magnetometer-only method is scored in the symmetric gauge it is written in (it "
             "cannot know the sensor's rotation); a method given inertial data (*) as "
             "returned. J is eq. (74) against the applied distortion, J_r eq. (81). 'ok' "
             "counts units where the method ran and ended normally. Brackets: the 95 % "
             "interval of the median over those units (order statistics; with fewer than six "
             "units the range).", ""]
    lines += _method_table(summary, trials) + [""]
    lines += _answer(summary, corr) + [""]
    given_attitude = sorted({_label(n) for n, inputs in zip(trials["algorithm"],
                                                            trials["inputs"].astype(str),
                                                            strict=True)
                             if "attitude" in str(inputs).split()})
    if given_attitude:
        verb = "takes" if len(given_attitude) == 1 else "take"
        lines += [f"{', '.join(given_attitude)} also {verb} the reference attitude and field "
                  "as inputs (by design), so its heading is not a blind estimate.", ""]
    lag = _lag_line(trials)
    if lag:
        lines += [lag, ""]
    lines += _correlation_lines(corr) + [""]
    lines += ["![heading error per method](heading/heading_error.png) "
              "(numbers: `heading/heading_error.csv`)", "",
              "![heading error against J](heading/heading_vs_J.png) "
              "(numbers: `heading/heading_vs_J.csv`)", ""]
    return "\n".join(lines)
