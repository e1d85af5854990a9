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
