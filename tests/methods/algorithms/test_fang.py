"""Fang et al. (2011): constraint, eigenvector choice, unit-mean-norm scale, failure."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.methods.algorithms.fang import C11, constrained_quadric, design_matrix

T_TRUE = np.array([[1.10, 0.05, -0.03], [0.02, 0.90, 0.04], [-0.06, 0.01, 1.05]])
H_TRUE = np.array([0.10, -0.20, 0.05])


def test_noise_free_recovery():
    y = fibonacci_sphere(60) @ T_TRUE.T + H_TRUE
    cal = magbench.calibrate(y, "fang")
    assert accuracy_cost(cal.T, cal.h, T_TRUE, H_TRUE)[0] < 1e-11
    np.testing.assert_allclose(cal.T, cal.T.T, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(cal.apply(y), axis=1), 1.0, atol=1e-12)


def test_noise_free_answer_equals_the_ellipsoid_fit():
    y = fibonacci_sphere(60) @ T_TRUE.T + H_TRUE
    fang = magbench.calibrate(y, "fang")
    ellipsoid = magbench.calibrate(y, "ellipsoid")
    np.testing.assert_allclose(fang.T, ellipsoid.T, atol=1e-12)
    np.testing.assert_allclose(fang.h, ellipsoid.h, atol=1e-12)


def test_calibrated_samples_have_unit_mean_norm(nominal):
    cal = magbench.calibrate(nominal.y, "fang")
    norms = np.linalg.norm(cal.apply(nominal.y), axis=1)
    assert abs(norms.mean() - 1.0) < 1e-12
    assert norms.std() > 1e-4          # noisy data: the norms are not all one, only their mean


def test_unit_mean_norm_holds_in_any_unit(nominal):
    y = nominal.y * 48_000.0            # nT instead of unit field
    cal = magbench.calibrate(y, "fang")
    assert abs(np.linalg.norm(cal.apply(y), axis=1).mean() - 1.0) < 1e-12


def test_coefficients_solve_the_constrained_generalised_eigenproblem(nominal):
    # Independent check of the 3x3 reduction: the full 10x10 pencil (S^T S, C) has exactly one
    # finite positive eigenvalue, and its eigenvector is the constrained minimiser.
    y = nominal.y - nominal.y.mean(axis=0)
    a = constrained_quadric(y)
    assert 4 * a[0] * a[2] - a[1] ** 2 == pytest.approx(1.0, abs=1e-12)
    D = design_matrix(y)
    C = np.zeros((10, 10))
    C[:3, :3] = C11
    values, vectors = scipy.linalg.eig(D.T @ D, C)
    finite = np.isfinite(values) & (np.abs(values.imag) < 1e-9)
    positive = np.flatnonzero(finite & (values.real > 0))
    assert positive.size == 1
    v = np.real(vectors[:, positive[0]])
    v = v / np.sqrt(v[:3] @ C11 @ v[:3])
    v = v * np.sign(v[0] * a[0])
    np.testing.assert_allclose(a, v, rtol=1e-6, atol=1e-9)


def test_a_hyperboloid_is_not_an_ellipsoid():
    # x^2 + y^2 - z^2 = 1 satisfies 4ac - b^2 > 0 in its x-y block but is not an ellipsoid.
    u = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    v = np.linspace(-1.0, 1.0, 10)
    U, V = np.meshgrid(u, v)
    y = np.column_stack([(np.cosh(V) * np.cos(U)).ravel(), (np.cosh(V) * np.sin(U)).ravel(),
                         np.sinh(V).ravel()])
    with pytest.raises(magbench.CalibrationFailed, match="not an ellipsoid"):
        magbench.calibrate(y, "fang")
