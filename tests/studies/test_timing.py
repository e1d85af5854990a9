"""The timing protocol's logic: which calls are made, on which data, and the comparison of
two passes (no timing is asserted)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.engine.trial import Outcome
from magbench.sources.synthetic import Point
from magbench.studies import timing
from magbench.studies.review import POINT_COLUMNS, ReviewStudy


def passes(first: dict[str, list[float]], second: dict[str, list[float]]):
    """Two timing frames: method -> median per point (points differ by gamma)."""
    def frame(table):
        rows = []
        for name, medians in table.items():
            for i, m in enumerate(medians):
                p = Point(gamma=0.05 * (i + 1))
                rows.append({**{c: getattr(p, c) for c in POINT_COLUMNS}, "algorithm": name,
                             "tau_s": m})
        return pd.DataFrame(rows)
    return frame(first), frame(second)


def test_two_passes_agree_when_every_cell_is_within_tolerance():
    a, b = passes({"magical": [1e-3, 2e-3], "ali": [4e-3, 4e-3]},
                  {"magical": [1.05e-3, 1.9e-3], "ali": [4.2e-3, 3.7e-3]})
    out = timing.compare_timings(a, b).set_index("algorithm")
    assert out["agree"].all()
    assert out.loc["ali", "worst_ratio"] == pytest.approx(3.7 / 4)   # farthest from 1
    assert out.loc["magical", "cells"] == 2


def test_one_cell_outside_tolerance_flips_the_method_only():
    a, b = passes({"magical": [1e-3, 2e-3], "ali": [4e-3, 4e-3]},
                  {"magical": [1e-3, 2.3e-3], "ali": [4e-3, 4e-3]})
    out = timing.compare_timings(a, b).set_index("algorithm")
    assert not out.loc["magical", "agree"] and out.loc["ali", "agree"]
    assert out.loc["magical", "worst_ratio"] == pytest.approx(1.15)
    assert timing.compare_timings(a, b, tolerance=0.2)["agree"].all()


def test_a_method_missing_from_one_pass_does_not_agree():
    a, b = passes({"magical": [1e-3], "ali": [4e-3]}, {"magical": [1e-3]})
    out = timing.compare_timings(a, b).set_index("algorithm")
    assert out.loc["ali", "cells"] == 0 and not out.loc["ali", "agree"]


def test_the_pass_times_every_method_on_the_same_number_of_calls():
    points = [Point(K=30), Point(K=30, gamma=0.5)]
    frame = timing.time_methods(points, 7, ["sphere", "ali"], datasets=2, repeats=2,
                                min_time_s=0.0, slow_call_s=np.inf, clock=lambda: "t0")
    assert list(frame.columns) == timing.TIMING_COLUMNS
    assert len(frame) == 4 and (frame["calls"] == 4).all() and (frame["datasets"] == 2).all()
    assert list(frame["gamma"]) == [0.05, 0.05, 0.5, 0.5]
    assert (frame["q25_s"] <= frame["median_s"]).all()
    assert (frame["median_s"] <= frame["q75_s"]).all()
    assert frame["speed_hz"].to_numpy() == pytest.approx(1 / frame["tau_s"].to_numpy())
    # A method that is slow on the first dataset is timed once per point, on one dataset.
    slow = timing.time_methods(points[:1], 7, ["sphere"], datasets=2, repeats=2,
                               slow_call_s=-1.0)
    assert slow["calls"].iloc[0] == 1 and slow["datasets"].iloc[0] == 1


def test_a_timing_file_is_current_only_for_the_same_study(tmp_path):
    study = ReviewStudy("baseline", [Point(K=30)], 2, 1, ["sphere"])
    assert not timing.timing_is_current(study, tmp_path)
    timing.write_timing(study, tmp_path, datasets=1, repeats=1)
    assert timing.timing_is_current(study, tmp_path)
    other = ReviewStudy("baseline", [Point(K=30)], 2, 2, ["sphere"])     # another seed
    assert not timing.timing_is_current(other, tmp_path)


def test_a_change_of_the_whole_machine_is_told_apart_from_a_method_changing():
    a, b = passes({"magical": [1e-3, 2e-3], "ali": [4e-3, 4e-3], "sphere": [5e-4, 5e-4]},
                  {"magical": [1.6e-3, 3.2e-3], "ali": [6.4e-3, 6.4e-3],
                   "sphere": [8e-4, 1.2e-3]})
    out = timing.compare_timings(a, b).set_index("algorithm")
    assert not out["agree"].any()                    # everything 1.6x slower ...
    assert out["common_ratio"].iloc[0] == pytest.approx(1.6)
    assert out.loc["magical", "agree_relative"] and out.loc["ali", "agree_relative"]
    assert not out.loc["sphere", "agree_relative"]   # ... but sphere 2.4x at one point
    assert out.loc["sphere", "worst_relative"] == pytest.approx(1.5)


def test_tau_weights_every_dataset_once_however_often_it_was_repeated(monkeypatch, tmp_path):
    # A stand-in for the call: dataset 0 takes 0.1 ms (so it is repeated until 3 ms are
    # spent), dataset 1 takes 10 ms (called once); no clock is read. The pass runs in a
    # supervised child: the calls are counted in a file.
    log = tmp_path / "calls"

    def fake(name, y, opts, seed, stream, timeout):
        with open(log, "a") as f:
            f.write(f"{stream[1]}\n")
        spent = 1e-4 if stream[1] == 0 else 1e-2
        return Outcome(name, None, "", spent, spent)

    monkeypatch.setattr(timing, "_call", fake)
    frame = timing.time_methods([Point(K=30)], 7, ["sphere"], datasets=2, repeats=1,
                                min_time_s=3e-3, max_repeats=50)
    row = frame.iloc[0]
    calls = [int(v) for v in log.read_text().split()]
    assert calls.count(1) == 1 and calls.count(0) > 20   # (and two warm-up calls on 0)
    assert row["tau_s"] == pytest.approx((1e-4 + 1e-2) / 2)     # not the median of all calls
    assert row["median_s"] == pytest.approx((1e-4 + 1e-2) / 2)  # median of two datasets
    assert row["speed_hz"] == pytest.approx(1 / row["tau_s"])


def test_a_method_with_no_tau_leaves_the_machine_factor_alone():
    # A method whose every call failed has tau NaN in both passes (seen: twostep_no_svd at the
    # baseline); it must not turn the common ratio, and so every relative verdict, into NaN.
    a, b = passes({"magical": [1e-3], "ali": [4e-3], "bad": [np.nan]},
                  {"magical": [1.2e-3], "ali": [4.8e-3], "bad": [np.nan]})
    out = timing.compare_timings(a, b).set_index("algorithm")
    assert out["common_ratio"].iloc[0] == pytest.approx(1.2)
    assert out.loc[["magical", "ali"], "agree_relative"].all()
    assert out.loc["bad", "cells"] == 0 and not out.loc["bad", "agree"]
