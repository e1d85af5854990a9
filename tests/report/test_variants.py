"""The Table 2 hypotheses section: squared-form accuracy and RB % recomputed per delta."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.report.variants import squared_form_table, variants_report_section


def trials_frame() -> pd.DataFrame:
    # twostep_no_svd: J/J0 = 0.4, 0.95, 1.5 -> meaningful at delta 1: 2 runs, 0.9 and 0.5: 1.
    return pd.DataFrame({
        "algorithm": ["twostep_no_svd"] * 3 + ["crassidis"] * 2,
        "J": [0.4, 0.95, 1.5, 0.01, np.nan],
        "J0": [1.0, 1.0, 1.0, 1.0, 1.0],
        "sq_err": [0.02, 0.05, 2.0, 1e-4, np.nan],
    })


def test_squared_form_table_recomputes_meaningful_per_delta():
    t = squared_form_table(trials_frame()).set_index(["algorithm", "delta"])
    assert t.loc[("twostep_no_svd", 1.0), "RB_pct"] == pytest.approx(200 / 3)
    assert t.loc[("twostep_no_svd", 1.0), "accuracy_sq"] == pytest.approx(1 / 0.035)
    assert t.loc[("twostep_no_svd", 0.9), "accuracy_sq"] == pytest.approx(50.0)
    assert t.loc[("crassidis", 0.5), "RB_pct"] == 50.0          # the NaN run is a failure
    assert t.loc[("crassidis", 0.5), "accuracy_sq"] == pytest.approx(1e4)


def test_section_sets_the_variants_beside_the_paper_and_reads_the_p0_sweep(tmp_path):
    assert variants_report_section(tmp_path) == ""
    (tmp_path / "baseline").mkdir()
    trials_frame().to_csv(tmp_path / "baseline" / "trials.csv", index=False)
    (tmp_path / "p0").mkdir()
    pd.DataFrame({"crassidis.P0": [np.nan, 1e-6, 3e-6, 1e-3],
                  "algorithm": ["crassidis"] * 4, "n": [9] * 4,
                  "RB_pct": [100.0, 100.0, 100.0, 100.0],
                  "mse": [1e-5, 1e-2, 1 / 3000, 1e-5]}).to_csv(tmp_path / "p0" / "summary.csv",
                                                              index=False)
    text = variants_report_section(tmp_path)
    assert "| TWOSTEP (D* = E*, steps 9-10 skipped) |" in text
    assert "35.3 / 91.6 %" in text and "3.31e+03 / 100 %" in text
    assert "28.6 / 66.7 %" in text                                # 1/0.035, 2 of 3 at delta 1
    assert "closest to the paper's 3.31e+03 is s = 3e-06 (3e+03)" in text


def test_best_fit_names_the_closest_hypothesis_and_whether_it_fits_both_numbers():
    import pandas as pd

    from magbench.report.variants import best_fit

    table = pd.DataFrame([
        {"algorithm": "twostep", "delta": 1.0, "n": 250, "RB_pct": 100.0, "accuracy_sq": 2.4e5},
        {"algorithm": "twostep_no_svd", "delta": 1.0, "n": 250, "RB_pct": 86.0,
         "accuracy_sq": 31.5},
        {"algorithm": "twostep_no_svd", "delta": 0.9, "n": 250, "RB_pct": 91.0,
         "accuracy_sq": 34.0}])
    line = best_fit(table, ["twostep", "twostep_no_svd"], 35.3, 91.6)
    assert "at delta = 0.9 (34 / 91 %" in line and line.count("It fits both numbers") == 1
    far = table[table["delta"] == 1.0]
    line = best_fit(far, ["twostep", "twostep_no_svd"], 35.3, 91.6)
    assert "at delta = 1 (31.5 / 86 %" in line and "It does not fit both numbers" in line
    assert best_fit(table, ["nobody"], 35.3, 91.6) == ""
