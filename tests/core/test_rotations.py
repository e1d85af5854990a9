"""Quaternions: the matrix of a quaternion, its inverse, and the Euler-angle quaternion."""

from __future__ import annotations

import numpy as np

from magbench.core.rotations import (
    euler_zyx_to_matrix,
    euler_zyx_to_quaternion,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_exp,
)


def test_quaternion_matrix_round_trip_and_euler_agree():
    rng = np.random.default_rng(0)
    R = rotation_exp(rng.normal(size=(500, 3)) * 2.0)
    q = matrix_to_quaternion(R)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-12)
    angles = rng.uniform(-3.0, 3.0, size=(3, 200))
    np.testing.assert_allclose(quaternion_to_matrix(euler_zyx_to_quaternion(*angles)),
                               euler_zyx_to_matrix(*angles), atol=1e-12)


def test_known_quaternions():
    """A 90 deg yaw is (cos 45, 0, 0, sin 45) and turns x into y; a scaled quaternion is
    normalised first."""
    q = euler_zyx_to_quaternion(0.0, 0.0, np.pi / 2)
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(quaternion_to_matrix(3 * q) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
