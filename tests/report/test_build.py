"""Report and figure generation from hand-made CSV files, and the claim verdict logic."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.report import build as report
from magbench.report.build import FAILS, HOLDS, PARTLY, REVIEW

NOMINAL = {"K": 300, "sigma": 0.005, "beta": 0.05, "gamma": 0.05, "cap_deg": 180.0,
           "band_deg": 90.0}


def summary(x: str, values: list, table: dict[str, dict[str, list]], floor=None) -> pd.DataFrame:
    """A summary.csv-like frame: table[method][column] lists one value per swept value."""
    rows = []
    for name, cols in table.items():
        for i, v in enumerate(values):
            row = {**NOMINAL, x: v, "algorithm": name, "n": 10}
            row.update({c: vals[i] for c, vals in cols.items()})
            row["tau_s"] = 1 / row["speed_hz"]
            row["crb_accuracy"] = floor[i] if floor else 400.0
            row["efficiency"] = 1.0
            rows.append(row)
    return pd.DataFrame(rows)


def gamma_case(magical_rb=100.0, speed_magical=(300, 300, 100)) -> pd.DataFrame:
    values = [0.05, 0.25, 1.0]
    table = {n: {"RB_pct": [100, 100, 95], "accuracy": [400, 400, 400],
                 "speed_hz": [500, 500, 500]} for n in REVIEW}
    table["magical"] = {"RB_pct": [100, 100, magical_rb], "accuracy": [400, 400, 400],
                        "speed_hz": list(speed_magical)}
    table["ali"]["RB_pct"] = [100, 100, 100]
    table["twostep"] = {"RB_pct": [100, 90, 80], "accuracy": [40, 40, 40],
                        "speed_hz": [500, 500, 500]}
    table["wu_shi"]["RB_pct"] = [100, 90, 85]
    table["crassidis"] = {"RB_pct": [100, 100, 50], "accuracy": [100, 50, 10],
                          "speed_hz": [500, 500, 500]}
    table["dorveaux"]["RB_pct"] = [100, 100, 60]
    return summary("gamma", values, table)


def verdicts(checks):
    return [c.verdict for c in checks]


def test_gamma_claims_hold_on_a_summary_built_to_satisfy_them():
    assert verdicts(report.check_gamma(gamma_case())) == [HOLDS] * 5


def test_gamma_claims_fail_when_the_evidence_says_so():
    checks = report.check_gamma(gamma_case(magical_rb=20.0, speed_magical=(300, 300, 300)))
    assert checks[0].verdict == PARTLY            # only Ali stays most robust
    assert checks[4].verdict == FAILS             # MAG.I.C.AL's speed no longer changes
    assert "MAG.I.C.AL 20" in checks[0].evidence


def test_sigma_claims_use_the_slope_of_accuracy():
    table = {n: {"RB_pct": [100, 100, 100], "accuracy": [4000, 400, 40],
                 "speed_hz": [1, 1, 1]} for n in REVIEW}
    s = summary("sigma", [0.0005, 0.005, 0.05], table)
    assert verdicts(report.check_sigma(s)) == [HOLDS, HOLDS]
    table["magical"]["accuracy"] = [400, 400, 400]
    table["crassidis"]["RB_pct"] = [100, 100, 0]
    table["ali"]["RB_pct"] = [100, 100, 0]
    table["twostep"]["RB_pct"] = [100, 100, 0]
    checks = report.check_sigma(summary("sigma", [0.0005, 0.005, 0.05], table))
    assert verdicts(checks) == [PARTLY, PARTLY]


def test_K_time_slope_and_flat_robustness():
    table = {n: {"RB_pct": [100, 100, 100], "accuracy": [160, 280, 400],
                 "speed_hz": [600, 200, 100]} for n in REVIEW}   # time ~ K
    s = summary("K", [50, 150, 300], table, floor=[160, 280, 400])
    assert verdicts(report.check_K(s)) == [HOLDS, HOLDS, HOLDS]
    for n in REVIEW:
        table[n]["speed_hz"] = [100, 100, 100]                   # time independent of K
    assert report.check_K(summary("K", [50, 150, 300], table, floor=[160, 280, 400]))[2] \
        .verdict == FAILS


def test_report_from_fixture_files(tmp_path):
    (tmp_path / "gamma").mkdir()
    gamma_case().to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    assert main(["report", f"results_dir={tmp_path}"]) == 0     # figures, then report.md
    text = (tmp_path / "report.md").read_text()
    assert "## Figure 2: sweep `gamma`" in text and "(gamma/fig2_gamma.png)" in text
    assert (tmp_path / "gamma" / "fig2_gamma.png").exists()
    assert text.count("**holds**") == 5
    assert "| Figure 6 |" in text and "**not evaluated**" in text


def test_metric_hypotheses_on_hand_made_rows():
    rows = pd.DataFrame({"algorithm": ["magical"] * 2, "meaningful": [True, True],
                         "J": [0.1, 0.3], "sq_err": [0.01, 0.03], "crb_J": [0.2, 0.2],
                         "crb": [0.01, 0.03]})
    hyp = report.metric_hypotheses(rows).iloc[0]
    assert hyp["inv_mean_J"] == pytest.approx(5.0)
    assert hyp["inv_mean_J2"] == pytest.approx(1 / 0.05)
    assert hyp["inv_mean_sq"] == pytest.approx(50.0)
    assert hyp["inv_crb"] == pytest.approx(50.0)
    assert hyp["crb_floor"] == pytest.approx(5.0)
    assert hyp["paper"] == pytest.approx(2.28e5)
    assert np.isclose(hyp["paper_over_sq"], 2.28e5 / 50)


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


def test_top_share_is_a_paired_bootstrap_of_the_squared_metric():
    rng = np.random.default_rng(1)
    err = rng.gamma(2.0, 1e-6, 250)
    rows = [{"trial": i, "algorithm": name, "sq_err": e * f}
            for i, e in enumerate(err) for name, f in (("magical", 1.0), ("wu_shi", 1.2))]
    text = report._top_share(pd.DataFrame(rows), ["magical", "wu_shi"])
    # On the same datasets magical's error is always 1.2 times smaller: first in every draw.
    assert "MAG.I.C.AL 100 %" in text and "the first place is significant" in text
    rows += [{"trial": i, "algorithm": "dorveaux", "sq_err": e * (1 + 0.3 * rng.standard_normal())}
             for i, e in enumerate(err)]
    text = report._top_share(pd.DataFrame(rows), ["magical", "dorveaux"])
    assert "not significant" in text


# --- verdicts that rest on intervals, the timing pass and the scaling benchmark -----------------

def rb_sweep(x: str, values: list, rb: dict[str, list[float]], n: int = 250) -> pd.DataFrame:
    """A summary of RB % only (n runs per point), the other review methods at 100 %."""
    table = {name: {"RB_pct": rb.get(name, [100.0] * len(values)),
                    "accuracy": [400.0] * len(values), "speed_hz": [500.0] * len(values)}
             for name in REVIEW}
    s = summary(x, values, table)
    s["n"] = n
    s["n_meaningful"] = (s["RB_pct"] * n / 100).round().astype(int)
    return s


def test_bias_versus_non_orthogonality_counts_only_differences_beyond_the_intervals():
    values = [0.05, 0.5, 1.0]
    # The committed pattern: two methods better with bias, two with beta, three tie.
    gamma = rb_sweep("gamma", values, {"dorveaux": [100, 84, 30], "magical": [100, 100, 96],
                                       "crassidis": [100, 60, 26], "vasconcelos": [100] * 3})
    beta = rb_sweep("beta", values, {"ali": [100, 80, 42.8], "wu_shi": [100, 99, 94.8],
                                     "crassidis": [100, 61, 26.8], "vasconcelos": [100, 100, 99.6]})
    check = report.check_bias_vs_distortion(gamma, beta, "claim")
    assert check.verdict == FAILS
    assert "more robust to bias: Ali PSO, Wu-Shi;" in check.evidence
    assert "more robust to non-orthogonality: Dorveaux, MAG.I.C.AL;" in check.evidence
    classes, _ = report.bias_vs_distortion(gamma, beta)
    assert classes["vasconcelos"] == classes["crassidis"] == "tie"   # 0.4 and 0.8 points
    # Two more methods fail with beta only: now most handle bias better.
    beta2 = rb_sweep("beta", values, {"ali": [100, 80, 42.8], "wu_shi": [100, 99, 94.8],
                                      "twostep": [100, 90, 70], "vasconcelos": [100, 90, 60],
                                      "crassidis": [100, 40, 10]})
    gamma2 = rb_sweep("gamma", values, {"crassidis": [100, 60, 26]})
    assert report.check_bias_vs_distortion(gamma2, beta2, "claim").verdict == HOLDS
    # The same differences on 10 runs per point are inside the intervals: no difference.
    small = report.bias_vs_distortion(rb_sweep("gamma", values, {}, n=10),
                                      rb_sweep("beta", values, {"wu_shi": [100, 99, 90]},
                                               n=10))[0]
    assert small["wu_shi"] == "tie"


def test_flat_robustness_flips_on_a_swing_beyond_the_intervals():
    values = [0.0005, 0.005, 0.05]
    flat = rb_sweep("sigma", values, {"twostep": [100, 99.6, 100]})
    assert report._flat_robustness(flat, "sigma", "Figure 5", "c").verdict == HOLDS
    swing = rb_sweep("sigma", values, {"crassidis": [84.8, 100, 100]})      # the EKF's 15
    check = report._flat_robustness(swing, "sigma", "Figure 5", "c")
    assert check.verdict == PARTLY and "intervals: Crassidis EKF" in check.evidence


def test_speed_verdict_reads_the_timing_pass_when_there_is_one():
    s = gamma_case()                       # per-trial speeds: MAG.I.C.AL slows 3x, others flat
    assert report.check_gamma(s)[4].verdict == HOLDS
    timing = s[["gamma", "algorithm"]].assign(speed_hz=500.0)   # the pass: all flat
    check = report.check_gamma(s, timing)[4]
    assert check.verdict == FAILS and "(timing pass)" in check.evidence


def test_time_versus_K_is_judged_on_the_scaling_benchmark():
    table = {n: {"RB_pct": [100] * 3, "accuracy": [160, 280, 400], "speed_hz": [100] * 3}
             for n in REVIEW}                                   # flat: overhead-dominated
    s = summary("K", [50, 150, 300], table, floor=[160, 280, 400])
    assert report.check_K(s)[2].verdict == FAILS
    calls = pd.DataFrame([{"algorithm": n, "K": K, "median_s": 1e-3 * K / 1000}
                          for n in REVIEW for K in (1000, 10000)])
    check = report.check_K(s, calls=calls)[2]
    assert check.verdict == HOLDS and "TWOSTEP 10 (slope 1.00)" in check.evidence
    calls.loc[calls["K"] == 10000, "median_s"] = 1e-1            # 100x: quadratic
    assert report.check_K(s, calls=calls)[2].verdict == FAILS


def test_printed_bias_cost_is_recomputed_from_the_estimates():
    T_true, h_true = np.diag([1.1, 0.9, 1.0]), np.array([0.1, -0.05, 0.02])
    T_est = T_true + 0.001 * np.eye(3)
    h_est = h_true + 0.001
    row = {"algorithm": "twostep", "meaningful": True, "trial": 0}
    row.update({f"h_{i}": h_est[i] for i in range(3)})
    row.update({f"T_{i}{j}": T_est[i, j] for i in range(3) for j in range(3)})
    row.update({f"h_true_{i}": h_true[i] for i in range(3)})
    row.update({f"T_true_{i}{j}": T_true[i, j] for i in range(3) for j in range(3)})
    J, J_h, J_T = report.accuracy_cost(T_est, h_est, T_true, h_true)
    row.update({"J": J, "J_h": J_h, "J_T": J_T})
    cost = report.printed_bias_cost(pd.DataFrame([row])).iloc[0]
    Jp, Jp_h, Jp_T = report.accuracy_cost(T_est, np.linalg.solve(T_est, h_est), T_true, h_true)
    assert cost["factor_J"] == pytest.approx(Jp / J)
    assert cost["factor_sq"] == pytest.approx((Jp_h ** 2 + Jp_T ** 2) / (J_h ** 2 + J_T ** 2))
    assert cost["factor_sq"] > cost["factor_J"] > 1
    text = report.printed_bias_sentence(pd.DataFrame([cost]))
    assert f"x{cost['factor_J']:.2g} in J and x{cost['factor_sq']:.2g} in the squared" in text


def test_printed_vasconcelos_explains_beta_but_not_gamma_only_when_the_numbers_say_so():
    values = [0.05, 0.5, 1.0]
    base = rb_sweep("K", [300], {})
    base = pd.concat([base, base[base["algorithm"] == "vasconcelos"].assign(
        algorithm="vasconcelos_printed", RB_pct=99.6, n_meaningful=249)])

    def sweep(x, printed):
        s = rb_sweep(x, values, {})
        v = s[s["algorithm"] == "vasconcelos"].assign(algorithm="vasconcelos_printed")
        v["RB_pct"] = printed
        v["n_meaningful"] = (v["RB_pct"] * 2.5).round().astype(int)
        return pd.concat([s, v])

    text = report.printed_robustness(base, sweep("gamma", [100, 27, 14.4]),
                                     sweep("beta", [100, 80, 32.4]))
    assert "rests on 1 failed run of 250" in text and "99.6 % [97.8, 99.9]" in text
    assert "explain the review's fall with beta" in text
    assert "the explanation holds for beta, not for gamma" in text
    text = report.printed_robustness(base, sweep("gamma", [100, 100, 99.2]),
                                     sweep("beta", [100, 80, 32.4]))
    assert "leave it robust to bias, as the review shows" in text


def test_tables_carry_intervals_and_sections_name_their_run(tmp_path):
    s = rb_sweep("gamma", [0.05, 1.0], {"magical": [100, 96]})
    text = report.sweep_tables(s, "gamma")
    assert "96 [92.8, 97.8]" in text and "100 [98.5, 100]" in text
    (tmp_path / "gamma").mkdir()
    (tmp_path / "gamma" / "run.json").write_text(
        '{"fingerprint": "abc123", "git_commit": "0123456789abcdef", '
        '"settings": {"trials": 250, "delta": 0.5, "seed": 7}}')
    note = report.run_note(tmp_path / "gamma")
    assert "250 trials per point" in note and "`abc123`" in note and "`0123456789`" in note
    assert "unknown" in report.run_note(tmp_path / "beta")


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
    assert "'low' manoeuvre, gyro noise 0.03 rad/s, 30 runs" in helps
    assert helps.endswith("the gyro helps here.")
    assert report.gyro_line(gyro_summary(10.0)).endswith("no gain from the gyro here over the "
                                                         "best magnetometer-only fit.")
