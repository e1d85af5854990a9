"""Rotations: known answers of the exponential map and of the Euler angles' order."""

from __future__ import annotations

import numpy as np

from magbench.core.rotations import (
    cross_rows,
    cumulative_product,
    euler_zyx_to_matrix,
    rotation_exp,
    skew,
)


def test_exponential_map_known_answers():
    Rz90 = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    assert np.allclose(rotation_exp(np.array([0.0, 0.0, np.pi / 2])), Rz90, atol=1e-15)
    assert np.array_equal(rotation_exp(np.zeros(3)), np.eye(3))
    # Near zero: I + [phi]x to second order, no cancellation.
    phi = np.array([1e-9, -2e-9, 3e-9])
    assert np.allclose(rotation_exp(phi), np.eye(3) + skew(phi), rtol=0, atol=1e-17)
    assert rotation_exp(np.zeros((2, 5, 3))).shape == (2, 5, 3, 3)


def test_cross_rows_are_numpys_cross_products_bit_for_bit():
    gen = np.random.default_rng(3)
    a, b = gen.normal(size=(500, 3)) * 1e3, gen.normal(size=(500, 3))
    assert np.array_equal(cross_rows(a, b), np.cross(a, b))
    assert np.array_equal(cross_rows(a[:1], b), np.cross(a[:1], b))     # one row against many
    x, y, z = np.eye(3)
    assert np.array_equal(cross_rows(np.array([x, y]), np.array([y, z])), [z, x])


def test_euler_zyx_is_yaw_after_pitch_after_roll():
    x, y, z = np.eye(3)
    assert np.allclose(euler_zyx_to_matrix(0.0, 0.0, np.pi / 2) @ x, y, atol=1e-15)     # yaw
    assert np.allclose(euler_zyx_to_matrix(np.pi / 2, 0.0, 0.0) @ y, z, atol=1e-15)     # roll
    assert np.allclose(euler_zyx_to_matrix(0.0, np.pi / 2, 0.0) @ z, x, atol=1e-15)     # pitch
    a = np.array([0.3, -0.2, 1.1])
    expected = (rotation_exp(a[2] * z) @ rotation_exp(a[1] * y) @ rotation_exp(a[0] * x))
    assert np.allclose(euler_zyx_to_matrix(*a), expected, atol=1e-15)
    assert euler_zyx_to_matrix(np.zeros(4), 0.0, np.ones(4)).shape == (4, 3, 3)


def test_cumulative_product_is_the_running_product():
    steps = rotation_exp(np.random.default_rng(0).normal(size=(7, 3)))
    P = cumulative_product(steps)
    assert np.allclose(P[-1], np.linalg.multi_dot(list(steps)), atol=1e-14)
