"""The review's claims: each verdict's rule on summaries built to pass or fail it."""

import pandas as pd

from magbench.report import claims as report
from magbench.report.baseline import REVIEW
from magbench.report.claims import FAILS, HOLDS, PARTLY
from tests.report.helpers import gamma_case, rb_sweep, summary, verdicts


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


def test_bias_versus_non_orthogonality_counts_only_differences_beyond_the_intervals():
    values = [0.05, 0.5, 1.0]
    # The committed pattern: two methods better with bias, two with beta, three tie.
    gamma = rb_sweep("gamma", values, {"dorveaux": [100, 84, 30], "magical": [100, 100, 96],
                                       "crassidis": [100, 60, 26], "vasconcelos": [100] * 3})
    beta = rb_sweep("beta", values, {"ali": [100, 80, 42.8], "wu_shi": [100, 99, 94.8],
                                     "crassidis": [100, 61, 26.8], "vasconcelos": [100, 100, 99.6]})
    check = report.check_bias_vs_distortion(gamma, beta)
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
    assert report.check_bias_vs_distortion(gamma2, beta2).verdict == HOLDS
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


def test_claims_are_keyed_by_id_not_by_position(monkeypatch):
    from magbench.core import reference

    values = reference.paper_values()
    shuffled = {**values, "review": {**values["review"], "claims": {
        fig: dict(reversed(list(claims.items())))
        for fig, claims in values["review"]["claims"].items()}}}
    monkeypatch.setattr(report, "paper_values", lambda: shuffled)
    checks = report.check_gamma(gamma_case())
    assert checks[0].claim == values["review"]["claims"]["fig2_gamma"]["most_robust"]
    assert checks[4].claim.startswith("execution speed does not change with gamma")


def test_claims_section_lists_every_claim_with_its_verdict(tmp_path):
    (tmp_path / "gamma").mkdir()
    gamma_case().to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    text = report.claims_section(tmp_path)
    assert text.startswith("## The paper's claims, checked")
    rows = [line for line in text.splitlines() if line.startswith("| Figure")]
    assert len(rows) == 6 and rows[-1].endswith("| **not evaluated** |")
