"""TWOSTEP (review Algorithm 1): known answers, the noise-mean correction, the weak points."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost
from magbench.core.model import CalibrationFailed
from magbench.methods.algorithms import twostep
from magbench.methods.algorithms._twostep_model import (
    D_from_E,
    effective_measurements,
    noise_variance,
    pack_symmetric,
    quadratic_features,
    unpack_symmetric,
)
from tests.conftest import dataset

D_KNOWN = np.array([[0.10, 0.02, -0.03],
                    [0.02, -0.05, 0.01],
                    [-0.03, 0.01, 0.08]])
H_KNOWN = np.array([0.04, -0.02, 0.03])


def known_data() -> np.ndarray:
    """Noise-free ``y = (I + D)^-1 m + h``: symmetric T, so no rotation is left to align."""
    return fibonacci_sphere(300) @ np.linalg.inv(np.eye(3) + D_KNOWN).T + H_KNOWN


def test_quadratic_features_give_the_quadratic_form():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(5, 3))
    M = unpack_symmetric(rng.normal(size=6))
    np.testing.assert_allclose(quadratic_features(y) @ pack_symmetric(M),
                               np.einsum("ki,ij,kj->k", y, M, y), atol=1e-12)


def test_D_from_E_inverts_E_equals_2D_plus_D_squared():
    E = 2 * D_KNOWN + D_KNOWN @ D_KNOWN
    np.testing.assert_allclose(D_from_E(E), D_KNOWN, atol=1e-14)


def test_known_symmetric_distortion_is_recovered_exactly():
    # sigma -> 0 turns off the noise-mean correction (5a), so the answer is exact.
    cal = magbench.calibrate(known_data(), "twostep", sigma=1e-9)
    np.testing.assert_allclose(cal.T, np.linalg.inv(np.eye(3) + D_KNOWN), atol=1e-12)
    np.testing.assert_allclose(cal.h, H_KNOWN, atol=1e-12)
    assert cal.converged


def test_review_bias_convention_returns_the_alonso_shuster_b():
    # (15) as printed, h = b = (I + D) h: the bias of y = (I + D)^-1 (m + b), not of model (2).
    cal = magbench.calibrate(known_data(), "twostep", sigma=1e-9, bias="review")
    np.testing.assert_allclose(cal.h, (np.eye(3) + D_KNOWN) @ H_KNOWN, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_noise_free_recovery_is_exact_after_procrustes(seed):
    d = dataset(seed, sigma=0.0)
    cal = magbench.calibrate(d.y, "twostep", sigma=1e-9)
    assert accuracy_cost(cal.T, cal.h, d.T, d.h)[0] < 1e-10


@pytest.mark.parametrize("sigma", [0.005, 0.05])
def test_noise_mean_correction_fits_the_sphere_of_squared_radius_one_minus_3_sigma2(sigma):
    # z_k - mu = ||y_k||^2 - (1 - 3 sigma^2): on noise-free data the fit is exact for a field of
    # that norm, so T comes out divided by sqrt(1 - 3 sigma^2) and h is unchanged. This is why
    # the default (sigma = 0.005) meets J ~ 1e-4 rather than 1e-6 on noise-free data.
    cal = magbench.calibrate(known_data(), "twostep", sigma=sigma)
    T_exact = np.linalg.inv(np.eye(3) + D_KNOWN)
    np.testing.assert_allclose(cal.T, T_exact / np.sqrt(1 - 3 * sigma**2), atol=1e-12)
    np.testing.assert_allclose(cal.h, H_KNOWN, atol=1e-12)


def test_constant_magnitude_leaves_one_direction_of_the_centred_fisher_matrix_empty():
    # On the ellipsoid (y - h)^T A (y - h) = 1, L_k theta_0 is the same for all k with
    # theta_0 = [A h, A]: centring (7) removes it, so (8b) is singular on noise-free data.
    d = dataset(3, sigma=0.0)
    Ti = np.linalg.inv(d.T)
    A = Ti.T @ Ti
    theta_0 = np.concatenate([A @ d.h, pack_symmetric(A)])
    values = twostep.design_rows(d.y) @ theta_0
    assert np.ptp(values) < 1e-12 * np.abs(values).max()


def test_centred_estimate_alone_collapses_to_E_minus_identity_on_noisy_data(nominal):
    # The noise of z_k is almost collinear with L_k theta_0, so (8a) slides to E ~ -I.
    y = nominal.y
    L = twostep.design_rows(y)
    z = effective_measurements(y)
    theta, _ = twostep.centred_estimate(L - L.mean(axis=0), z - z.mean(),
                                        1 / noise_variance(0.005))
    s = np.linalg.eigvalsh(unpack_symmetric(theta[3:]))
    np.testing.assert_allclose(s, -1.0, atol=0.02)


def test_gauss_newton_repairs_the_centred_estimate(nominal):
    cal = magbench.calibrate(nominal.y, "twostep")
    assert cal.converged and 1 <= cal.n_iter <= 10
    assert accuracy_cost(cal.T, cal.h, nominal.T, nominal.h)[0] < 0.01


def test_iteration_cap_gives_converged_false(nominal):
    cal = magbench.calibrate(nominal.y, "twostep", max_iter=1)
    assert not cal.converged and cal.n_iter == 1
    assert "iteration cap 1 reached" in cal.message


def test_refine_false_returns_the_centred_estimate_with_no_iterations():
    cal = magbench.calibrate(known_data(), "twostep", refine=False, sigma=1e-9)
    assert cal.n_iter == 0 and "centred estimate" in cal.message


def test_hyperboloid_data_make_I_plus_E_indefinite():
    # x^2 + y^2 - z^2 = 1 is z_k = L_k theta' with c = 0, E = diag(0, 0, -2): s_3 = -2 <= -1.
    t = np.linspace(-0.6, 0.6, 7)
    phi = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    tt, pp = np.meshgrid(t, phi)
    y = np.column_stack([(np.cosh(tt) * np.cos(pp)).ravel(),
                         (np.cosh(tt) * np.sin(pp)).ravel(), np.sinh(tt).ravel()])
    with pytest.raises(CalibrationFailed, match="I \\+ E is not positive definite"):
        magbench.calibrate(y, "twostep")


def test_two_parallel_circles_leave_the_centred_fisher_matrix_singular():
    # The points lie on the unit sphere and on z^2 = 1/4: two quadrics, two empty directions.
    phi = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    ring = np.column_stack([np.cos(phi), np.sin(phi)]) * np.sqrt(0.75)
    y = np.vstack([np.column_stack([ring, np.full(8, 0.5)]),
                   np.column_stack([ring, np.full(8, -0.5)])])
    with pytest.raises(CalibrationFailed, match=r"centred Fisher matrix \(8b\) is singular"):
        magbench.calibrate(y, "twostep")


@pytest.mark.parametrize(("option", "value"), [("sigma", 0.0), ("bias", "other")])
def test_bad_options_are_value_errors(nominal, option, value):
    with pytest.raises(ValueError, match=option):
        magbench.calibrate(nominal.y, "twostep", **{option: value})
