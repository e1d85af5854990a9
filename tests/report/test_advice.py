"""The opening advice: which method when, from hand-made summaries."""

import numpy as np
import pandas as pd

from magbench.report import advice as report
from tests.report.helpers import summary


def test_recommendations_name_the_equally_good_methods_and_never_a_variant():
    base = summary("K", [300], {
        "magical": {"RB_pct": [100], "accuracy": [397], "speed_hz": [300]},
        "fang": {"RB_pct": [100], "accuracy": [395], "speed_hz": [1300]},
        "vasconcelos_printed": {"RB_pct": [100], "accuracy": [397], "speed_hz": [5000]},
        "sphere": {"RB_pct": [87.6], "accuracy": [16], "speed_hz": [1800]}})
    lines = report.recommendations(base, None)
    assert "2 methods are equally good" in lines[0] and "the fastest here is Fang" in lines[0]
    assert "Vasconcelos (review" not in "\n".join(lines)         # variants are never advised
    assert lines[1].startswith("- **Not for full soft-iron calibration**: Sphere fit (RB 87.6 %")


def test_recommendations_on_partial_coverage_name_the_most_robust_per_cap():
    cov = summary("cap_deg", [180.0, 60.0, 30.0], {
        "magical": {"RB_pct": [100, 90, 35], "accuracy": [397, 50, 15], "speed_hz": [3] * 3},
        "fang": {"RB_pct": [100, 94, 10], "accuracy": [395, 50, 14], "speed_hz": [3] * 3}})
    text = report.recommendations(None, cov)[0]
    assert "cap 60 deg: Fang 94 % (MAG.I.C.AL within 10 points)" in text
    assert "cap 30 deg: MAG.I.C.AL 35 %." in text             # Fang is 25 points behind


def test_stress_rows_read_the_hardest_point_of_each_sweep():
    gamma = summary("gamma", [0.05, 1.0], {
        "magical": {"RB_pct": [100, 100], "accuracy": [400, 380], "speed_hz": [300] * 2},
        "ali": {"RB_pct": [100, 99.2], "accuracy": [400, 300], "speed_hz": [30] * 2},
        "crassidis": {"RB_pct": [100, 22], "accuracy": [400, 5], "speed_hz": [900] * 2},
        "vasconcelos_printed": {"RB_pct": [100, 100], "accuracy": [900, 900],
                                "speed_hz": [9] * 2}})
    line = report.stress_line(gamma, "gamma", "Large offset", "Fig. 2")
    assert line.startswith("- **Large offset** (Fig. 2, gamma = 1, 10 datasets): 2 methods keep")
    assert "most accurate are MAG.I.C.AL (1/rho 380)" in line     # Ali is 21 % behind
    assert "least robust: Crassidis EKF (RB 22 %)" in line
    assert "Vasconcelos (review" not in line                         # variants never advised
    # K: the hardest point is the fewest samples, and nobody robust there is said so.
    few = summary("K", [10, 300], {
        "magical": {"RB_pct": [60, 100], "accuracy": [3, 400], "speed_hz": [300] * 2},
        "fang": {"RB_pct": [75, 100], "accuracy": [2, 400], "speed_hz": [300] * 2}})
    assert report.stress_line(few, "K", "Few samples", "Fig. 4") == (
        "- **Few samples** (Fig. 4, K = 10, 10 datasets): no method keeps RB >= 99 %; the most "
        "robust is Fang (RB 75 %).")
    assert report.stress_line(None, "K", "Few samples", "Fig. 4") == ""


def test_gyro_row_compares_the_best_gyro_and_magnetometer_only_methods():
    def gyro_summary(sar_rb):
        rows = [{"coverage": c, "gyro_noise": g, "algorithm": a, "n": 30, "RB_pct": rb,
                 "accuracy": acc}
                for c in ("wide", "low") for g in (0.0, 0.03)
                for a, rb, acc in (("sar_ls", sar_rb, 50.0), ("magical", 40.0, 20.0))]
        return pd.DataFrame(rows)

    helps = report.gyro_line(gyro_summary(90.0))
    assert "gyro noise 0.03 rad/s, 30 runs per manoeuvre" in helps
    assert "'low': SAR-LS RB 90 [74.4, 96.5] % against MAG.I.C.AL 40 [24.6, 57.7] %" in helps
    assert helps.endswith("RB beyond the intervals on: 'wide', 'low'; accuracy on: no manoeuvre.")
    # 60 % against 40 % on 30 runs each: the Wilson intervals overlap, no gain is claimed.
    tie = report.gyro_line(gyro_summary(60.0))
    assert "(within the intervals)" in tie and "RB beyond the intervals on: no manoeuvre" in tie


