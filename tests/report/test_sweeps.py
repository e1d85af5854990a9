"""The sweep sections: tables with intervals, the run note, the figure link."""

from magbench.report import sweeps as report
from magbench.report.intervals import run_note
from tests.report.helpers import rb_sweep


def test_tables_carry_intervals_and_sections_name_their_run(tmp_path):
    s = rb_sweep("gamma", [0.05, 1.0], {"magical": [100, 96]})
    text = report.sweep_tables(s, "gamma")
    assert "96 [92.8, 97.8]" in text and "100 [98.5, 100]" in text
    (tmp_path / "gamma").mkdir()
    (tmp_path / "gamma" / "run.json").write_text(
        '{"fingerprint": "abc123", "git_commit": "0123456789abcdef", '
        '"settings": {"trials": 250, "delta": 0.5, "seed": 7}}')
    note = run_note(tmp_path / "gamma")
    assert "250 trials per point" in note and "`abc123`" in note and "`0123456789`" in note
    assert "unknown" in run_note(tmp_path / "beta")


def test_sweep_section_links_the_figure_by_its_spec(tmp_path):
    assert report.sweep_section(tmp_path, "gamma") == ""
    (tmp_path / "gamma").mkdir()
    rb_sweep("gamma", [0.05, 1.0], {}).to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    text = report.sweep_section(tmp_path, "gamma")
    assert text.startswith("## Figure 2: sweep `gamma`")
    assert "![Figure 2](gamma/fig2_gamma.png)" in text
    assert "*RB % [95 % Wilson interval]*" in text
    assert report.figure_title("coverage") == "Coverage (beyond the review)"


def test_selection_paragraph_sets_the_methods_beside_the_efficient_estimator():
    import pandas as pd

    s = rb_sweep("cap_deg", [180.0, 30.0], {})
    s["efficiency"] = s["cap_deg"].map({180.0: 1.0, 30.0: 60.0})
    s.loc[s["algorithm"] == "magical", "efficiency"] *= 1.5         # 90 at cap 30
    s.loc[s["cap_deg"] == 30.0, "accuracy"] = 10.0
    reference = pd.DataFrame({"cap_deg": [30.0], "band_deg": [90.0], "RB_pct": [8.0],
                              "accuracy": [10.6], "efficiency": [77.0]})
    trials = pd.DataFrame({"cap_deg": 30.0, "band_deg": 90.0, "trial": [0, 1],
                           "algorithm": "magical", "J0": [0.24, 0.24]})
    text = report.selection_lines(s, reference, trials, 0.5)[0]
    assert "cap 30 deg: 77 (8 % kept; methods 60-90)" in text
    assert "at cap 30 deg, 10-10, sit within a factor 2 of the selection threshold " \
           "1/(delta mean J0) (8.3)" in text
    assert report.selection_lines(s, reference.assign(RB_pct=100.0), trials, 0.5) == []
    assert report.selection_lines(s, None, trials, 0.5) == []
