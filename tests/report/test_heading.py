"""The heading study's report section, from constructed result files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magbench.report.heading import heading_report_section, proxy_verdict
from magbench.studies.heading import HEADING_ROW_COLUMNS, correlations, summarize_heading


def fake_trials() -> pd.DataFrame:
    """Two recordings x three methods (semi) and one (given): fang best, sphere worst."""
    rows = []
    for ds, offset in (("rec_a", 0.0), ("rec_b", 0.5)):
        for name, heading, J in (("fang", 4.0, 0.05), ("magical", 4.5, 0.06),
                                 ("sphere", 9.0, 0.2)):
            for part in ("semi", "given"):
                rows.append({"part": part, "dataset": ds, "distortion": "eq80", "trial": 0,
                             "algorithm": name, "inputs": "", "ok": True, "error": "",
                             "heading_rms": heading + offset, "J": J if part == "semi"
                             else np.nan, "J_r": J / 10, "heading_floor": 3.0,
                             "crb_heading": np.nan, "lag_ms": 15.0 if ds == "rec_a" else 12.0,
                             "gyro_lag_ms": 4.0})
    frame = pd.DataFrame(rows)
    return frame.reindex(columns=HEADING_ROW_COLUMNS)


def write_results(root: Path) -> Path:
    folder = root / "heading"
    folder.mkdir(parents=True)
    trials = fake_trials()
    trials.to_csv(folder / "heading_trials.csv", index=False)
    summarize_heading(trials).to_csv(folder / "summary.csv", index=False)
    correlations(trials).to_csv(folder / "correlation.csv", index=False)
    return root


def test_section_tables_best_method_and_proxy_answer(tmp_path):
    text = heading_report_section(write_results(tmp_path))
    assert "| Fang | 4.25 [4.00, 4.50] | 0.05 | 2/2 |" in text     # two units: their range
    assert "on the semi-synthetic BROAD data Fang at 4.25 deg" in text
    assert "(1.4 x the 3.00 deg floor)" in text
    # per recording the ranks agree exactly; pooled, rec_b's offset breaks a few
    assert "(per dataset 1.00 to 1.00): a fair proxy" in text
    assert "rec_a 15.0 ms (gyro 4.0 ms), rec_b 12.0 ms (gyro 4.0 ms)" in text
    assert "heading/heading_error.png" in text and "heading/heading_vs_J.png" in text


def test_section_without_results(tmp_path):
    assert "No results yet" in heading_report_section(tmp_path)


@pytest.mark.parametrize(("rho", "verdict"), [(0.9, "a fair proxy"), (0.5, "a weak proxy"),
                                              (-0.2, "no proxy"), (np.nan, "cannot be judged")])
def test_proxy_verdict(rho, verdict):
    assert proxy_verdict(rho).startswith(verdict)
