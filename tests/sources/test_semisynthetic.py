"""Semi-synthetic source: lag removed, clean rows and reference found, distortions exact."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.sources.recordings import InertialRecording
from magbench.sources.semisynthetic import distort, movement_mask, prepare
from magbench.sources.synthetic import Point
from magbench.sources.trajectory import simulate

B = 44.0


def recording(lag_s: float = 0.012, seed: int = 0) -> tuple[InertialRecording, object]:
    tr = simulate(np.random.default_rng(seed), rate_hz=50.0, duration_s=40.0, rate_rms=1.5,
                  lag_s=lag_s, mag_noise=0.002)
    y = B * tr.y
    y[300:340] += np.array([0.0, 0.0, 20.0])             # a magnet passing by
    q = tr.attitude.copy()
    q[:25] = np.nan                                        # the reference starts late
    return InertialRecording("sim", tr.t, y, tr.angular_rate, tr.acceleration, q), tr


def test_prepare_measures_the_lag_and_finds_the_clean_rows_and_the_reference():
    rec, tr = recording()
    p = prepare(rec)
    assert p.lag_s == pytest.approx(0.012, abs=0.002)
    assert abs(p.gyro_lag_s) < 0.002
    assert p.strength == pytest.approx(B, rel=1e-3)
    assert np.allclose(p.reference / p.strength, tr.m0, atol=2e-3)
    t_disturbed = (p.rec.t >= tr.t[300]) & (p.rec.t <= tr.t[339])
    near = (p.rec.t >= tr.t[298]) & (p.rec.t <= tr.t[341])     # resampling blurs one sample
    assert not p.clean[t_disturbed].any() and p.clean[~near][30:].all()


def test_distortions_follow_the_model():
    rec, _ = recording(lag_s=0.0)
    p = prepare(rec)
    d = distort(np.random.default_rng(1), p, "eq80", mount_deg=3.0)
    assert np.allclose(d.y, p.rec.y / p.strength @ d.T.T + d.h)
    angle = np.degrees(np.arccos((np.trace(d.mount) - 1) / 2))
    assert angle == pytest.approx(3.0)
    plain = distort(np.random.default_rng(1), p, "eq80", mount_deg=3.0)
    magnet = distort(np.random.default_rng(1), p, "magnet", mount_deg=3.0)
    assert np.allclose(plain.T, magnet.T)
    assert np.linalg.norm(magnet.h - plain.h) == pytest.approx(26.7 / 44.0)
    assert np.abs(plain.h).max() <= Point().gamma
    with pytest.raises(ValueError, match="distortion must be"):
        distort(np.random.default_rng(1), p, "bogus")


def test_movement_mask_spans_the_motion():
    t = np.arange(0, 30, 0.02)
    w = np.zeros((len(t), 3))
    w[(t > 10) & (t < 20), 2] = 1.0
    mask = movement_mask(t, w)
    # a one-second average passes 0.1 rad/s once a tenth of the window moves at 1 rad/s
    assert t[mask][0] == pytest.approx(9.6, abs=0.05)
    assert t[mask][-1] == pytest.approx(20.4, abs=0.05)
