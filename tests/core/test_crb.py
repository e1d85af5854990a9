"""The Cramer-Rao bound: a closed form, the gauge, and an ML method's Monte Carlo error."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import magbench
from magbench.core.crb import crb_mse, efficient_expected_J, fisher_information, gauge_basis
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.sources.synthetic import Point, make_dataset


def test_sphere_closed_form():
    # T = I, uniform directions: 9 sigma^2/K for h and 40.5 sigma^2/K for T (crb.py docstring).
    K, sigma = 3000, 0.01
    bound = crb_mse(np.eye(3), np.zeros(3), fibonacci_sphere(K), sigma)
    assert bound.h_part == pytest.approx(9 * sigma**2 / K, rel=0.01)
    assert bound.T_part == pytest.approx(40.5 * sigma**2 / K, rel=0.01)
    assert bound.total == pytest.approx(49.5 * sigma**2 / K, rel=0.01)


def test_rotations_are_the_null_space():
    T = np.eye(3) + 0.1 * np.random.default_rng(0).uniform(-1, 1, (3, 3))
    F = fisher_information(T, fibonacci_sphere(200))
    G = gauge_basis(T)
    assert np.abs(F @ G).max() < 1e-9 * np.abs(F).max()
    assert np.linalg.matrix_rank(F, tol=1e-9 * np.abs(F).max()) == 9


def test_bound_is_invariant_to_the_gauge_and_scales_with_sigma():
    m = fibonacci_sphere(300)
    T = np.diag([1.1, 0.9, 1.0])
    Q = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    a = crb_mse(T, np.zeros(3), m, 0.01).total
    b = crb_mse(T @ Q, np.zeros(3), m @ Q, 0.01).total   # same data, rotated gauge
    assert b == pytest.approx(a, rel=1e-9)
    assert crb_mse(T, np.zeros(3), m, 0.02).total == pytest.approx(4 * a, rel=1e-12)
    assert crb_mse(T, np.zeros(3), m, 0.0).total == 0.0


def test_unidentifiable_directions_give_an_infinite_bound():
    theta = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    circle = np.column_stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)])
    assert np.isinf(crb_mse(np.eye(3), np.zeros(3), circle, 0.01).total)


def test_magical_is_efficient_at_low_noise():
    # MAG.I.C.AL solves the ML problem (58) of this model: at low noise its mean squared
    # error over many datasets must sit on the bound.
    point = Point(K=100, sigma=1e-3)
    sq, bounds, Js, EJ = [], [], [], []
    for seed in range(200):
        d = make_dataset(np.random.default_rng(seed), point)
        cal = magbench.calibrate(d.y, "magical")
        J, J_h, J_T = accuracy_cost(cal.T, cal.h, d.T, d.h)
        sq.append(J_h**2 + J_T**2)
        Js.append(J)
        bounds.append(crb_mse(d.T, d.h, d.m, point.sigma).total)
        EJ.append(efficient_expected_J(d.T, d.m, point.sigma))
    assert np.mean(sq) == pytest.approx(np.mean(bounds), rel=0.15)
    assert np.mean(Js) == pytest.approx(np.mean(EJ), rel=0.1)


def test_a_given_covariance_gives_exactly_the_bound_computed_here():
    """A trial computes the covariance once and hands it to both summaries: the numbers are
    the same to the bit, and the covariance given is the one used."""
    from magbench.core.crb import crb_covariance

    data = make_dataset(np.random.default_rng(3), Point())
    C = crb_covariance(data.T, data.m, 0.005)
    assert crb_mse(data.T, data.h, data.m, 0.005, covariance=C) == crb_mse(
        data.T, data.h, data.m, 0.005)
    assert efficient_expected_J(data.T, data.m, 0.005, covariance=C) == efficient_expected_J(
        data.T, data.m, 0.005)
    assert crb_mse(data.T, data.h, data.m, 0.005, covariance=4 * C).total == pytest.approx(
        4 * crb_mse(data.T, data.h, data.m, 0.005).total, rel=1e-12)
    assert efficient_expected_J(data.T, data.m, 0.005, covariance=4 * C) == pytest.approx(
        2 * efficient_expected_J(data.T, data.m, 0.005), rel=1e-12)


def test_expected_J_draws_are_the_datasets_own_so_their_error_averages_out():
    """One fixed set of draws reused for every dataset biases a sweep's mean floor by that
    set's sampling error; draws seeded by the dataset average out. With the covariance set to
    the identity, E[J] = E||z_9|| + E||z_3|| is known in closed form."""
    from scipy.special import gammaln

    def chi_mean(k):
        return np.sqrt(2) * np.exp(gammaln((k + 1) / 2) - gammaln(k / 2))

    exact = chi_mean(9) + chi_mean(3)
    T = np.eye(3)
    values = [efficient_expected_J(T, np.full((5, 3), float(i)), 1.0, covariance=np.eye(12))
              for i in range(300)]
    assert len(set(values)) == 300                      # fresh draws for every dataset
    assert np.mean(values) == pytest.approx(exact, rel=1e-3)
    assert efficient_expected_J(T, np.zeros((5, 3)), 1.0, covariance=np.eye(12)) == values[0]
