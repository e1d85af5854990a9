"""Report section of the generalisation study, from ``<results_dir>/generalisation`` CSVs alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.verdict import Gate
from magbench.report.intervals import run_note

__all__ = ["generalisation_section", "headline"]

FOLDER = "generalisation"


def _pct(k: int, n: int) -> str:
    return f"{k} of {n} ({100 * k / n:.0f} %)" if n else "0 of 0"


def headline(cases: pd.DataFrame) -> dict:
    """The numbers the section leads with: cases, losses, harmful writes, needless FAILs."""
    return {"cases": len(cases), "losses": int(cases["loss"].sum()),
            "harmful": int(cases["harmful"].sum()),
            "harmful_mean_norm": int(cases["harmful_mean_norm"].sum()),
            "direction_cases": int(np.isfinite(cases["raw_direction_deg"].to_numpy(float)).sum()),
            "losses_direction": int(cases["loss_direction"].sum()),
            "heading_cases": int(np.isfinite(cases["raw_heading_deg"].to_numpy(float)).sum()),
            "losses_heading": int(cases["loss_heading"].sum()),
            "losses_compass": int(cases["loss_compass"].sum()),
            "needless_fail": int(cases["needless_fail"].sum()),
            "harmful_compass": int(cases["harmful_compass"].sum()),
            "needless_fail_compass": int(cases["needless_fail_compass"].sum()),
            "needless_unusable": int((cases["needless_fail_compass"].astype(bool)
                                      & (cases["best_fixed_heading_deg"]
                                         > Gate().fail_heading_deg)).sum()),
            "losses_peers": int(cases["loss_peers"].sum()),
            "losses_oracle": int(cases["loss_oracle"].sum()),
            "losses_compass_oracle": int(cases["loss_compass_oracle"].sum()),
            "losses_recording_best": int(cases["loss_recording_best"].sum()),
            "one_tied": int((cases["tied"] == 1).sum()),
            "passed_over": int((cases["passed_over"].fillna("") != "").sum())
            if "passed_over" in cases else 0,
            "not_written": int((~cases["written"].astype(bool)).sum()),
            "recordings": int(cases["dataset"].nunique())}


def _protocol_lines(summary: pd.DataFrame) -> list[str]:
    lines = ["| protocol | cases | losses | losses to a peer | written worse than raw (by "
             "mean norm) | needless FAIL | not written | losses by heading | compass score: "
             "losses, harmful, needless FAIL | the recording's best fixed fit: losses | "
             "median regret | worst regret |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in summary.itertuples():
        lines.append(f"| {r.protocol} | {r.cases} | {r.losses} | {r.losses_peers} | "
                     f"{r.harmful} ({r.harmful_mean_norm}) | {r.needless_fail} | "
                     f"{r.not_written} | {r.losses_heading} of {r.heading_cases} | "
                     f"{r.losses_compass}, {r.harmful_compass}, {r.needless_fail_compass} | "
                     f"{r.losses_recording_best} | {r.regret_median:+.2f} | {r.regret_max:+.2f} |")
    return lines


def _fewer_than_recording_best(summary: pd.DataFrame) -> str:
    """Where calibrate loses fewer cases than the recordings' best fixed fits (text)."""
    rows = summary[(summary["protocol"] != "all")
                   & (summary["losses"] < summary["losses_recording_best"])]
    if rows.empty:
        return ""
    return ", and loses fewer than it on " + ", ".join(
        f"`{r.protocol}` ({r.losses} against {r.losses_recording_best})"
        for r in rows.itertuples())


def _wtl_lines(summary: pd.DataFrame) -> list[str]:
    total = summary[summary["protocol"] == "all"].iloc[0]
    cols = [c for c in summary.columns if c.startswith("wtl:")]
    lines = ["| against | wins / ties / losses of calibrate |", "|---|---|"]
    for c in cols:
        lines.append(f"| {c.removeprefix('wtl:')} | {total[c]} |")
    return lines


