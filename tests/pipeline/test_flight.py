"""Mounting rotation from simulated flight logs: every standard rotation found through the ULog
reader and a calibration, the confidence printed; a refusal without attitude change."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import magbench
from magbench.core.mounting import AUTO_ROTATIONS, MIN_CONFIDENCE, ROTATIONS, rotation_matrix
from magbench.core.quaternions import matrix_to_quat
from magbench.pipeline.flight import mounting_rotation
from magbench.sources.recordings import read_samples
from magbench.sources.trajectory import simulate
from tests.sources.log_writers import write_ulog

T_TRUE = 0.5 * np.array([[1.05, 0.03, -0.02], [0.03, 0.95, 0.04], [-0.02, 0.04, 1.0]])
H_TRUE = np.array([0.12, -0.05, 0.2])


def current_profile(t: np.ndarray) -> np.ndarray:
    """A battery current (A) that rises and falls as a throttle would, 0 to 20 A."""
    return 20 * np.clip(0.5 + 0.3 * np.sin(0.44 * t + 1) + 0.2 * np.sin(1.45 * t), 0, 1)


def simulated_ulog(path: Path, rotation: int, seed: int = 0, seconds: float = 30.0,
                   motor: np.ndarray | None = None) -> Path:
    """A PX4 log of a calibration manoeuvre: ``sensor_mag`` (gauss, 20 Hz) of a compass mounted
    with ``rotation``, distorted by ``T_TRUE``, ``H_TRUE``; ``vehicle_attitude`` at 40 Hz;
    with ``motor`` (gauss per A), ``battery_status`` at 40 Hz and ``motor * current`` added."""
    rng = np.random.default_rng(seed)
    traj = simulate(rng, duration_s=seconds, rate_hz=40.0)
    m_sensor = traj.m @ rotation_matrix(rotation)
    y = m_sensor @ T_TRUE.T + H_TRUE + rng.normal(0.0, 0.002, m_sensor.shape)
    current = current_profile(traj.t)
    if motor is not None:
        y = y + current[:, None] * np.asarray(motor)
    q = matrix_to_quat(traj.R)
    us = np.round((traj.t + 1.0) * 1e6).astype(int)
    mag_fields = [("uint64_t", "timestamp"), ("float", "x"), ("float", "y"), ("float", "z")]
    battery = [("battery_status", 0, [("uint64_t", "timestamp"), ("float", "current_a")],
                [(int(u), float(c)) for u, c in zip(us, current, strict=True)])]
    return write_ulog(path, (battery if motor is not None else []) + [
        ("sensor_mag", 0, mag_fields, [(int(u), *v) for u, v in zip(us[::2], y[::2],
                                                                      strict=True)]),
        ("vehicle_attitude", 0, [("uint64_t", "timestamp"), ("float[4]", "q")],
         [(int(u), list(v)) for u, v in zip(us, q, strict=True)]),
    ])


def test_every_standard_rotation_is_found_from_a_simulated_log(tmp_path):
    lowest = np.inf
    for rotation in AUTO_ROTATIONS:
        rec = read_samples(simulated_ulog(tmp_path / f"r{rotation}.ulg", rotation, seed=rotation,
                                          seconds=15.0))
        A, b = magbench.calibrate(rec.y, "fang").correction()
        found = mounting_rotation(rec, A, b)
        print(f"{rotation:2d} {ROTATIONS[rotation][0]:<36} -> {found.rotation} "
              f"confidence {found.confidence:7.1f}")
        assert found.rotation is not None, found.line()
        np.testing.assert_allclose(rotation_matrix(found.rotation), rotation_matrix(rotation),
                                   atol=1e-9)
        lowest = min(lowest, found.confidence)
    assert lowest > 10 * MIN_CONFIDENCE


def test_refuses_when_the_logged_attitude_does_not_change(tmp_path):
    rec = read_samples(simulated_ulog(tmp_path / "r2.ulg", 2, seconds=15.0))
    frozen = {c: np.full(rec.K, v[0]) if c in ("qw", "qx", "qy", "qz") else v
              for c, v in rec.extra.items()}
    A, b = magbench.calibrate(rec.y, "fang").correction()
    found = mounting_rotation(type(rec)(**{**rec.__dict__, "extra": frozen}), A, b)
    assert found.rotation is None and found.confidence < MIN_CONFIDENCE
    assert "turned through 0 deg" in found.reason
    # Neither attitude nor accelerometer: nothing to say.
    assert mounting_rotation(type(rec)(**{**rec.__dict__, "extra": {
        "current": np.zeros(rec.K)}}), A, b) is None
