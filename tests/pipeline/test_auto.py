"""The automatic choice from Python: the same study and candidates as ``calibrate``."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

import magbench
import magbench.pipeline.auto as auto
from magbench.cli import main
from magbench.core.geometry import fibonacci_sphere
from magbench.core.model import CalibrationFailed
from magbench.pipeline.rounds import FIRST_ROUND

T_TRUE = np.array([[520.0, 20.0, -8.0], [0.0, 470.0, 15.0], [0.0, 0.0, 610.0]])
H_TRUE = np.array([900.0, -350.0, 120.0])


def samples(K: int = 240, seed: int = 0) -> np.ndarray:
    y = fibonacci_sphere(K) @ T_TRUE.T + H_TRUE
    return y + 3.0 * np.random.default_rng(seed).standard_normal((K, 3))


def test_the_python_choice_is_the_command_line_choice(tmp_path):
    y = samples()
    result = magbench.calibrate_auto(y, seed=7)
    path = tmp_path / "rec.csv"
    pd.DataFrame(y, columns=["mx", "my", "mz"]).to_csv(path, index=False)
    assert main(["calibrate", "progress=false", f"file={path}", f"out={tmp_path / 'o'}",
                 "seed=7", "bootstrap=0"]) == 0
    written = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert result.method == written["method"] and result.choice == written["choice"]
    np.testing.assert_allclose(np.linalg.inv(result.calibration.T), written["A"], rtol=1e-12)
    np.testing.assert_allclose(result.calibration.h, written["b"], rtol=1e-12)
    assert result.status == "PASS" and result.reason == ""
    assert result.verdict["held_out"] and result.intervals is not None
    assert set(result.ranking["algorithm"]) == set(FIRST_ROUND)


def test_calibrate_without_a_method_returns_the_chosen_safe_calibration():
    y = samples()
    cal = magbench.calibrate(y, seed=7)
    T = cal.T
    np.testing.assert_array_equal(T, T.T)
    assert np.linalg.eigvalsh(T).min() > 0
    np.testing.assert_allclose(cal.h, H_TRUE, atol=2.0)
    np.testing.assert_allclose(np.linalg.norm(cal.apply(y), axis=1), 1.0, atol=0.03)
    np.testing.assert_array_equal(T, magbench.calibrate_auto(y, seed=7).calibration.T)


def test_a_failed_choice_raises_with_its_reason(monkeypatch):
    real = auto.calibrate_auto

    def failing(*args, **kwargs):
        return replace(real(*args, **kwargs), status="FAIL", reason="too few directions")

    monkeypatch.setattr(auto, "calibrate_auto", failing)
    with pytest.raises(CalibrationFailed, match="automatic choice: FAIL: too few directions"):
        magbench.calibrate(samples())


def test_bad_samples_are_a_value_error():
    with pytest.raises(ValueError, match="time must have shape"):
        magbench.calibrate_auto(samples(), time=np.arange(5.0))
    phi = np.linspace(0, 2 * np.pi, 100)
    with pytest.raises(ValueError, match="coplanar"):
        magbench.calibrate_auto(np.column_stack([np.cos(phi), np.sin(phi), 0 * phi]))