def _heading_lines(cases: pd.DataFrame, trials: pd.DataFrame) -> list[str]:
    att = cases[np.isfinite(cases["raw_heading_deg"].to_numpy(float))]
    if att.empty:
        return []
    peers = trials[(trials["kind"] == "peer") & np.isfinite(
        trials["heading_deg"].to_numpy(float))]
    names = sorted(peers["algorithm"].unique())
    lines = ["", f"Where the recording has a reference attitude ({len(att)} cases of "
             f"{att['dataset'].nunique()} recordings), the held-out heading error (RMS deg, "
             "BROAD's definition) against the recording's world field, fitted to the "
             "attitude over every row (`core.direction.attitude_field`); median over the "
             "cases, with the world-frame direction spread about its own mean in brackets, "
             "which a sensor that barely turns keeps small whatever it points at:", "",
             "| protocol | raw | calibrate | " + " | ".join(names) + " |",
             "|---|---:|---:|" + "---:|" * len(names)]
    for p, g in att.groupby("protocol", sort=False):
        cells = []
        for e in names:
            v = peers[(peers["protocol"] == p) & (peers["algorithm"] == e)]
            cells.append(f"{v['heading_deg'].median():.1f} ({v['direction_deg'].median():.1f})"
                         if len(v) else "-")
        lines.append(f"| {p} | {g['raw_heading_deg'].median():.1f} "
                     f"({g['raw_direction_deg'].median():.1f}) | "
                     f"{g['auto_heading_deg'].median():.1f} "
                     f"({g['auto_direction_deg'].median():.1f}) | " + " | ".join(cells) + " |")
    return lines


def _interval_lines(intervals: pd.DataFrame) -> list[str]:
    if intervals.empty:
        return ["", "Interval check: no recording of two minutes or more wrote a correction "
                "from both halves."]
    agree = int(intervals["agree"].astype(bool).sum())
    per = intervals.groupby("dataset")["agree"].apply(lambda a: a.astype(bool).all())
    return ["", f"**Intervals.** On the {intervals['dataset'].nunique()} recordings of two "
            "minutes or more, the offsets written from the first and from the second half "
            "agree within the printed 95 % intervals (combined in quadrature) on "
            f"{_pct(agree, len(intervals))} axes; all three axes agree on "
            f"{int(per.sum())} of {len(per)} recordings."]


def _loss_lines(cases: pd.DataFrame) -> list[str]:
    lost = cases[cases["loss"] | cases["harmful"]]
    if lost.empty:
        return []
    lines = ["", "<details><summary>Every loss and harmful write</summary>", "",
             "| recording | protocol | status | calibrate chose | its spread % | best fixed | "
             "its spread % | raw % |", "|---|---|---|---|---:|---|---:|---:|"]
    for r in lost.itertuples():
        lines.append(f"| {r.dataset} | {r.protocol} | {r.status} | {r.method or '-'} | "
                     f"{r.auto_pct:.2f} | {r.best_fixed} | {r.best_fixed_pct:.2f} | "
                     f"{r.raw_pct:.2f} |")
    return lines + ["", "</details>"]


