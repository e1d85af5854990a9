"""The adjusted least squares ellipsoid fit: adjusted moments, recovery, consistency."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.methods.algorithms.als import _adjusted_powers, _powers, adjusted_matrix
from magbench.sources.synthetic import Point, make_dataset

T_TRUE = np.array([[1.10, 0.05, -0.03], [0.02, 0.90, 0.04], [-0.06, 0.01, 1.05]])
H_TRUE = np.array([0.10, -0.20, 0.05])


def test_adjusted_powers_are_unbiased_for_the_noise_free_powers():
    # E t_p(x + e) = x^p for e ~ N(0, s), evaluated exactly by Gauss-Hermite quadrature
    # (exact for polynomials of degree < 2 * 6).
    nodes, weights = np.polynomial.hermite_e.hermegauss(6)
    weights = weights / weights.sum()
    x, s = np.array([[-1.3, 0.4, 2.0]]), 0.09
    expected = np.zeros((5, 1, 3))
    for e, w in zip(nodes * np.sqrt(s), weights, strict=True):
        expected += w * _adjusted_powers(_powers(x + e), s)
    np.testing.assert_allclose(expected, _powers(x), rtol=1e-12, atol=1e-12)


def test_noise_free_matrix_has_the_true_quadric_in_its_null_space():
    y = fibonacci_sphere(40) @ T_TRUE.T + H_TRUE
    M = np.linalg.inv(T_TRUE @ T_TRUE.T)
    beta = np.array([M[0, 0], M[1, 1], M[2, 2], M[0, 1], M[0, 2], M[1, 2],
                     *(-M @ H_TRUE), H_TRUE @ M @ H_TRUE - 1.0])
    psi = adjusted_matrix(_powers(y), 0.0)
    assert np.linalg.norm(psi @ beta) < 1e-13 * np.linalg.norm(psi)


def test_noise_free_recovery_with_the_variance_estimated_as_zero():
    y = fibonacci_sphere(50) @ T_TRUE.T + H_TRUE
    cal = magbench.calibrate(y, "als")
    assert accuracy_cost(cal.T, cal.h, T_TRUE, H_TRUE)[0] < 1e-9
    assert "noise std 0 (estimated)" in cal.message


def test_consistent_where_the_algebraic_fit_is_biased():
    # Large noise and many samples: the algebraic fit keeps its bias, ALS does not, and the
    # variance estimate finds the true noise level.
    errors = {"als": [], "ellipsoid": []}
    for seed in range(3):
        data = make_dataset(np.random.default_rng(seed), Point(K=20000, sigma=0.1))
        for name, found in errors.items():
            cal = magbench.calibrate(data.y, name)
            found.append(accuracy_cost(cal.T, cal.h, data.T, data.h)[0])
            if name == "als":
                assert float(cal.message.split("noise std ")[1].split()[0]) == \
                    pytest.approx(0.1, rel=0.02)
    assert np.mean(errors["als"]) < 0.4 * np.mean(errors["ellipsoid"])


def test_a_given_noise_level_is_used_and_checked():
    data = make_dataset(np.random.default_rng(1), Point(K=2000, sigma=0.05))
    given = magbench.calibrate(data.y, "als", noise_std=0.05)
    estimated = magbench.calibrate(data.y, "als")
    assert "(given)" in given.message
    assert accuracy_cost(given.T, given.h, estimated.T, estimated.h)[0] < 0.01
    with pytest.raises(ValueError, match="noise_std"):
        magbench.calibrate(data.y, "als", noise_std=-1.0)


def test_centring_and_scaling_change_only_the_conditioning():
    # ALS with the estimated variance is similarity invariant: the fit on the raw samples (no
    # centring, no scaling) is the fit of calibrate to rounding.
    from magbench.methods.algorithms import als
    from magbench.methods.algorithms.ellipsoid import quadric_to_calibration

    y = make_dataset(np.random.default_rng(3), Point(K=500, sigma=0.02, gamma=0.5)).y
    powers = _powers(y)
    v = np.linalg.eigh(adjusted_matrix(powers, als.noise_variance(powers)))[1][:, 0]
    A = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    h, _, T = quadric_to_calibration(A, v[6:9], float(v[9]))
    cal = magbench.calibrate(y, "als")
    np.testing.assert_allclose(cal.h, h, atol=1e-12)
    np.testing.assert_allclose(cal.T, T, atol=1e-12)


def test_the_adjusted_matrix_is_exactly_quadratic_in_the_noise_variance():
    """P0 + s P1 + s^2 P2, built once, equals the matrix rebuilt from the samples at each s
    (to rounding), so the root search may evaluate the polynomial."""
    from magbench.methods.algorithms.als import adjusted_polynomial

    y = np.random.default_rng(3).standard_normal((200, 3))
    powers = _powers(y)
    P = adjusted_polynomial(powers)
    for s in (0.0, 1e-4, 0.01, 0.3, 2.0):
        direct = adjusted_matrix(powers, s)
        assert np.allclose(P[0] + s * P[1] + s * s * P[2], direct, rtol=0, atol=1e-12)
