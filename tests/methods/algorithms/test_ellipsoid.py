"""The algebraic ellipsoid fit: known answers, rigid-motion invariance, non-ellipsoid data."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.methods.algorithms.ellipsoid import quadric_to_calibration

#: A soft-iron matrix that is neither symmetric nor a multiple of I.
T_TRUE = np.array([[1.10, 0.05, -0.03], [0.02, 0.90, 0.04], [-0.06, 0.01, 1.05]])
H_TRUE = np.array([0.10, -0.20, 0.05])


def symmetric_root(T: np.ndarray) -> np.ndarray:
    """The symmetric positive definite S with S S^T = T T^T."""
    w, V = np.linalg.eigh(T @ T.T)
    return (V * np.sqrt(w)) @ V.T


def test_quadric_to_calibration_known_axis_aligned_answer():
    # x^2/4 + y^2 + z^2/9 = 1 centred at (1, 2, 3): semi-axes 2, 1, 3.
    A = np.diag([1 / 4, 1.0, 1 / 9])
    centre = np.array([1.0, 2.0, 3.0])
    b = -A @ centre
    c = centre @ A @ centre - 1.0
    h, M, T = quadric_to_calibration(3.7 * A, 3.7 * b, 3.7 * c)   # any overall scale
    np.testing.assert_allclose(h, centre, atol=1e-14)
    np.testing.assert_allclose(M, A, atol=1e-14)
    np.testing.assert_allclose(T, np.diag([2.0, 1.0, 3.0]), atol=1e-13)


@pytest.mark.parametrize("constraint", ["trace", "unit"])
def test_noise_free_recovery_returns_the_symmetric_root(constraint):
    y = fibonacci_sphere(50) @ T_TRUE.T + H_TRUE
    cal = magbench.calibrate(y, "ellipsoid", constraint=constraint)
    np.testing.assert_allclose(cal.h, H_TRUE, atol=1e-12)
    np.testing.assert_allclose(cal.T, symmetric_root(T_TRUE), atol=1e-12)
    assert accuracy_cost(cal.T, cal.h, T_TRUE, H_TRUE)[0] < 1e-11
    np.testing.assert_allclose(np.linalg.norm(cal.apply(y), axis=1), 1.0, atol=1e-12)


def test_the_minimum_ten_samples_determine_the_ellipsoid():
    # Nine points always lie on some quadric (9 coefficients up to scale): a fit through them
    # is exact whatever the truth, so nine are refused and ten are the minimum.
    y = fibonacci_sphere(10) @ T_TRUE.T + H_TRUE
    cal = magbench.calibrate(y, "ellipsoid")
    assert accuracy_cost(cal.T, cal.h, T_TRUE, H_TRUE)[0] < 1e-9
    with pytest.raises(ValueError, match="at least 10"):
        magbench.calibrate(y[:9], "ellipsoid")


def test_trace_fit_moves_rigidly_with_the_data(nominal):
    # trace(A) is invariant under rotation and translation, so the fitted ellipsoid of rotated
    # and shifted data is the rotated and shifted ellipsoid: T' = R T R^T, h' = R h + t.
    angle = 0.7
    R = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0],
                  [0.0, 0.0, 1.0]])
    t = np.array([0.3, -0.1, 0.2])
    base = magbench.calibrate(nominal.y, "ellipsoid")
    moved = magbench.calibrate(nominal.y @ R.T + t, "ellipsoid")
    np.testing.assert_allclose(moved.T, R @ base.T @ R.T, atol=1e-10)
    np.testing.assert_allclose(moved.h, R @ base.h + t, atol=1e-10)


@pytest.mark.parametrize("constraint", ["trace", "unit"])
def test_a_hyperboloid_is_not_an_ellipsoid(constraint):
    # Points on the one-sheet hyperboloid x^2 + y^2 - z^2 = 1.
    u = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    v = np.linspace(-1.0, 1.0, 10)
    U, V = np.meshgrid(u, v)
    y = np.column_stack([(np.cosh(V) * np.cos(U)).ravel(), (np.cosh(V) * np.sin(U)).ravel(),
                         np.sinh(V).ravel()])
    with pytest.raises(magbench.CalibrationFailed, match="not an ellipsoid"):
        magbench.calibrate(y, "ellipsoid", constraint=constraint)


def test_unknown_constraint_is_a_value_error(nominal):
    with pytest.raises(ValueError, match="constraint must be one of"):
        magbench.calibrate(nominal.y, "ellipsoid", constraint="bookstein")
