"""Mounting rotations: ArduPilot's rotation matrices, every rotation found from a simulated
attitude (the confidences printed), a refusal when the attitude barely changes."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.mounting import (
    AUTO_ROTATIONS,
    MIN_CONFIDENCE,
    ROTATIONS,
    detect_mounting,
    rotation_matrix,
)
from magbench.sources.trajectory import simulate

#: ArduPilot's own test (AP_Math tests, TEST_ROTATION): (1, 1, 1) rotated by each rotation.
AP_VECTORS = {
    0: (1, 1, 1), 2: (-1, 1, 1), 8: (1, -1, -1), 12: (-1, 1, -1), 24: (1, 1, -1),
    25: (-1, 1, 1), 26: (-1, -1, -1), 37: (-1, -1, 1), 36: (1, -1, -1),
    38: (-0.4066309, -1.5839677, -0.5706992), 39: (0, 1, np.sqrt(2)),
    40: (0, -1, np.sqrt(2)), 41: (1.1144155, 1, 0.87067682),
}


@pytest.mark.parametrize("rotation", sorted(AP_VECTORS))
def test_rotation_matrices_match_ardupilots_test_vectors(rotation):
    np.testing.assert_allclose(rotation_matrix(rotation) @ np.ones(3), AP_VECTORS[rotation],
                               atol=1e-6)


def test_rotations_are_proper_and_only_26_27_repeat_others():
    mats = {r: rotation_matrix(r) for r in ROTATIONS}
    for M in mats.values():
        np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(M), 1.0)
    same = {(a, b) for a in mats for b in mats if a < b and np.allclose(mats[a], mats[b])}
    assert same == {(10, 27), (14, 26)}


def flight(rotation: int, seed: int = 1, noise: float = 0.01):
    """Calibrated samples in the compass's axes, and the attitude, of a random manoeuvre."""
    rng = np.random.default_rng(seed)
    traj = simulate(rng, duration_s=20.0, rate_hz=10.0)
    m_sensor = traj.m @ rotation_matrix(rotation)          # M^T m_body, row by row
    return m_sensor + rng.normal(0.0, noise, m_sensor.shape), traj.R


def test_every_standard_rotation_is_found_with_its_confidence():
    lowest = np.inf
    for rotation in AUTO_ROTATIONS:
        m, R = flight(rotation)
        found = detect_mounting(m, attitude=R)
        print(f"{rotation:2d} {ROTATIONS[rotation][0]:<36} -> {found.rotation} "
              f"confidence {found.confidence:8.1f}")
        assert found.rotation is not None, found.line()
        np.testing.assert_allclose(rotation_matrix(found.rotation), rotation_matrix(rotation),
                                   atol=1e-9)
        assert found.rotation <= rotation          # a repeated matrix reports the first id
        lowest = min(lowest, found.confidence)
    assert lowest > 10 * MIN_CONFIDENCE


def test_accelerometer_at_rest_finds_the_rotation_from_the_dip():
    rng = np.random.default_rng(3)
    traj = simulate(rng, duration_s=20.0, rate_hz=10.0)
    accel = -9.81 * traj.R[:, 2, :]                     # specific force: -g in body axes
    for rotation in (0, 5, 17, 38):
        m = traj.m @ rotation_matrix(rotation) + rng.normal(0.0, 0.01, traj.m.shape)
        found = detect_mounting(m, accel=accel)
        assert found.basis == "accelerometer" and found.rotation is not None
        np.testing.assert_allclose(rotation_matrix(found.rotation), rotation_matrix(rotation),
                                   atol=1e-9)


def test_refuses_when_the_attitude_barely_changes():
    m, R = flight(2)
    still = detect_mounting(np.repeat(m[:1], 200, 0) + np.random.default_rng(0).normal(
        0.0, 0.01, (200, 3)), attitude=np.repeat(R[:1], 200, 0))
    assert still.rotation is None and still.confidence < MIN_CONFIDENCE
    assert still.reason.startswith("confidence ") and "turned through 0 deg" in still.reason
    assert still.line().startswith("mounting rotation: not detected (confidence")
    assert still.to_dict()["id"] is None
    few = detect_mounting(m[:10], attitude=R[:10])
    assert few.rotation is None and few.reason == ("10 samples with an attitude, at least 20 "
                                                   "are needed")
    with pytest.raises(ValueError, match="needs an attitude or an accelerometer"):
        detect_mounting(m)
