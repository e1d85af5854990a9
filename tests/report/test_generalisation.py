"""The generalisation section says what the CSV files hold."""

from __future__ import annotations

import pandas as pd

from magbench.report.generalisation import generalisation_section, headline


def write(folder, cases):
    folder.mkdir(parents=True)
    cases.to_csv(folder / "generalisation_cases.csv", index=False)
    pd.DataFrame([{"protocol": "half", "cases": len(cases), "regret_median": 0.1,
                   "regret_max": 2.0, "losses": int(cases["loss"].sum()),
                   "loss_pct": 50.0, "harmful": 1, "harmful_mean_norm": 2,
                   "needless_fail": 0, "not_written": 1, "direction_cases": 0,
                   "losses_direction": 0, "heading_cases": 1, "losses_heading": 1,
                   "losses_compass": 1, "losses_peers": 1, "harmful_compass": 1,
                   "needless_fail_compass": 1, "losses_recording_best": 2},
                  {"protocol": "all", "cases": len(cases), "regret_median": 0.1,
                   "regret_max": 2.0, "losses": int(cases["loss"].sum()), "loss_pct": 50.0,
                   "harmful": 1, "harmful_mean_norm": 2, "needless_fail": 0,
                   "not_written": 1, "direction_cases": 0, "losses_direction": 0,
                   "heading_cases": 1, "losses_heading": 1,
                   "losses_compass": 1, "losses_peers": 1, "harmful_compass": 1,
                   "needless_fail_compass": 1, "losses_recording_best": 1,
                   "wtl:sphere": "1/0/1"}]).to_csv(
        folder / "generalisation_summary.csv", index=False)
    pd.DataFrame({"kind": ["auto"], "algorithm": ["calibrate"], "protocol": ["half"],
                  "direction_deg": [float("nan")], "heading_deg": [float("nan")]}).to_csv(
        folder / "generalisation_trials.csv", index=False)


def test_the_section_leads_with_the_counts(tmp_path):
    cases = pd.DataFrame({"dataset": ["a", "b"], "protocol": ["half", "half"],
                          "status": ["PASS", "FAIL"], "method": ["fang", ""],
                          "written": [True, False], "auto_pct": [3.0, 9.0],
                          "raw_pct": [2.0, 9.0], "best_fixed": ["sphere", "sphere"],
                          "best_fixed_pct": [1.0, 8.0], "regret": [2.0, 1.0],
                          "loss": [True, False], "harmful": [True, False],
                          "harmful_mean_norm": [True, True],
                          "loss_direction": [False, False],
                          "loss_compass": [True, False],
                          "needless_fail": [False, False],
                          "harmful_compass": [True, False],
                          "needless_fail_compass": [False, True],
                          "loss_peers": [True, False],
                          "auto_direction_deg": [float("nan")] * 2,
                          "raw_direction_deg": [float("nan")] * 2,
                          "loss_heading": [False, True],
                          "auto_heading_deg": [float("nan"), 95.0],
                          "raw_heading_deg": [float("nan"), 95.0],
                          # b's best fixed fit still points 45 deg astray: no usable compass
                          "best_fixed_heading_deg": [float("nan"), 45.0],
                          "loss_oracle": [False, True],
                          "loss_compass_oracle": [False, False],
                          "loss_recording_best": [False, True], "tied": [1, 3],
                          "passed_over": ["twostep;fang", ""]})
    assert headline(cases) == {"cases": 2, "losses": 1, "harmful": 1, "harmful_mean_norm": 2,
                               "direction_cases": 0, "losses_direction": 0,
                               "heading_cases": 1, "losses_heading": 1,
                               "losses_compass": 1, "harmful_compass": 1,
                               "needless_fail_compass": 1, "needless_unusable": 1,
                               "losses_peers": 1, "losses_oracle": 1,
                               "losses_compass_oracle": 0, "losses_recording_best": 1,
                               "one_tied": 1, "passed_over": 1,
                               "needless_fail": 0, "not_written": 1, "recordings": 2}
    write(tmp_path / "generalisation", cases)
    text = generalisation_section(tmp_path)
    assert "loses to the best fixed method in hindsight in 1 of 2 (50 %)" in text
    assert ("writes a correction worse than the raw data in 1 (by the raw data's mean-norm "
            "spread: 2)") in text
    assert "| half | 2 | 1 | 1 | 1 (2) | 0 | 1 | 1 of 1 | 1, 1, 1 |" in text
    assert "against the best peer (navlib, magcal) alone it loses in 1 of 2 (50 %)" in text
    assert ("in 1 it passed over a fit that could have been worse than no correction on the "
            "directions not recorded") in text
    assert ("magnitude elsewhere) it loses in 1 of 2 (50 %), writes a correction worse than "
            "raw in 1 and FAILs where a fixed fit would have helped in 1; in 1 of those the best "
            "fixed fit's heading error is still above the gate's 30 deg") in text
    assert "it would still lose 1 by magnitude and 0 by the compass score" in text
    assert "in 1 of 2 cases (50 %) only the best fixed fit itself is within" in text
    assert "| 1, 1, 1 | 2 | +0.10 |" in text
    assert "loses fewer than it on `half` (1 against 2)." in text
    assert "picked knowing every held-out score of all its protocols, still loses 1 of 2" in text
    assert "| sphere | 1/0/1 |" in text and "| a | half | PASS | fang |" in text


def test_no_study_no_section(tmp_path):
    assert generalisation_section(tmp_path) == ""
