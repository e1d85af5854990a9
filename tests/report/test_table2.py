"""Table 2 beside the paper, and the table a finished baseline writes."""

import numpy as np

from magbench.report.table2 import table2, table2_markdown, write_sweep_tables
from tests.report.helpers import NOMINAL, rb_sweep


def test_table2_sets_every_review_method_beside_the_paper():
    t = table2(rb_sweep("K", [300], {})).set_index("algorithm")
    assert t.loc["magical", "accuracy_paper"] == 2.28e5 and t.loc["twostep", "RB_pct_paper"] == 91.6
    assert t.loc["wu_shi", "speed_ratio"] == 500.0 / 0.24
    assert (t["speed_source"] == "trials").all()


def test_a_finished_baseline_writes_table2(tmp_path):
    write_sweep_tables("baseline", rb_sweep("K", [300], {}), tmp_path / "baseline", 0.5)
    text = (tmp_path / "baseline" / "table2.md").read_text()
    assert text.startswith("# Baseline (Table 2)") and "delta = 0.5 in eq. (76)" in text
    write_sweep_tables("gamma", rb_sweep("K", [300], {}), tmp_path / "gamma", 0.5)
    assert not (tmp_path / "gamma").exists()


def test_one_speed_from_the_timing_pass_and_the_review_ranking_beside_it():
    s = rb_sweep("K", [300], {})                   # the review's seven, TWOSTEP first
    timing = s[[*NOMINAL, "algorithm"]].assign(speed_hz=[100.0 * (i + 1) for i in range(len(s))],
                                          datasets=3)
    t = table2(s, timing=timing).set_index("algorithm")
    assert (t["speed_source"] == "timing").all()
    assert t.loc["magical", "speed_hz"] == 100.0 * len(s)          # not the per-trial 500
    text = table2_markdown(s, 0.5, timing=timing)
    assert "the mean over its first 3 datasets of the median CPU time" in text
    assert "MATLAB timings" not in text
    # Paper: TWOSTEP 455/s and the EKF 47.6/s fastest, Vasconcelos 0.089/s slowest.
    assert "span 3.7 orders of magnitude, TWOSTEP and Crassidis EKF fastest" in text
    assert "Vasconcelos slowest (0.089/s)" in text
    assert "TWOSTEP and Crassidis EKF rank 7th and 6th of seven" in text


def test_no_speed_where_no_run_was_meaningful():
    s = rb_sweep("K", [300], {"twostep": [0.0]})
    timing = s[[*NOMINAL, "algorithm"]].assign(speed_hz=100.0, datasets=3)
    t = table2(s, timing=timing).set_index("algorithm")
    assert np.isnan(t.loc["twostep", "speed_hz"]) and t.loc["ali", "speed_hz"] == 100.0
