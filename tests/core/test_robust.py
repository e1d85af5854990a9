"""Outlier trimming and the refusal of collapsed, singular or non-finite fits."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.core.robust import (
    CUTOFF,
    FLOOR,
    MAD_SCALE,
    outliers,
    refusal_reason,
    resultant_length,
    robust_sphere_fit,
)


def test_outliers_known_answer():
    r = np.array([0.0, 0.01, -0.01, 0.02, -0.02, 0.5])
    med = np.median(r)
    limit = CUTOFF * MAD_SCALE * np.median(np.abs(r - med))
    expected = np.abs(r - med) > limit
    np.testing.assert_array_equal(outliers(r), expected)
    assert outliers(r).tolist() == [False] * 5 + [True]


def test_quiet_data_are_never_trimmed_below_the_floor():
    r = np.array([0.0, 1e-12, -1e-12, 5e-4, -5e-4])      # MAD ~ 0: the floor decides
    assert not outliers(r).any()
    assert outliers(np.append(r, 2 * FLOOR)).tolist()[-1]


def spiky(seed: int, K: int = 1000, share: float = 0.05):
    rng = np.random.default_rng(seed)
    T = np.array([[1.1, 0.05, 0.0], [0.0, 0.9, 0.04], [0.0, 0.0, 1.2]])
    h = np.array([2.0, -1.0, 0.5])                       # offset beyond the field radius
    y = rng.permutation(fibonacci_sphere(K)) @ T.T + h + 0.005 * rng.standard_normal((K, 3))
    bad = rng.choice(K, int(share * K), replace=False)
    y[bad] *= 10.0                                       # 10x spikes, as in the issue
    return y, bad


@pytest.mark.parametrize("seed", range(3))
def test_robust_sphere_fit_sets_aside_10x_spikes_and_nothing_else(seed):
    y, bad = spiky(seed)
    centre, radius, inliers = robust_sphere_fit(y)
    assert radius > 0
    assert set(np.flatnonzero(~inliers)) == set(bad)
    np.testing.assert_allclose(centre, [2.0, -1.0, 0.5], atol=0.05)


def collapsed(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J_r's degenerate minimiser: h far beyond the data, a large T = D I."""
    c = y.mean(axis=0)
    far = c + 1e3 * np.array([1.0, 0.0, 0.0])
    return np.linalg.norm(y - far, axis=1).mean() * np.eye(3), far


def test_a_collapsed_fit_is_refused_and_a_good_one_is_not():
    y = fibonacci_sphere(300) * 2.0 + 1.0
    assert refusal_reason(2.0 * np.eye(3), np.ones(3), y, np.ones(3)) == ""
    T, h = collapsed(y)
    assert resultant_length(np.linalg.solve(T, (y - h).T).T) > 0.99
    assert "collapse toward one direction" in refusal_reason(T, h, y, np.ones(3))


@pytest.mark.parametrize(("T", "h", "message"), [
    (np.diag([1.0, 1.0, 1e-3]), np.zeros(3), "nearly singular"),
    (np.full((3, 3), np.nan), np.zeros(3), "not finite"),
    (np.eye(3), np.array([np.inf, 0, 0]), "not finite"),
])
def test_singular_or_non_finite_fits_are_refused(T, h, message):
    assert message in refusal_reason(T, h, fibonacci_sphere(50), np.zeros(3))


@pytest.mark.parametrize("share", [0.3, 0.5, 0.7])
def test_screen_keeps_the_rotation_when_the_recording_is_mostly_still(share):
    from magbench.core.robust import screen

    y, bad = spiky(0, K=1000, share=0.02)
    n = int(share / (1 - share) * len(y))
    still = y[0] * 0 + [2.5, -1.0, 0.5] + 0.005 * np.random.default_rng(1).standard_normal(
        (n, 3))
    s = screen(np.vstack([still, y]))
    np.testing.assert_allclose(s.centre, [2.0, -1.0, 0.5], atol=0.05)
    assert s.thinned >= n - 80                                # the still stretch is one cell
    assert set(np.flatnonzero(~s.inliers[n:])) == set(bad)    # only the spikes are outliers


def test_a_screen_that_would_empty_most_directions_is_not_applied():
    from magbench.core.geometry import fibonacci_sphere as fib
    from magbench.core.robust import Screen, keeps_directions, trimmed

    y = fib(400)
    every = np.ones(400, dtype=bool)
    assert keeps_directions(y, every, every)
    assert not keeps_directions(y, every, y[:, 2] > 0.5)
    # statistics from a cluster of directions: everything else would be an outlier
    cluster = y[:, 2] > 0.9
    residual = np.where(cluster, 0.0, 1.0)
    out = trimmed(Screen(np.zeros(3), 1.0, every, cluster), residual, y)
    assert not out.applied and np.array_equal(out.inliers, cluster)     # left as it was
