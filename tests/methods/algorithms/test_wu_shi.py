"""Wu and Shi's optimal ML (review Algorithm 6): initial estimate, O(K) Newton step, failures."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.metrics import accuracy_cost, trivial_cost
from magbench.core.model import CalibrationFailed
from magbench.methods.algorithms import wu_shi
from magbench.methods.algorithms._wu_shi_init import UPPER, initial_estimate
from tests.conftest import dataset

UPPER_VEC = [3 * b + a for a, b in UPPER]      # column-major vec indices of upper entries


def hyperboloid(K: int = 200) -> np.ndarray:
    """Points of x^2 + y^2 - z^2 = 1: the fitted quadric's A = diag(1, 1, -1) is indefinite."""
    t = np.linspace(-1.0, 1.0, K)
    phi = np.linspace(0.0, 7.0 * np.pi, K)
    return np.column_stack([np.cosh(t) * np.cos(phi), np.cosh(t) * np.sin(phi), np.sinh(t)])


def dense_newton_step(y: np.ndarray, s: wu_shi.State) -> np.ndarray:
    """Eq. (54) with the full (4K+9)-square Hessian (A5) built entry by entry from (A6)-(A7)."""
    K, T, I3 = y.shape[0], s.T, np.eye(3)
    n = 12 + 4 * K
    grad, H = np.zeros(n), np.zeros((n, n))
    m_at = lambda k: slice(12 + 3 * k, 15 + 3 * k)  # noqa: E731
    for k in range(K):
        m, u = s.m[k], y[k] - s.h
        r = u - T @ m
        grad[:9] += -2.0 * np.kron(m, r)
        grad[9:12] += -2.0 * r
        grad[m_at(k)] = -2.0 * T.T @ r + 2.0 * s.lam[k] * m
        grad[12 + 3 * K + k] = m @ m - 1.0
        H[:9, :9] += 2.0 * np.kron(np.outer(m, m), I3)
        H[:9, 9:12] += 2.0 * np.kron(m[:, None], I3)
        H_Tm = 2.0 * (np.kron(m[:, None], I3) @ T - np.kron(I3, r[:, None]))
        H[:9, m_at(k)], H[m_at(k), :9] = H_Tm, H_Tm.T
        H[9:12, m_at(k)], H[m_at(k), 9:12] = 2.0 * T, 2.0 * T.T
        H[m_at(k), m_at(k)] = 2.0 * T.T @ T + 2.0 * s.lam[k] * I3
        H[m_at(k), 12 + 3 * K + k] = H[12 + 3 * K + k, m_at(k)] = 2.0 * m
    H[9:12, 9:12] = 2.0 * K * I3
    H[9:12, :9] = H[:9, 9:12].T
    keep = UPPER_VEC + list(range(9, n))         # drop the lower-triangular entries of T
    return np.linalg.solve(H[np.ix_(keep, keep)], grad[keep])


def perturbed_state(seed: int, K: int) -> tuple[np.ndarray, wu_shi.State]:
    """A noisy dataset and a generic iterate: non-zero residuals and multipliers."""
    d = dataset(seed, K=K, sigma=0.02)
    rng = np.random.default_rng(seed + 100)
    T0, h0 = initial_estimate(d.y)
    s = wu_shi.initial_state(d.y, T0, h0)
    return d.y, wu_shi.State(s.T + np.triu(rng.normal(0, 0.02, (3, 3))),
                             s.h + rng.normal(0, 0.02, 3),
                             s.m + rng.normal(0, 0.02, s.m.shape), rng.normal(0, 0.05, K))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_schur_step_equals_the_dense_gauss_newton_step(seed):
    y, s = perturbed_state(seed, K=12)
    dg, dl = wu_shi.newton_step(y, s)
    K = y.shape[0]
    fast = np.concatenate([dg, dl[:, :3].ravel(), dl[:, 3]])
    np.testing.assert_allclose(fast, dense_newton_step(y, s), rtol=0, atol=1e-10)
    assert np.max(np.abs(fast)) > 1e-3 and fast.size == 4 * K + 9   # a real, non-trivial step


