"""Time alignment: known lags recovered below a sample, resampling and attitude rates exact."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.lag import attitude_rate, gyro_lag, magnetometer_lag, shift, stream_lag
from magbench.sources.trajectory import simulate

RATE_HZ = 25.0


def manoeuvre(lag_s: float, noise: float = 0.0, seed: int = 1):
    return simulate(np.random.default_rng(seed), rate_hz=RATE_HZ, duration_s=60.0,
                    lag_s=lag_s, mag_noise=noise, gyro_noise=noise, rate_rms=1.5)


@pytest.mark.parametrize("lag_samples", [-0.25, 0.0, 0.37, 1.6])
def test_a_known_magnetometer_lag_is_recovered_below_a_sample(lag_samples):
    lag = lag_samples / RATE_HZ
    tr = manoeuvre(lag)
    found, peak = magnetometer_lag(tr.t, tr.y, tr.angular_rate)
    assert abs(found - lag) * RATE_HZ < 0.02 and peak > 0.99
    noisy = manoeuvre(lag, noise=0.005)
    found, _ = magnetometer_lag(noisy.t, noisy.y, noisy.angular_rate)
    assert abs(found - lag) * RATE_HZ < 0.15
    # the attitude's own rate serves as well as the gyro
    found, _ = magnetometer_lag(tr.t, tr.y, attitude_rate(tr.t, tr.attitude))
    assert abs(found - lag) * RATE_HZ < 0.05


def test_attitude_rate_is_the_body_rate():
    tr = simulate(np.random.default_rng(2), rate_hz=200.0, duration_s=10.0)
    assert np.abs(attitude_rate(tr.t, tr.attitude)[1:-1] - tr.w[1:-1]).max() < 1e-3


def test_stream_and_gyro_lag_of_a_resampled_stream():
    tr = simulate(np.random.default_rng(3), rate_hz=RATE_HZ, duration_s=60.0, rate_rms=1.5)
    lag = 0.3 / RATE_HZ
    late = shift(tr.t, tr.w, -lag)        # the rate at t - lag: late by lag
    found, _ = stream_lag(tr.t, tr.w, late)
    assert abs(found - lag) * RATE_HZ < 0.05
    found, _ = gyro_lag(tr.t, late, tr.attitude)
    assert abs(found - lag) * RATE_HZ < 0.1


def test_shift_resamples_linearly_and_is_nan_outside():
    t = np.arange(10) * 0.1
    x = np.column_stack([2 * t + 1, -t])
    out = shift(t, x, 0.05)
    assert np.allclose(out[:-1], np.column_stack([2 * (t + 0.05) + 1, -(t + 0.05)])[:-1])
    assert np.isnan(out[-1]).all()


def test_a_peak_at_the_edge_of_the_search_is_no_answer():
    tr = manoeuvre(0.2)
    found, _ = magnetometer_lag(tr.t, tr.y, tr.angular_rate, max_lag_s=0.08)
    assert np.isnan(found)


def test_streams_that_never_overlap_have_no_correlation_and_no_warning():
    import warnings

    from magbench.core.lag import _correlation

    a = np.full((10, 3), np.nan)
    a[:5] = 1.0
    b = np.full((10, 3), np.nan)
    b[5:] = 2.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")                  # "Mean of empty slice" would raise
        assert np.isnan(_correlation(a, b))


def test_a_long_recordings_lag_is_the_whole_fits_to_round_off(monkeypatch):
    # Beyond geometry.BLOCK_ROWS samples the lag fit works a block at a time (issue 40): the
    # same A by TSQR, the correlation summed over blocks, so the lag agrees to round-off;
    # centre= centres the field a block at a time.
    from magbench.core import geometry

    lag = 0.37 / RATE_HZ
    tr = manoeuvre(lag, noise=0.005)
    whole, peak = magnetometer_lag(tr.t, tr.y, tr.angular_rate)
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 600)             # 1500 rows: three blocks
    long, long_peak = magnetometer_lag(tr.t, tr.y, tr.angular_rate)
    assert long == pytest.approx(whole, rel=1e-9) and long_peak == pytest.approx(peak, rel=1e-9)
    assert abs(long - lag) * RATE_HZ < 0.15
    centre = np.array([0.3, -0.2, 0.1])
    assert magnetometer_lag(tr.t, tr.y + centre, tr.angular_rate, centre=centre)[0] == \
        pytest.approx(long, rel=1e-9)


@pytest.mark.parametrize("lag", [0.0123, -0.05, 3.0])
def test_a_long_streams_shift_by_blocks_is_the_whole_arrays(monkeypatch, lag):
    # Issue 40: beyond geometry.BLOCK_ROWS rows with increasing times the shift interpolates
    # a block of times at a time from the samples around them: every number (the NaN past
    # either end included) is the whole array's, to the last bit.
    from magbench.core import geometry

    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.005, 0.015, 5000))
    v = rng.normal(size=(3, 5000)).T                      # a log's column layout
    whole = shift(t, v, lag)
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 333)
    blocked = shift(t, v, lag)
    assert np.isnan(whole).any() and np.isfinite(whole).sum() > 1000
    assert np.array_equal(blocked, whole, equal_nan=True)
