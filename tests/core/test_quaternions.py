"""Quaternion helpers: agreement with rotation matrices, composition, inverse."""

from __future__ import annotations

import numpy as np

from magbench.core.quaternions import (
    matrix_to_quat,
    quat_about_axis,
    quat_conjugate,
    quat_multiply,
    quat_rotate,
    quat_to_matrix,
    quat_to_rotvec,
)
from magbench.core.rotations import rotation_exp


def random_rotations(n: int, seed: int = 0) -> np.ndarray:
    return rotation_exp(np.random.default_rng(seed).normal(size=(n, 3)) * 1.5)


def test_matrix_round_trip_and_unit_norm():
    R = random_rotations(500)
    q = matrix_to_quat(R)
    assert np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-14
    assert np.all(q[:, 0] >= 0)
    assert np.abs(quat_to_matrix(q) - R).max() < 1e-14


def test_rotate_agrees_with_the_matrix_and_products_compose():
    R = random_rotations(200, 1)
    q = matrix_to_quat(R)
    v = np.random.default_rng(2).normal(size=(200, 3))
    assert np.abs(quat_rotate(q, v) - np.einsum("kij,kj->ki", R, v)).max() < 1e-14
    pq = quat_multiply(q[:-1], q[1:])
    assert np.abs(quat_to_matrix(pq) - R[:-1] @ R[1:]).max() < 1e-14
    identity = quat_multiply(q, quat_conjugate(q))
    assert np.abs(identity - [1, 0, 0, 0]).max() < 1e-14


def test_rotation_about_an_axis_is_right_handed():
    q = quat_about_axis(np.array([0.0, 0.0, 2.0]), np.pi / 2)
    assert np.allclose(quat_rotate(q, np.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0])


def test_known_answers_scalar_first_active_hamilton():
    # 90 deg about z: the quaternion (cos 45, 0, 0, sin 45), x -> y, y -> -x (active).
    q = quat_about_axis(np.array([0.0, 0.0, 1.0]), np.pi / 2)
    h = np.sqrt(0.5)
    assert np.allclose(q, [h, 0, 0, h], atol=1e-15)
    assert np.allclose(quat_to_matrix(q), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    assert np.allclose(quat_to_rotvec(q), [0, 0, np.pi / 2], atol=1e-15)
    # Hamilton: i j = k (90 deg about x after 90 deg about y is not about z; i j = k is the
    # product of the 180 deg rotations).
    assert np.allclose(quat_multiply([0, 1, 0, 0], [0, 0, 1, 0]), [0, 0, 0, 1], atol=1e-15)
    # 180 deg about x: w = 0, kept with the first non-zero part positive.
    assert np.allclose(matrix_to_quat(np.diag([1.0, -1.0, -1.0])), [0, 1, 0, 0], atol=1e-15)


def test_missing_rows_stay_missing_and_shapes_broadcast():
    q = np.array([[1.0, 0, 0, 0], [np.nan] * 4, [0.0, 0, 0, 0]])
    R = quat_to_matrix(q)
    assert R.shape == (3, 3, 3)
    assert np.array_equal(R[0], np.eye(3)) and np.isnan(R[1:]).all()
    v = quat_rotate(q, np.array([1.0, 2.0, 3.0]))
    assert np.array_equal(v[0], [1.0, 2.0, 3.0]) and np.isnan(v[1:]).all()
    assert np.isnan(quat_to_rotvec(q)[1:]).all()
    assert quat_to_matrix(np.ones((2, 5, 4))).shape == (2, 5, 3, 3)
    assert quat_multiply(np.ones((2, 5, 4)), np.array([1.0, 0, 0, 0])).shape == (2, 5, 4)
