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
