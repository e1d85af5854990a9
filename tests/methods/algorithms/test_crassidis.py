"""Crassidis et al. EKF (review Algorithm 2): Jacobian, fixed points, online form, bounds."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.core.model import CalibrationFailed
from magbench.methods.algorithms import crassidis
from magbench.methods.algorithms._twostep_model import pack_symmetric, unpack_symmetric
from tests.conftest import dataset

D_KNOWN = np.array([[0.10, 0.02, -0.03],
                    [0.02, -0.05, 0.01],
                    [-0.03, 0.01, 0.08]])
B_KNOWN = np.array([0.04, -0.02, 0.03])

#: Noise-free single-pass bound. A single EKF pass linearises the early samples far from the
#: truth and its covariance then shrinks like 1/k, so those errors are never undone: over 500
#: noise-free nominal datasets (eq. 80 ranges, sigma = 0) the default filter met J <= 3.7e-3
#: (mean 7.4e-4); three passes give <= 7e-4, ten <= 2.1e-4.
SINGLE_PASS_BOUND = 1e-2


def known_data() -> np.ndarray:
    """Noise-free ``y = (I + D)^-1 (m + b)``, the model of (17)."""
    return (fibonacci_sphere(300) + B_KNOWN) @ np.linalg.inv(np.eye(3) + D_KNOWN).T


def test_jacobian_matches_the_printed_form_and_finite_differences():
    rng = np.random.default_rng(4)
    for _ in range(5):
        y_k, theta = rng.normal(size=3), 0.3 * rng.normal(size=9)
        G = crassidis.correction_maps(y_k[None, :])[0]
        u = y_k + G @ theta
        literal = crassidis.jacobian_literal(y_k, theta)
        np.testing.assert_allclose(-2.0 * u @ G, literal, atol=1e-14)
        eps = 1e-6
        numeric = [(crassidis.measurement_model(y_k, theta + eps * e)
                    - crassidis.measurement_model(y_k, theta - eps * e)) / (2 * eps)
                   for e in np.eye(9)]
        np.testing.assert_allclose(numeric, literal, atol=1e-8)
        # (17) is ||y||^2 - ||(I + D) y - b||^2, the form the filter evaluates.
        assert crassidis.measurement_model(y_k, theta) == pytest.approx(y_k @ y_k - u @ u,
                                                                       abs=1e-13)


def test_the_truth_is_a_fixed_point_and_maps_to_model_2():
    theta_true = np.concatenate([B_KNOWN, pack_symmetric(D_KNOWN)])
    cal = magbench.calibrate(known_data(), "crassidis", theta0=theta_true, P0=1.0)
    T = np.linalg.inv(np.eye(3) + D_KNOWN)
    np.testing.assert_allclose(cal.T, T, atol=1e-13)
    np.testing.assert_allclose(cal.h, T @ B_KNOWN, atol=1e-13)       # h = (I + D)^-1 b
    review = magbench.calibrate(known_data(), "crassidis", theta0=theta_true, bias="review")
    np.testing.assert_allclose(review.h, B_KNOWN, atol=1e-13)        # (22) as printed


def test_degenerate_zero_residual_solution_is_a_fixed_point():
    # D = -I, ||b|| = 1 maps every sample to u_k = -b on the unit sphere: zero innovation for
    # any constant-magnitude data, and T = (I + D)^-1 does not exist.
    theta = np.array([0.0, 0.0, 1.0, -1.0, -1.0, -1.0, 0.0, 0.0, 0.0])
    d = dataset(0)
    out, _ = crassidis.run_filter(d.y, theta.copy(), np.eye(9), 0.005, "5b", 1)
    np.testing.assert_allclose(out, theta, atol=1e-14)  # up to rounding in u_k
    with pytest.raises(CalibrationFailed, match="singular"):
        magbench.calibrate(d.y, "crassidis", theta0=theta)


def test_processing_in_two_chunks_equals_one_pass(nominal):
    # The online form: the state (theta, P) after the first half is all the second half needs.
    P0 = crassidis.initial_covariance("prior")
    full, P_full = crassidis.run_filter(nominal.y, np.zeros(9), P0.copy(), 0.005, "5b", 1)
    half, P_half = crassidis.run_filter(nominal.y[:150], np.zeros(9), P0.copy(), 0.005, "5b", 1)
    both, P_both = crassidis.run_filter(nominal.y[150:], half, P_half, 0.005, "5b", 1)
    np.testing.assert_array_equal(both, full)
    np.testing.assert_array_equal(P_both, P_full)


@pytest.mark.parametrize("seed", range(10))
def test_noise_free_single_pass_meets_its_bound_and_more_passes_improve(seed):
    d = dataset(seed, sigma=0.0)
    one = magbench.calibrate(d.y, "crassidis")
    ten = magbench.calibrate(d.y, "crassidis", passes=10)
    J1 = accuracy_cost(one.T, one.h, d.T, d.h)[0]
    J10 = accuracy_cost(ten.T, ten.h, d.T, d.h)[0]
    assert J1 < SINGLE_PASS_BOUND
    assert J10 < 5e-4 and J10 < J1
    assert one.n_iter == 300 and ten.n_iter == 3000 and one.converged


def test_nominal_accuracy_is_near_the_noise_floor(nominal):
    cal = magbench.calibrate(nominal.y, "crassidis")
    assert accuracy_cost(cal.T, cal.h, nominal.T, nominal.h)[0] < 0.01


def test_initial_covariance_forms():
    np.testing.assert_array_equal(crassidis.initial_covariance(0.5), 0.5 * np.eye(9))
    np.testing.assert_array_equal(crassidis.initial_covariance(np.arange(1.0, 10.0)),
                                  np.diag(np.arange(1.0, 10.0)))
    np.testing.assert_array_equal(crassidis.initial_covariance("prior"),
                                  np.diag(crassidis.DEFAULT_P0_STD**2))


def test_data_prior_is_the_sphere_fit_on_known_data():
    # Samples on a sphere of radius r = 2 about c: the sphere fit is exact and e = 0, so the
    # start is b = c / r, D = (1/r - 1) I and the covariance vanishes; an ellipsoid's relative
    # spread of radii gives e^2 on D and e^2 (1 + |b|^2) on b.
    m = fibonacci_sphere(200)
    c = np.array([0.3, -0.6, 0.9])
    theta0, P = crassidis.data_prior(2.0 * m + c)
    np.testing.assert_allclose(theta0, np.r_[c / 2.0, np.full(3, -0.5), np.zeros(3)],
                               atol=1e-12)
    np.testing.assert_allclose(P, 0.0, atol=1e-12)
    theta0, P = crassidis.data_prior(m * [1.1, 1.0, 0.9] + c)
    e2 = P[8, 8]
    assert 1e-3 < e2 < 1e-2                                  # ~ (0.1)^2 / 1.2 relative spread
    np.testing.assert_allclose(np.diag(P), np.r_[np.full(3, e2 * (1 + theta0[:3] @ theta0[:3])),
                                                 np.full(6, e2)])
    np.testing.assert_array_equal(P, np.diag(np.diag(P)))
    np.testing.assert_array_equal(crassidis.initial_covariance("data", 2.0 * m),
                                  crassidis.data_prior(2.0 * m)[1])


def test_default_P0_is_the_data_prior_and_prior_is_the_variant(nominal):
    default = magbench.calibrate(nominal.y, "crassidis")
    theta0, P0 = crassidis.data_prior(nominal.y)
    data = magbench.calibrate(nominal.y, "crassidis", theta0=theta0, P0=P0)
    prior = magbench.calibrate(nominal.y, "crassidis_prior")
    explicit = magbench.calibrate(nominal.y, "crassidis", P0="prior", theta0=np.zeros(9))
    np.testing.assert_array_equal(default.T, data.T)
    np.testing.assert_array_equal(prior.T, explicit.T)
    assert not np.array_equal(default.T, prior.T)
    assert magbench.get_method("crassidis_prior").family == "variant"


@pytest.mark.parametrize(("option", "value", "match"), [
    ("P0", -np.eye(9), "positive definite"),
    ("P0", np.eye(3), "P0 must be"),
    ("P0", "truth", r"P0 must be one of \('data', 'prior'\)"),
    ("P0", [1.0, np.nan] * 4 + [1.0], "P0 must be"),
    ("theta0", np.zeros(3), "theta0"),
    ("variance", "other", "variance"),
    ("passes", 0, "passes"),
    ("sigma", 0.0, "sigma"),
    ("bias", "other", "bias"),
])
def test_bad_options_are_value_errors(nominal, option, value, match):
    with pytest.raises(ValueError, match=match):
        magbench.calibrate(nominal.y, "crassidis", **{option: value})


def test_unpack_symmetric_round_trip():
    np.testing.assert_array_equal(unpack_symmetric(pack_symmetric(D_KNOWN)), D_KNOWN)
