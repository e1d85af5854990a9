"""Wall times live beside the trials: the trials file is what the seed determines."""

from __future__ import annotations

import pandas as pd
import pytest

from magbench.engine.sweep import run_study
from magbench.sources.synthetic import Point
from magbench.studies.review import ReviewStudy, read_trials
from magbench.studies.times import split_times, times_path, with_times


def test_split_times_moves_time_s_out_and_keeps_the_order():
    rows = [{"trial": 0, "algorithm": "a", "time_s": 0.5, "J": 1.0},
            {"trial": 0, "algorithm": "b", "time_s": 0.25, "J": 2.0}]
    kept, times = split_times(rows, "trial")
    assert kept == [{"trial": 0, "algorithm": "a", "J": 1.0},
                    {"trial": 0, "algorithm": "b", "J": 2.0}]
    assert [t["time_s"] for t in times] == [0.5, 0.25]
    assert "time_s" in rows[0]                       # the caller's rows are left alone


def test_times_path_names_the_sidecar(tmp_path):
    assert times_path(tmp_path / "trials.csv") == tmp_path / "trials_times.csv"
    assert times_path(tmp_path / "runs.csv.gz") == tmp_path / "runs_times.csv"


def test_with_times_refuses_another_runs_times(tmp_path):
    trials = pd.DataFrame({"trial": [0, 1], "algorithm": ["a", "a"]})
    pd.DataFrame({"trial": [0, 2], "algorithm": ["a", "a"], "time_s": [1.0, 2.0]}).to_csv(
        times_path(tmp_path / "trials.csv"), index=False)
    with pytest.raises(ValueError, match="does not list the rows"):
        with_times(trials, tmp_path / "trials.csv", "trial")


def test_the_same_seed_gives_byte_identical_trials_files(tmp_path):
    study = ReviewStudy("t", [Point(K=40)], trials=3, seed=5, algorithms=["sphere", "fang"])
    for folder in ("a", "b"):
        run_study(study, tmp_path / folder, n_jobs=1, progress=False)
    a, b = ((tmp_path / f / "trials.csv").read_bytes() for f in ("a", "b"))
    assert a == b and b"time_s" not in a
    assert read_trials(tmp_path / "a" / "trials.csv")["time_s"].notna().all()