def test_gyro_accuracy_is_compared_on_the_manoeuvres_both_solve():
    summary = pd.DataFrame([{"coverage": "low", "gyro_noise": 0.03, "algorithm": a, "n": 4,
                             "RB_pct": 100.0, "accuracy": 1.0} for a in ("sar_ls", "magical")])
    trials = pd.DataFrame([{"coverage": "low", "gyro_noise": 0.03, "trial": i, "algorithm": a,
                            "J": j * (1.0 if a == "magical" else 0.5), "meaningful": True}
                           for i, j in enumerate([1.0, 2.0, 3.0, 4.0])
                           for a in ("sar_ls", "magical")])
    line = report.gyro_line(summary, trials)
    assert "accuracy 2x MAG.I.C.AL's [2, 2] on the 4 manoeuvres both solve" in line
    assert line.endswith("accuracy on: 'low'.")


def test_advice_section_reads_the_results_folder(tmp_path):
    assert report.advice_section(tmp_path) == ""
    (tmp_path / "baseline").mkdir()
    summary("K", [300], {"magical": {"RB_pct": [100], "accuracy": [397], "speed_hz": [300]}}
            ).to_csv(tmp_path / "baseline" / "summary.csv", index=False)
    text = report.advice_section(tmp_path)
    assert text.startswith("## In short: which method to use\n\n- **Data from the whole sphere")
    assert "1 methods are equally good" in text and "the fastest here is MAG.I.C.AL" in text
    assert text.rstrip().endswith("writes the chosen correction.")


def test_stress_rows_compare_accuracy_on_matched_datasets():
    hard = np.r_[np.full(50, 1.0), np.full(50, 10.0)]
    rows = [{"beta": 1.0, "trial": i, "algorithm": n, "J": j * f, "meaningful": m}
            for n, f in (("dorveaux", 1.0), ("magical", 1.02), ("wu_shi", 0.6))
            for i, j in enumerate(hard)
            for m in [not (n == "wu_shi" and i >= 95)]]
    trials = pd.DataFrame(rows)
    s = summary("beta", [1.0], {
        "dorveaux": {"RB_pct": [100], "accuracy": [1 / 5.5], "speed_hz": [1]},
        "magical": {"RB_pct": [100], "accuracy": [1 / 5.61], "speed_hz": [1]},
        "wu_shi": {"RB_pct": [95], "accuracy": [1 / 3.0], "speed_hz": [1]}})
    line = report.stress_line(s, "beta", "Strong", "Fig. 3", trials)
    assert "the most accurate are Dorveaux, MAG.I.C.AL (accuracy 0.98-1 of Dorveaux's on " \
           "the 100 datasets meaningful for both; apart beyond the 95 % paired intervals: " \
           "MAG.I.C.AL)" in line
    assert "Wu-Shi (RB 95 %) is 1.7x as accurate as Dorveaux on the 95 datasets" in line


def test_the_fastest_method_is_flagged_where_it_falls_behind():
    rows = [{"sigma": 0.05, "trial": i, "algorithm": n, "J": 1.0 + 0.1 * i * 0 + f,
             "meaningful": True} for i in range(20) for n, f in (("magical", 0.0),
                                                                  ("fang", 0.25))]
    s = summary("sigma", [0.05], {n: {"RB_pct": [100], "accuracy": [1.0], "speed_hz": [1]}
                                  for n in ("magical", "fang")})
    text = report._fastest_caveat("fang", {"sigma": s}, {"sigma": pd.DataFrame(rows)})
    assert text == (" But at sigma = 0.05 (Fig. 5) it keeps 0.8 of MAG.I.C.AL's accuracy on "
                    "the same 20 datasets: see the rows below.")
    assert report._fastest_caveat("magical", {"sigma": s}, {"sigma": pd.DataFrame(rows)}) == ""
