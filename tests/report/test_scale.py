"""The bench section's scale paragraph, from a hand-made scale.csv."""

import pandas as pd
import pytest

from magbench.report.scale import growth_exponent, scale_lines
from magbench.report.speed import bench_report_section


def scale_csv() -> pd.DataFrame:
    # Time linear in the trials (x10 -> x10), memory flat, the worker's x2 over x100.
    return pd.DataFrame({"trials": [1000, 10000, 100000], "methods": 2,
                         "run_s": [9.0, 90.0, 900.0], "summarize_s": [0.5, 5.0, 50.0],
                         "intervals_s": [0.5, 5.0, 50.0], "peak_rss_mb": [120.0, 120.0, 120.0],
                         "worker_peak_rss_mb": [80.0, 113.0, 160.0]})


def test_growth_exponents_are_the_log_log_slopes_between_the_ends():
    frame = scale_csv()
    assert growth_exponent(frame, "run_s") == pytest.approx(1.0)
    assert growth_exponent(frame, "peak_rss_mb") == pytest.approx(0.0)
    assert growth_exponent(frame.iloc[::-1], "worker_peak_rss_mb") == pytest.approx(0.5 * 0.301,
                                                                                     abs=1e-3)


def test_paragraph_states_the_sizes_times_and_exponents():
    text = "\n".join(scale_lines(scale_csv()))
    assert "1000 to 100000 trials of 2 methods" in text
    assert "took 10 s and 1e3 s: time grows as trials^1.00" in text
    assert "from 120 to 120 MB (trials^0.00;" in text
    assert "largest worker's reached 160 MB (trials^0.15)" in text
    assert scale_lines(scale_csv().iloc[:1]) == []


def test_the_bench_section_shows_scale_alone(tmp_path):
    (tmp_path / "bench").mkdir()
    assert bench_report_section(tmp_path) == ""
    scale_csv().to_csv(tmp_path / "bench" / "scale.csv", index=False)
    text = bench_report_section(tmp_path)
    assert text.startswith("## Speed (benchmark)") and "trials^1.00" in text


def test_a_rounded_away_shrink_reads_as_zero():
    frame = scale_csv().assign(worker_peak_rss_mb=[80.0, 79.99, 79.98])
    assert "largest worker's reached 80 MB (trials^0.00)" in "\n".join(scale_lines(frame))
