"""The result files the report reads."""

import pandas as pd

from magbench.report.load import ESTIMATE_COLUMNS, TRIAL_COLUMNS, load_trials, sweep_delta
from magbench.studies.review import ROW_COLUMNS


def test_the_report_reads_only_columns_a_trials_file_has(tmp_path):
    assert set(TRIAL_COLUMNS + ESTIMATE_COLUMNS) <= set(ROW_COLUMNS)
    pd.DataFrame([dict.fromkeys(ROW_COLUMNS, 1.0)]).to_csv(tmp_path / "trials.csv", index=False)
    assert list(load_trials(tmp_path).columns) == [c for c in ROW_COLUMNS if c in TRIAL_COLUMNS]
    assert len(load_trials(tmp_path, estimates=True).columns) == 16 + 24
    assert load_trials(tmp_path / "absent") is None


def test_delta_comes_from_the_run_record(tmp_path):
    assert sweep_delta(tmp_path) == 0.5
    (tmp_path / "run.json").write_text('{"settings": {"delta": 0.9}}')
    assert sweep_delta(tmp_path) == 0.9
