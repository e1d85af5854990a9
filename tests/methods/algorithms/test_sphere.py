"""The closed-form sphere fit: known answer, least-squares optimality, failure."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.methods.algorithms.sphere import fit


def test_noise_free_known_sphere():
    c = np.array([0.3, -0.2, 0.1])
    y = fibonacci_sphere(40, radius=1.7) + c
    cal = magbench.calibrate(y, "sphere")
    np.testing.assert_allclose(cal.T, 1.7 * np.eye(3), atol=1e-13)
    np.testing.assert_allclose(cal.h, c, atol=1e-13)


def test_solution_is_the_linear_least_squares_minimiser(nominal):
    # Independent formulation: ||y||^2 = 2 c^T y + d with an intercept column, r^2 = d + ||c||^2.
    y = nominal.y
    G = np.column_stack([2 * y, np.ones(len(y))])
    sol = np.linalg.lstsq(G, np.sum(y * y, axis=1), rcond=None)[0]
    c, r = sol[:3], np.sqrt(sol[3] + sol[:3] @ sol[:3])
    cal = magbench.calibrate(y, "sphere")
    np.testing.assert_allclose(cal.h, c, atol=1e-12)
    np.testing.assert_allclose(cal.T, r * np.eye(3), atol=1e-12)


def test_soft_iron_is_not_represented(nominal):
    cal = magbench.calibrate(nominal.y, "sphere")
    assert np.count_nonzero(cal.T - np.diag(np.diag(cal.T))) == 0
    assert len(set(np.diag(cal.T))) == 1


def test_coplanar_samples_fail():
    # calibrate() rejects coplanar data first; the method's own guard covers direct calls.
    y = fibonacci_sphere(30)
    y[:, 2] = 0.0
    with pytest.raises(magbench.CalibrationFailed, match="three dimensions"):
        fit(y)
