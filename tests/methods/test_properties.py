"""Property tests: whatever the input, calibrate answers with a finite Calibration, a ValueError
or CalibrationFailed, and never hangs (issue 6)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import magbench
from magbench.core.model import CalibrationFailed
from magbench.engine.trial import time_limit
from magbench.sources.synthetic import Point, make_dataset
from tests.methods.algorithms.test_contract import SCALE_RTOL

METHODS = [m for m in magbench.methods() if magbench.get_method(m).magnetometer_only]
PROPERTY = settings(max_examples=15, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
#: A hang guard, not a speed test: a call on tiny input taking this long is stuck.
HANG_S = 20.0


def answer(samples, name, **options):
    """calibrate's outcome, with the allowed failures as values and a hang as a test failure."""
    with time_limit(HANG_S):
        try:
            cal = magbench.calibrate(samples, name, **options)
        except (ValueError, CalibrationFailed) as exc:
            assert str(exc), "errors must say what went wrong"
            return exc
    assert np.all(np.isfinite(cal.T)) and np.all(np.isfinite(cal.h))
    return cal


def nominal(seed: int, K: int = 300) -> np.ndarray:
    return make_dataset(np.random.default_rng(seed), Point(K=K)).y


finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@pytest.mark.parametrize("name", METHODS)
@PROPERTY
@given(data=arrays(float, st.tuples(st.integers(1, 20), st.just(3)), elements=finite))
def test_small_arbitrary_inputs(name, data):
    answer(data, name)


@pytest.mark.parametrize("name", METHODS)
@PROPERTY
@given(seed=st.integers(0, 1000), row=st.integers(0, 299), col=st.integers(0, 2),
       bad=st.sampled_from([np.nan, np.inf, -np.inf]))
def test_non_finite_values_are_value_errors(name, seed, row, col, bad):
    y = nominal(seed)
    y[row, col] = bad
    with pytest.raises(ValueError, match="NaN or infinite"):
        magbench.calibrate(y, name)


@pytest.mark.parametrize("name", METHODS)
@PROPERTY
@given(seed=st.integers(0, 1000), exponent=st.floats(-12, 12))
def test_any_magnitude_scales_T_and_h(name, seed, exponent):
    if magbench.get_method(name).family == "variant":
        pytest.skip("a printed-formula variant (e.g. eq. 57's start from R instead of R^-1) "
                    "errs by an amount that depends on the data's scale")
    y = nominal(seed)
    s = 10.0**exponent
    # A bias-only method takes the field magnitude as an input: scale it with the samples.
    opts = {"field_norm": s} if magbench.get_method(name).model == "bias" else {}
    base = answer(y, name)
    scaled = answer(y * s, name, **opts)
    if isinstance(base, magbench.Calibration) and isinstance(scaled, magbench.Calibration):
        tol = SCALE_RTOL.get(name, 1e-5)
        np.testing.assert_allclose(scaled.T / s, base.T, rtol=tol, atol=tol)
        np.testing.assert_allclose(scaled.h / s, base.h, rtol=tol, atol=tol)
    else:
        assert type(base) is type(scaled)


@pytest.mark.parametrize("name", METHODS)
@PROPERTY
@given(seed=st.integers(0, 1000), copies=st.integers(2, 4))
def test_duplicated_samples(name, seed, copies):
    answer(np.repeat(nominal(seed, K=60), copies, axis=0), name)


@pytest.mark.parametrize("name", METHODS)
@PROPERTY
@given(seed=st.integers(0, 1000), normal=st.tuples(finite, finite, finite).filter(
    lambda v: np.linalg.norm(v) > 1e-3))
def test_coplanar_and_collinear_samples_are_value_errors(name, seed, normal):
    y = nominal(seed, K=50)
    n = np.asarray(normal) / np.linalg.norm(normal)
    flat = y - np.outer(y @ n, n)              # projected onto a plane through the origin
    with pytest.raises(ValueError, match=r"coplanar|collinear"):
        magbench.calibrate(flat + 0.3, name)
    line = np.outer(y[:, 0], n)
    with pytest.raises(ValueError, match="collinear"):
        magbench.calibrate(line, name)
