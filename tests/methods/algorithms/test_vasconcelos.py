"""Vasconcelos et al. (Algorithm 4): the initial estimate (36)-(44), (A1)-(A3) and Newton (35)."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.metrics import accuracy_cost
from magbench.core.model import CalibrationFailed
from magbench.methods.algorithms import vasconcelos as V
from tests.conftest import dataset

SEEDS = range(6)


def initial(y: np.ndarray, printed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    return V.initial_estimate(V.pseudo_linear_fit(y), printed=printed)


def fd_gradient(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Central differences of a scalar or vector function, one column per coordinate."""
    cols = [(f(x + eps * e) - f(x - eps * e)) / (2 * eps) for e in np.eye(x.size)]
    return np.array(cols).T


def test_pack_uses_column_major_vec():
    T_hat, h = np.arange(9.0).reshape(3, 3), np.array([10.0, 11.0, 12.0])
    x = V.pack(T_hat, h)
    np.testing.assert_array_equal(x[:3], T_hat[:, 0])      # first column first (34)
    np.testing.assert_array_equal(x[9:], h)
    T_back, h_back = V.unpack(x)
    np.testing.assert_array_equal(T_back, T_hat)
    np.testing.assert_array_equal(h_back, h)


@pytest.mark.parametrize("seed", SEEDS)
def test_initial_estimate_is_exact_on_noise_free_data(seed):
    d = dataset(seed, sigma=0.0)
    T_hat, h = initial(d.y)
    assert np.all(np.triu(T_hat, 1) == 0.0)                 # (40) is lower triangular
    J = accuracy_cost(np.linalg.inv(T_hat), h, d.T, d.h)[0]
    assert J < 1e-12
    T_true_inv = np.linalg.inv(d.T)
    np.testing.assert_allclose(T_hat.T @ T_hat, T_true_inv.T @ T_true_inv, atol=1e-12)
    np.testing.assert_allclose(h, d.h, atol=1e-13)


@pytest.mark.parametrize("seed", SEEDS)
def test_initial_estimate_as_printed_in_the_review_is_not_exact(seed):
    # Evidence for the four corrections: on the same exact data the printed (40)-(43) miss.
    d = dataset(seed, sigma=0.0)
    T_hat, h = initial(d.y, printed=True)
    T_fixed, h_fixed = initial(d.y)
    assert accuracy_cost(np.linalg.inv(T_hat), h, d.T, d.h)[0] > 1e-3
    # Of h, only the second component (beta_2) differs.
    np.testing.assert_allclose(h[[0, 2]], h_fixed[[0, 2]], rtol=1e-12)
    assert abs(h[1] - d.h[1]) > 1e-4
    # a, b, c and lambda are right as printed: the diagonal and T^_33 agree.
    np.testing.assert_allclose(np.abs(np.diag(T_hat))[[0, 2]],
                               np.abs(np.diag(T_fixed))[[0, 2]], rtol=0.05)


@pytest.mark.parametrize("seed", [3, 8])
def test_gradient_and_hessian_match_finite_differences(seed):
    d = dataset(seed)
    sigma = 0.005
    x = V.pack(*initial(d.y)) + 0.02 * np.random.default_rng(seed).normal(size=12)
    J, g, H = V.gradient_hessian(x, d.y, sigma)
    assert J == pytest.approx(V.cost(x, d.y, sigma), rel=1e-14)
    g_fd = fd_gradient(lambda z: V.cost(z, d.y, sigma), x)
    H_fd = fd_gradient(lambda z: V.gradient_hessian(z, d.y, sigma)[1], x)
    np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-6 * np.abs(g).max())
    np.testing.assert_allclose(H, H_fd, rtol=1e-6, atol=1e-6 * np.abs(H).max())
    np.testing.assert_allclose(H, H.T, rtol=1e-12, atol=1e-12 * np.abs(H).max())


