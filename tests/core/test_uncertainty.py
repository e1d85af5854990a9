"""Model-based 95 % intervals: known derivatives, the noise estimate, and coverage by simulation.

The coverage test is the issue's: on synthetic recordings the 95 % intervals on h and on the
entries of A contain the truth 90-99 % of the time (200 recordings of the full model, 100 of
each restricted one; entries a restricted model fixes at zero are left out).
"""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.crb import crb_covariance, model_basis, parameter_covariance
from magbench.core.gauge import safe_gauge
from magbench.core.uncertainty import a_jacobian, fisher_intervals, noise_sigma
from magbench.sources.synthetic import Point, make_dataset


def test_a_jacobian_of_a_diagonal_T_is_minus_one_over_s_squared():
    s = np.array([1.3, 0.8, 1.1])
    J = a_jacobian(np.diag(s))
    for i in range(3):
        assert J[4 * i, 4 * i] == pytest.approx(-1.0 / s[i] ** 2, rel=1e-6)


def test_full_model_covariance_is_the_cramer_rao_bound():
    rng = np.random.default_rng(0)
    d = make_dataset(rng, Point())
    np.testing.assert_allclose(parameter_covariance(d.T, d.m, 0.01, "full"),
                               crb_covariance(d.T, d.m, 0.01))
    assert [model_basis(d.T, m).shape[1] for m in ("full", "diagonal", "sphere", "bias")] == \
        [9, 6, 4, 3]


def test_noise_sigma_recovers_the_simulated_noise():
    d = make_dataset(np.random.default_rng(1), Point(K=2000, sigma=0.01))
    assert noise_sigma(d.y, d.T, d.h, 9) == pytest.approx(0.01, rel=0.05)


def _coverage(method: str, model: str, n: int) -> tuple[float, np.ndarray]:
    hits = []
    for i in range(n):
        rng = np.random.default_rng([15, i])
        if model == "full":
            d = make_dataset(rng, Point(K=300, sigma=0.01))
            T, h, y = d.T, d.h, d.y
        else:
            m = make_dataset(rng, Point(K=300)).m
            s = rng.uniform(0.8, 1.2, 3) if model == "diagonal" else np.full(3, 1.1)
            T, h = np.diag(s), rng.uniform(-0.1, 0.1, 3)
            y = m @ T.T + h + rng.normal(0.0, 0.01, m.shape)
        cal = magbench.calibrate(y, method)
        iv = fisher_intervals(y, cal.T, cal.h, model)
        A = safe_gauge(T, h).A
        inside = np.concatenate([np.abs(iv.h - h) <= iv.h_half,
                                 (np.abs(iv.A - A) <= iv.A_half).ravel()])
        free = np.concatenate([np.ones(3, bool), (iv.A_half > 0).ravel()])
        hits.append(np.where(free, inside, np.nan))
    hits = np.array(hits)
    hits = hits[:, ~np.isnan(hits).all(axis=0)]          # drop entries the model fixes
    return float(np.nanmean(hits)), np.nanmean(hits, axis=0)


@pytest.mark.parametrize(("method", "model", "n"), [("fang", "full", 200),
                                                    ("diagonal", "diagonal", 100),
                                                    ("sphere", "sphere", 100)])
def test_95_percent_intervals_contain_the_truth_90_to_99_percent_of_the_time(method, model, n):
    pooled, per_entry = _coverage(method, model, n)
    assert 0.90 <= pooled <= 0.99, pooled
    assert np.nanmin(per_entry) >= 0.85, per_entry


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9])
def test_correlation_length_of_ar1_noise(phi):
    from magbench.core.uncertainty import correlation_length

    rng = np.random.default_rng(0)
    w = rng.standard_normal(20_000)
    e = np.empty_like(w)
    e[0] = w[0]
    for k in range(1, w.size):
        e[k] = phi * e[k - 1] + w[k]
    assert correlation_length(e) == pytest.approx((1 + phi) / (1 - phi), rel=0.15, abs=0.1)


def test_block_length_is_capped_and_a_drift_gives_long_blocks():
    from magbench.core.uncertainty import MIN_BLOCKS, block_length

    rng = np.random.default_rng(1)
    white = rng.standard_normal(1000)
    assert block_length(white) <= 6
    drift = white + 3 * np.sin(np.linspace(0, 2 * np.pi, 1000))
    assert block_length(drift) == 1000 // MIN_BLOCKS


def test_block_resample_draws_whole_circular_blocks():
    from magbench.core.uncertainty import block_resample

    idx = block_resample(103, 10, np.random.default_rng(2))
    assert idx.size == 103
    steps = np.diff(idx)[: 100].reshape(10, 10)[:, :9]           # inside each block
    assert np.all((steps == 1) | (steps == -102))


@pytest.mark.parametrize("dof", [2, 3, 7, 11, 30, 200])
def test_student_t95_against_scipy(dof):
    from scipy.stats import t

    from magbench.core.uncertainty import student_t95

    tol = 0.01 if dof == 2 else 0.002
    assert student_t95(dof) == pytest.approx(t.ppf(0.975, dof), rel=tol)
