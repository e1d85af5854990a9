"""Table 2 beside the paper, and the table a finished baseline writes."""

from magbench.report.table2 import table2, write_sweep_tables
from tests.report.helpers import rb_sweep


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