def test_gradient_is_orthogonal_to_rotations_of_T_hat():
    # J(R T^, h) = J(T^, h) for orthogonal R, so the gradient has no component along S T^
    # for skew S: why the Hessian is singular at the minimum (rank 9 of 12).
    d = dataset(4)
    x = V.pack(*initial(d.y)) + 0.05 * np.random.default_rng(0).normal(size=12)
    _, g, _ = V.gradient_hessian(x, d.y, 0.005)
    T_hat, _ = V.unpack(x)
    for S in (np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 0.0]]),
              np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0.0]]),
              np.array([[0, 0, 0], [0, 0, 1], [0, -1, 0.0]])):
        tangent = V.pack(S @ T_hat, np.zeros(3))
        assert abs(g @ tangent) < 1e-9 * np.linalg.norm(g) * np.linalg.norm(tangent)


def test_hessian_is_singular_at_the_noise_free_minimum():
    d = dataset(5, sigma=0.0)
    _, _, H = V.gradient_hessian(V.pack(*initial(d.y)), d.y, 1.0)
    eig = np.linalg.eigvalsh(H)
    assert np.all(np.abs(eig[:3]) < 1e-9 * eig[-1]) and eig[3] > 1e-3 * eig[-1]


@pytest.mark.parametrize("safeguard", ["none", "lm"])
@pytest.mark.parametrize("seed", SEEDS)
def test_noise_free_recovery(seed, safeguard):
    d = dataset(seed, sigma=0.0)
    cal = magbench.calibrate(d.y, "vasconcelos", safeguard=safeguard)
    assert cal.converged
    assert accuracy_cost(cal.T, cal.h, d.T, d.h)[0] < 1e-6


@pytest.mark.parametrize("seed", [2, 11])
def test_newton_reaches_a_stationary_point_on_noisy_data(seed):
    d = dataset(seed)
    cal = magbench.calibrate(d.y, "vasconcelos")
    assert cal.converged and 1 <= cal.n_iter <= 10
    assert accuracy_cost(cal.T, cal.h, d.T, d.h)[0] < 0.01
    x = V.pack(np.linalg.inv(cal.T), cal.h)
    _, g, _ = V.gradient_hessian(x, d.y, 0.005)
    _, g0, _ = V.gradient_hessian(V.pack(*initial(d.y)), d.y, 0.005)
    assert np.linalg.norm(g) < 1e-6 * np.linalg.norm(g0)
    # The damped variant ends at the same minimum (up to the rotation of T^).
    damped = magbench.calibrate(d.y, "vasconcelos", safeguard="lm")
    np.testing.assert_allclose(damped.T @ damped.T.T, cal.T @ cal.T.T, atol=1e-8)
    np.testing.assert_allclose(damped.h, cal.h, atol=1e-8)


def test_sigma_only_scales_the_cost():
    d = dataset(6)
    a = magbench.calibrate(d.y, "vasconcelos", sigma=0.005)
    b = magbench.calibrate(d.y, "vasconcelos", sigma=0.5)
    np.testing.assert_allclose(a.T, b.T, atol=1e-10)
    np.testing.assert_allclose(a.h, b.h, atol=1e-10)


def test_iteration_cap_reports_not_converged():
    d = dataset(2)
    cal = magbench.calibrate(d.y, "vasconcelos", max_iter=1, rtol=0.0)
    assert not cal.converged and cal.n_iter == 1
    assert "iteration cap 1" in cal.message


def test_data_on_a_hyperboloid_raise_calibration_failed():
    # x^2 + y^2 - z^2 = 1: the quadric fit (39) is exact but no ellipsoid, so the square roots
    # of (42) are of negative numbers.
    t = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
    s = np.linspace(-1.0, 1.0, 7)
    tt, ss = np.meshgrid(t, s)
    y = np.column_stack([np.cosh(ss.ravel()) * np.cos(tt.ravel()),
                         np.cosh(ss.ravel()) * np.sin(tt.ravel()), np.sinh(ss.ravel())])
    with pytest.raises(CalibrationFailed, match="not an ellipsoid"):
        magbench.calibrate(y, "vasconcelos")


def test_bad_option_values_are_value_errors(nominal):
    with pytest.raises(ValueError, match="safeguard"):
        magbench.calibrate(nominal.y, "vasconcelos", safeguard="trust-region")
    with pytest.raises(ValueError, match="initial"):
        magbench.calibrate(nominal.y, "vasconcelos", initial="guess")
    with pytest.raises(ValueError, match="sigma"):
        magbench.calibrate(nominal.y, "vasconcelos", sigma=0.0)
