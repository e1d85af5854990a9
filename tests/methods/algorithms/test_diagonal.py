"""Offset + diagonal scale: known answers, the least-squares refinement, partial coverage."""

from __future__ import annotations

import numpy as np
import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.methods.algorithms.diagonal import _algebraic_start

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


def test_refinement_minimises_the_norm_residuals():
    rng = np.random.default_rng(4)
    y = fibonacci_sphere(300) * S + H + 0.01 * rng.standard_normal((300, 3))
    cal = magbench.calibrate(y, "diagonal")

    def cost(s, h):
        return np.sum((np.linalg.norm((y - h) / s, axis=1) - 1) ** 2)

    best = cost(np.diag(cal.T), cal.h)
    for k in range(6):                 # a stationary point: every small move costs more
        for eps in (1e-4, -1e-4):
            s, h = np.diag(cal.T).copy(), cal.h.copy()
            (s if k < 3 else h)[k % 3] += eps
            assert cost(s, h) >= best
    assert cal.converged


def test_cross_coupling_is_not_represented(nominal):
    cal = magbench.calibrate(nominal.y, "diagonal")
    assert np.count_nonzero(cal.T - np.diag(np.diag(cal.T))) == 0
    assert np.all(np.diag(cal.T) > 0)


def test_is_registered_with_its_model():
    spec = magbench.get_method("diagonal")
    assert (spec.model, spec.family, spec.min_samples) == ("diagonal", "extra", 6)


def test_a_quadric_that_is_no_ellipsoid_gives_no_algebraic_start():
    # One-sheet hyperboloid x^2 + y^2 - z^2 = 1: a_3 < 0, so the fit starts from the sphere.
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 12), np.linspace(-1, 1, 7))
    y = np.column_stack([np.cosh(v).ravel() * np.cos(u).ravel(),
                         np.cosh(v).ravel() * np.sin(u).ravel(), np.sinh(v).ravel()])
    assert _algebraic_start(y) is None