def test_gradient_matches_finite_differences_of_the_lagrangian():
    y, s = perturbed_state(3, K=10)
    g_g, g_l = wu_shi.gradient(y, s)
    eps = 1e-6
    for p, (a, b) in enumerate(UPPER):
        E = np.zeros((3, 3))
        E[a, b] = eps
        fd = (wu_shi.lagrangian(y, wu_shi.State(s.T + E, s.h, s.m, s.lam))
              - wu_shi.lagrangian(y, wu_shi.State(s.T - E, s.h, s.m, s.lam))) / (2 * eps)
        assert fd == pytest.approx(g_g[p], abs=1e-7)
    dm = np.zeros_like(s.m)
    dm[4, 1] = eps
    fd = (wu_shi.lagrangian(y, wu_shi.State(s.T, s.h, s.m + dm, s.lam))
          - wu_shi.lagrangian(y, wu_shi.State(s.T, s.h, s.m - dm, s.lam))) / (2 * eps)
    assert fd == pytest.approx(g_l[4, 1], abs=1e-7)


@pytest.mark.parametrize("seed", range(6))
def test_noise_free_recovery_in_the_nominal_ranges(seed):
    d = dataset(seed, sigma=0.0)
    cal = magbench.calibrate(d.y, "wu_shi", raw=True)   # the method's own form
    assert cal.converged
    assert accuracy_cost(cal.T, cal.h, d.T, d.h)[0] < 1e-6
    assert np.all(np.tril(cal.T, -1) == 0.0)        # T_hat = R^-1 is upper triangular (50)


def test_initial_estimate_is_exact_on_noise_free_data():
    d = dataset(4, sigma=0.0)
    for null_vector in ("svd", "eigh"):
        T0, h0 = initial_estimate(d.y, null_vector=null_vector)
        # T0 m_hat = T m with m_hat = Q^T m, so T0 T0^T = T T^T.
        np.testing.assert_allclose(T0 @ T0.T, d.T @ d.T.T, atol=1e-9)
        np.testing.assert_allclose(h0, d.h, atol=1e-9)


def test_svd_and_eigh_null_vectors_agree_on_noisy_data(nominal):
    T_svd, h_svd = initial_estimate(nominal.y, null_vector="svd")
    T_eig, h_eig = initial_estimate(nominal.y, null_vector="eigh")
    np.testing.assert_allclose(T_svd, T_eig, atol=1e-8)
    np.testing.assert_allclose(h_svd, h_eig, atol=1e-8)


def test_converged_point_satisfies_the_first_order_conditions(nominal):
    T0, h0 = initial_estimate(nominal.y)
    cal, history = wu_shi.refine(nominal.y, T0, h0)
    assert cal.converged and history.shape == (cal.n_iter + 1,)
    assert history[0] < 1e-20 < history[-1]          # (4) is zero at x(0) by (57)
    # Re-run to the same point and check the gradient (A6) there: zero, with ||m_k|| = 1.
    s = wu_shi.initial_state(nominal.y, T0, h0)
    for _ in range(cal.n_iter):
        s = wu_shi.apply_step(s, *wu_shi.newton_step(nominal.y, s))
    g_g, g_l = wu_shi.gradient(nominal.y, s)
    assert np.max(np.abs(g_g)) < 1e-10 and np.max(np.abs(g_l)) < 1e-10
    assert history[-1] == pytest.approx(wu_shi.objective(nominal.y, s), rel=1e-12)


@pytest.mark.parametrize("t0_form", ["inverse", "chol"])
def test_refine_in_place_equals_the_state_by_state_iteration_bit_for_bit(nominal, t0_form):
    # refine updates x in place (_advance) and reuses each x's residuals; the public path
    # builds a new State per step (apply_step, newton_step, objective). Same arithmetic, so the
    # same bits; and refine leaves its inputs alone.
    y = nominal.y.copy()
    T0, h0 = initial_estimate(y, t0_form=t0_form)
    inputs = (y.copy(), T0.copy(), h0.copy())
    cal, history = wu_shi.refine(y, T0, h0, rtol=0.0, xtol=0.0, max_iter=6)
    for given, kept in zip((y, T0, h0), inputs, strict=True):
        np.testing.assert_array_equal(given, kept)
    s = wu_shi.initial_state(y, T0, h0)
    steps = [wu_shi.objective(y, s)]
    for _ in range(6):
        s = wu_shi.apply_step(s, *wu_shi.newton_step(y, s))
        steps.append(wu_shi.objective(y, s))
    assert history.tobytes() == np.array(steps).tobytes()
    assert cal.T.tobytes() == s.T.tobytes() and cal.h.tobytes() == s.h.tobytes()
    assert history[-1] != history[-2]                 # six real steps, not a fixed point


