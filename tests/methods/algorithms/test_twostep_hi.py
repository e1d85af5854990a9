"""TWOSTEP bias-only (Alonso and Shuster 2002a): both steps, stopping rule, failure."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.methods.algorithms.twostep_hi import centred_estimate, effective_measurements, fit
from magbench.sources.synthetic import Point, make_dataset

B_TRUE = np.array([0.04, -0.03, 0.02])


def test_noise_free_bias_is_recovered():
    y = fibonacci_sphere(100) + B_TRUE
    cal = magbench.calibrate(y, "twostep_hi")
    np.testing.assert_array_equal(cal.T, np.eye(3))
    # The only error is the assumed noise mean mu = -3 sigma^2 acting on noise-free data.
    np.testing.assert_allclose(cal.h, B_TRUE, atol=1e-6)
    assert cal.converged


def test_centred_estimate_is_exact_and_field_magnitude_free():
    # Centring removes ||b||^2 and ||H||^2: on noise-free data step 1 is exact whatever the
    # field magnitude, here 1.3 instead of the assumed 1.
    y = 1.3 * fibonacci_sphere(100) + B_TRUE
    b, F = centred_estimate(y, effective_measurements(y), variance=1.0)
    np.testing.assert_allclose(b, B_TRUE, atol=1e-13)
    assert np.all(np.linalg.eigvalsh(F) > 0)


def test_gauss_newton_reaches_the_minimum_of_the_full_cost():
    rng = np.random.default_rng(4)
    sigma = 0.005
    y = fibonacci_sphere(300) + B_TRUE + rng.normal(0.0, sigma, (300, 3))
    cal = fit(y, sigma=sigma, tol=1e-12)

    def residuals(b):   # z_k - 2 y_k^T b + ||b||^2 - mu_k, all weights equal
        return effective_measurements(y) - 2 * y @ b + b @ b + 3 * sigma**2

    best = scipy.optimize.least_squares(residuals, np.zeros(3), xtol=1e-15, ftol=1e-15,
                                        gtol=1e-15).x
    np.testing.assert_allclose(cal.h, best, atol=1e-10)
    step1, _ = centred_estimate(y, effective_measurements(y), variance=1.0)
    assert not np.allclose(step1, best, atol=1e-8)   # so step 2 did something


def test_iteration_cap_is_reported(nominal):
    cal = fit(nominal.y, tol=0.0, max_iter=3)
    assert not cal.converged and cal.n_iter == 3
    assert "iteration cap 3" in cal.message


def test_sigma_must_be_positive(nominal):
    with pytest.raises(ValueError, match="sigma must be > 0"):
        magbench.calibrate(nominal.y, "twostep_hi", sigma=0.0)


def test_coplanar_samples_fail():
    y = fibonacci_sphere(30)
    y[:, 2] = 0.0
    with pytest.raises(magbench.CalibrationFailed, match="not positive definite"):
        fit(y)


def test_field_norm_sets_the_scale():
    # Data in another unit with the known magnitude given: T and h come out in that unit.
    import magbench

    d = make_dataset(np.random.default_rng(3), Point(sigma=0.0, beta=0.0, alpha_low=1.0,
                                                     alpha_high=1.0))
    cal = magbench.calibrate(d.y * 48.5, "twostep_hi", field_norm=48.5)
    np.testing.assert_allclose(cal.T, 48.5 * np.eye(3), rtol=1e-12)
    np.testing.assert_allclose(cal.h, 48.5 * d.h, atol=1e-5)
