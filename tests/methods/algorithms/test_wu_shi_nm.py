"""Wu and Shi's approximate ML (NM, their eqs. 8 and 11-15)."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.metrics import accuracy_cost
from magbench.core.model import CalibrationFailed
from magbench.methods.algorithms import wu_shi, wu_shi_nm
from magbench.methods.algorithms._wu_shi_init import UPPER, initial_estimate, upper_inverse
from tests.conftest import dataset
from tests.methods.algorithms.test_wu_shi import hyperboloid

UPPER_VEC = [3 * b + a for a, b in UPPER]


def paper_gradient_hessian(y, R, h):
    """Eqs. (12)-(15) term by term with Kronecker products, lower-triangular rows removed."""
    I3 = np.eye(3)
    grad, H = np.zeros(12), np.zeros((12, 12))
    for u in y - h:
        Ru = R @ u
        e = Ru @ Ru - 1.0
        uu = np.outer(u, u)
        grad[:9] += 4 * e * np.kron(u, Ru)
        grad[9:] += -4 * e * R.T @ R @ u
        H[:9, :9] += 4 * (2 * np.kron(uu, np.outer(Ru, Ru)) + e * np.kron(uu, I3))
        H_Rh = 4 * (-2 * np.outer(np.kron(u, Ru), u @ R.T @ R)
                    - e * (np.kron(I3, Ru[:, None]) + np.kron(u[:, None], R)))
        H[:9, 9:] += H_Rh
        H[9:, :9] += H_Rh.T
        H[9:, 9:] += 4 * (e * R.T @ R + 2 * np.outer(R.T @ R @ u, R.T @ R @ u))
    keep = UPPER_VEC + [9, 10, 11]
    return grad[keep], H[np.ix_(keep, keep)]


def test_gradient_and_hessian_match_the_paper_and_finite_differences():
    d = dataset(5, K=20, sigma=0.02)
    rng = np.random.default_rng(1)
    T0, h0 = initial_estimate(d.y)
    R = upper_inverse(T0) + np.triu(rng.normal(0, 0.03, (3, 3)))
    h = h0 + rng.normal(0, 0.03, 3)
    grad, hess = wu_shi_nm.gradient_hessian(d.y, R, h)
    g_ref, H_ref = paper_gradient_hessian(d.y, R, h)
    np.testing.assert_allclose(grad, g_ref, atol=1e-12)
    np.testing.assert_allclose(hess, H_ref, atol=1e-12)
    eps = 1e-6
    for p, (a, b) in enumerate(UPPER):
        E = np.zeros((3, 3))
        E[a, b] = eps
        fd = (wu_shi_nm.objective(d.y, R + E, h) - wu_shi_nm.objective(d.y, R - E, h)) / (2 * eps)
        assert fd == pytest.approx(grad[p], abs=1e-7)
        fd_grad = (wu_shi_nm.gradient_hessian(d.y, R + E, h)[0]
                   - wu_shi_nm.gradient_hessian(d.y, R - E, h)[0]) / (2 * eps)
        np.testing.assert_allclose(fd_grad, hess[p], atol=1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_noise_free_recovery_in_the_nominal_ranges(seed):
    d = dataset(seed, sigma=0.0)
    cal = magbench.calibrate(d.y, "wu_shi_nm", raw=True)   # the method's own form
    assert cal.converged
    assert accuracy_cost(cal.T, cal.h, d.T, d.h)[0] < 1e-6
    assert np.all(np.tril(cal.T, -1) == 0.0)


def test_converged_point_is_a_minimum_of_the_quartic(nominal):
    T0, h0 = initial_estimate(nominal.y)
    cal, history = wu_shi_nm.refine(nominal.y, T0, h0)
    assert cal.converged and history.shape == (cal.n_iter + 1,)
    R = upper_inverse(cal.T)
    grad, hess = wu_shi_nm.gradient_hessian(nominal.y, R, cal.h)
    assert np.max(np.abs(grad)) < 1e-10
    assert np.all(np.linalg.eigvalsh(hess) > 0)
    assert history[-1] <= history[0]
    assert history[-1] == pytest.approx(wu_shi_nm.objective(nominal.y, R, cal.h), rel=1e-12)


def test_nm_and_ml_are_close_but_distinct_on_noisy_data(nominal):
    ml = magbench.calibrate(nominal.y, "wu_shi")
    nm = magbench.calibrate(nominal.y, "wu_shi_nm")
    gap = accuracy_cost(nm.T, nm.h, ml.T, ml.h)[0]
    assert 1e-8 < gap < 5e-3        # different objectives (4) and (8), same data


def test_indefinite_quadric_raises_the_cholesky_failure():
    with pytest.raises(CalibrationFailed, match=r"A is not positive definite \(Cholesky"):
        magbench.calibrate(hyperboloid(), "wu_shi_nm")


def test_the_iteration_cap_gives_converged_false(nominal):
    cal = magbench.calibrate(nominal.y, "wu_shi_nm", max_iter=1, rtol=0.0, xtol=0.0)
    assert not cal.converged and cal.n_iter == 1
    assert "iteration cap 1 reached" in cal.message


def test_shared_initial_estimate(nominal):
    assert wu_shi_nm.initial_estimate is wu_shi.initial_estimate