def test_a_perturbed_start_converges_to_the_same_estimate(nominal):
    # Wu and Shi's Figure 6: the ML estimate does not diverge within a 5 % initial error.
    T0, h0 = initial_estimate(nominal.y)
    rng = np.random.default_rng(0)
    R0 = np.linalg.inv(T0) * (1 + 0.05 * np.sign(rng.normal(size=(3, 3))))
    h0_bad = h0 * (1 + 0.05 * np.sign(rng.normal(size=3)))
    ref = wu_shi.refine(nominal.y, T0, h0)[0]
    cal = wu_shi.refine(nominal.y, np.triu(np.linalg.inv(np.triu(R0))), h0_bad)[0]
    assert cal.converged
    np.testing.assert_allclose(cal.T, ref.T, atol=1e-9)
    np.testing.assert_allclose(cal.h, ref.h, atol=1e-9)


def test_indefinite_quadric_raises_the_cholesky_failure():
    with pytest.raises(CalibrationFailed, match=r"initial estimate: A is not positive definite "
                                                r"\(Cholesky failed\)"):
        magbench.calibrate(hyperboloid(), "wu_shi")


def test_the_iteration_cap_gives_converged_false(nominal):
    cal = magbench.calibrate(nominal.y, "wu_shi", max_iter=1, rtol=0.0, xtol=0.0)
    assert not cal.converged and cal.n_iter == 1
    assert "iteration cap 1 reached" in cal.message
    assert magbench.calibrate(nominal.y, "wu_shi").converged


def test_singular_per_sample_block_raises(nominal):
    y = nominal.y
    s = wu_shi.State(np.eye(3), np.zeros(3), np.zeros_like(y), np.zeros(y.shape[0]))
    with pytest.raises(CalibrationFailed, match="per-sample Hessian block"):
        wu_shi.newton_step(y, s)


def test_refine_rejects_a_non_triangular_start(nominal):
    with pytest.raises(ValueError, match="upper-triangular"):
        wu_shi.refine(nominal.y, np.ones((3, 3)), np.zeros(3))


def test_review_literal_start_is_r_itself_and_can_diverge():
    # Review eq. (57) as printed, T_hat(0) = chol(A), starts from R = T_hat^-1 instead of T_hat.
    d = dataset(3)                  # alpha = 0.81: the start is off by a factor of about 1.5
    T_inv, h = initial_estimate(d.y)
    T_chol, h_chol = initial_estimate(d.y, t0_form="chol")
    np.testing.assert_allclose(T_chol @ T_inv, np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(h, h_chol)
    literal = magbench.calibrate(d.y, "wu_shi", t0_form="chol")
    # Where a Newton run that does not converge ends is chaotic (one-ulp changes of the data
    # move its J between about 1 and 1e6), so "diverged" is judged by the review's own test: the
    # estimate is not meaningful, J >= delta J_o (76) with delta = 0.5.
    J_literal = accuracy_cost(literal.T, literal.h, d.T, d.h)[0]
    assert not literal.converged and J_literal > 0.5 * trivial_cost(d.T, d.h)
    default = magbench.calibrate(d.y, "wu_shi")
    assert default.converged and accuracy_cost(default.T, default.h, d.T, d.h)[0] < 0.01


def test_review_literal_start_reaches_the_same_estimate_when_it_converges():
    d = dataset(0)                  # alpha = 1.08
    literal = magbench.calibrate(d.y, "wu_shi", t0_form="chol")
    default = magbench.calibrate(d.y, "wu_shi")
    assert literal.converged and literal.n_iter > default.n_iter
    np.testing.assert_allclose(literal.T, default.T, atol=1e-9)
    np.testing.assert_allclose(literal.h, default.h, atol=1e-9)
