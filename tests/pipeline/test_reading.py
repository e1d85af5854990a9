"""Step 1, read: the recording, its reader's warnings in order, one-line refusals."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.core.units import parse_units
from magbench.pipeline.reading import MIN_COVERAGE, read_recording, recording_units


def _csv(path, y: np.ndarray, **extra) -> object:
    frame = pd.DataFrame(y, columns=["mx", "my", "mz"])
    frame.insert(0, "t", np.arange(len(y)) * 0.02)
    for name, values in extra.items():
        frame[name] = values
    frame.to_csv(path, index=False)
    return path


def test_the_readers_warnings_reach_warn_in_order_before_a_missing_regressor(tmp_path):
    y = 40.0 * fibonacci_sphere(200)
    y[5] = np.nan                                       # one row the reader drops, and says so
    path = _csv(tmp_path / "rec.csv", y)
    said = []
    with pytest.raises(ValueError, match="compensate: the recording has no current column"):
        read_recording(path, compensate=["current"], warn=said.append)
    assert len(said) == 1 and "dropped 1 of 200 rows" in said[0]
    rec = read_recording(path)                          # warnings dropped without warn
    assert rec.K == 199


def test_the_samples_needed_are_the_methods_or_the_fewest_any_method_needs(tmp_path):
    path = _csv(tmp_path / "six.csv", 40.0 * fibonacci_sphere(6))
    assert read_recording(path).K == 6                  # enough for some method
    with pytest.raises(ValueError) as refused:
        read_recording(path, method="fang")
    assert str(refused.value) == ("six.csv has 6 usable samples; at least 10 are needed (the "
                                  "method's number of unknowns)")
    assert 0 < MIN_COVERAGE < 0.3                       # below the sweeps' (module notes)


def test_a_csv_keeps_the_units_given(tmp_path):
    path = _csv(tmp_path / "rec.csv", 40.0 * fibonacci_sphere(50))
    for text in ("uT", "counts"):
        assert recording_units(path, parse_units(text)) == parse_units(text)
