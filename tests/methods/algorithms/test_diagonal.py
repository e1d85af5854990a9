"""Offset + diagonal scale: known answers, the least-squares refinement, partial coverage."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.methods.algorithms.diagonal import _algebraic_start, fit

S = np.array([1.3, 0.8, 1.05])
H = np.array([0.4, -0.25, 0.1])


def test_noise_free_axis_aligned_ellipsoid_is_recovered_exactly():
    y = fibonacci_sphere(60) * S + H
    assert _algebraic_start(y) is not None
    np.testing.assert_allclose(_algebraic_start(y)[0], S, atol=1e-12)   # closed form exact
    cal = magbench.calibrate(y, "diagonal")
    np.testing.assert_allclose(cal.T, np.diag(S), atol=1e-10)
    np.testing.assert_allclose(cal.h, H, atol=1e-10)


def test_noise_free_cap_of_60_degrees_is_recovered():
    y = fibonacci_sphere(200, z_range=(0.5, 1.0)) * S + H
    cal = magbench.calibrate(y, "diagonal")
    np.testing.assert_allclose(cal.T, np.diag(S), atol=1e-8)
    np.testing.assert_allclose(cal.h, H, atol=1e-8)


def test_cross_coupling_is_not_represented(nominal):
    cal = magbench.calibrate(nominal.y, "diagonal")
    assert np.count_nonzero(cal.T - np.diag(np.diag(cal.T))) == 0
    assert np.all(np.diag(cal.T) > 0)


def test_is_registered_with_its_model():
    spec = magbench.get_method("diagonal")
    assert (spec.model, spec.family, spec.min_samples) == ("diagonal", "extra", 7)


def test_a_quadric_that_is_no_ellipsoid_gives_no_algebraic_start():
    # One-sheet hyperboloid x^2 + y^2 - z^2 = 1: a_3 < 0, so the fit starts from the sphere.
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 12), np.linspace(-1, 1, 7))
    y = np.column_stack([np.cosh(v).ravel() * np.cos(u).ravel(),
                         np.cosh(v).ravel() * np.sin(u).ravel(), np.sinh(v).ravel()])
    assert _algebraic_start(y) is None
    with pytest.raises(magbench.CalibrationFailed, match="not an ellipsoid"):
        fit(y)