def generalisation_section(results_dir: Path | str, folder: str = FOLDER) -> str:
    """Markdown section of the generalisation study, or '' when it has not been run."""
    where = Path(results_dir) / folder
    need = ("generalisation_cases.csv", "generalisation_summary.csv",
            "generalisation_trials.csv")
    if not all((where / n).exists() for n in need):
        return ""
    cases = pd.read_csv(where / "generalisation_cases.csv")
    summary = pd.read_csv(where / "generalisation_summary.csv")
    trials = pd.read_csv(where / "generalisation_trials.csv", keep_default_na=False,
                         na_values=[""])
    intervals = (pd.read_csv(where / "generalisation_intervals.csv")
                 if (where / "generalisation_intervals.csv").exists() else pd.DataFrame())
    h = headline(cases)
    lines = [
        "## Generalisation: fit on one part of a recording, score on the rest", "",
        "Every real recording is split by each protocol: one part is fitted, the other scored "
        "by the held-out field-magnitude spread `100 std|m| / mean|m|` of the corrected "
        "samples (and, with a reference attitude, the heading error against the recording's "
        "world field). "
        "`calibrate`'s automatic choice runs its own decision, exit status included: where it "
        "writes nothing the user keeps the raw data, and that is its score. Protocols: "
        "`blocks` (even time blocks fitted, odd scored), `band_x/y/z` (directions within "
        "+-15 deg of one sensor plane fitted, every other direction scored), `half` (first "
        "half fitted), `first15` (first 15 %), `spikes` (5 % spikes in the fitted part), "
        "`still_first` (a still first half before the fitted blocks). A *loss* is a held-out "
        "spread worse than the best fixed method in hindsight by more than max(0.25 points, "
        "5 %). The raw data's spread is a share of the field (the whole recording's robust "
        "radius), not of their mean norm, which an offset larger than the field inflates: a "
        "phone with a 409 uT hard iron in a 41 uT field spreads 5 % of its mean norm while "
        "its raw field points 60-96 deg astray; the mean-norm count is in brackets. With an "
        "attitude, a *loss by heading* is a held-out heading error worse than the best fixed "
        "method's by more than max(1 deg, 10 %); the truth is the world field that the "
        "attitude and the raw samples of the whole recording imply (an offset fitted with "
        "it), which no magnetometer-only fit sees.", "",
        f"**In short.** Over {h['cases']} cases of {h['recordings']} recordings, `calibrate` "
        f"loses to the best fixed method in hindsight in {_pct(h['losses'], h['cases'])}; it "
        f"writes a correction worse than the raw data in {h['harmful']} (by the raw data's "
        f"mean-norm spread: {h['harmful_mean_norm']}) and FAILs where a fixed fit would have "
        f"helped in {h['needless_fail']}; in {h['passed_over']} it passed over a fit that "
        "could have been worse than no correction on the directions not recorded (`calibrate` "
        "takes each eligible fit in turn as the sensor's model, `passed_over` in the cases "
        "table); against the best peer (navlib, magcal) alone it "
        f"loses in {_pct(h['losses_peers'], h['cases'])}. By heading, where an attitude "
        f"exists, it loses in {_pct(h['losses_heading'], h['heading_cases'])}. By the "
        "score its choice serves (heading where the recording has an attitude, magnitude "
        "elsewhere) it loses in "
        f"{_pct(h['losses_compass'], h['cases'])}, writes a correction worse than raw in "
        f"{h['harmful_compass']} and FAILs where a fixed fit would have helped in "
        f"{h['needless_fail_compass']}; in {h['needless_unusable']} of those the best fixed "
        "fit's heading error is still above the gate's 30 deg (a magnet attached, a phone "
        "carried past disturbances: no fit gives a usable compass there). Had it taken, "
        "among the candidates it judged eligible, the one best on the held-out part, and "
        "written it whatever its gate said, it would still lose "
        f"{h['losses_oracle']} by magnitude and {h['losses_compass_oracle']} by the compass "
        "score: that is all a better ranking could win; the rest is in which fits are "
        "eligible (a fit stopped at its iteration cap, a degenerate or vetoed one) and in "
        "the candidates themselves. How strict the comparison is: in "
        f"{h['one_tied']} of {h['cases']} cases ({100 * h['one_tied'] / max(h['cases'], 1):.0f}"
        " %) only the best fixed fit itself is within the tolerance, so every other choice "
        "loses there; and the one fixed method that "
        "loses least on each recording, picked knowing every held-out score of all its "
        f"protocols, still loses {_pct(h['losses_recording_best'], h['cases'])}. No rule "
        "that takes one method per recording can do better; `calibrate` chooses case by "
        f"case{_fewer_than_recording_best(summary)}.",
        "",
        f"![calibrate against fixed fits]({folder}/generalisation.png)", "",
        run_note(where, "recordings"), "",
        *_protocol_lines(summary), "",
        "Against each fixed method and peer, as if the user always ran it (all cases):", "",
        *_wtl_lines(summary),
        *_heading_lines(cases, trials),
        *_interval_lines(intervals),
        *_loss_lines(cases),
    ]
    return "\n".join(lines)
