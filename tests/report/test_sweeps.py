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
