"""The two interval helpers: Wilson's binomial interval and the bootstrap of 1/mean."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.intervals import (
    RESAMPLES,
    bootstrap_inverse_mean,
    bootstrap_mean,
    bootstrap_paired_ratio,
    intervals_overlap,
    resampled_means,
    wilson,
)
from magbench.core.seeding import rng


def test_wilson_matches_published_values():
    # Brown, Cai and DasGupta (2001) / any statistics package: 5 of 10 -> [0.2366, 0.7634],
    # 0 of 10 -> [0, 0.2775] (the normal approximation would give [0, 0]).
    assert wilson(5, 10) == pytest.approx((23.6593, 76.3407), abs=1e-3)
    assert wilson(0, 10) == pytest.approx((0.0, 27.7533), abs=1e-3)
    assert wilson(10, 10) == pytest.approx((72.2467, 100.0), abs=1e-3)


def test_wilson_one_failure_in_250_is_not_distinguishable_from_100_percent():
    low, high = wilson(249, 250)
    assert low == pytest.approx(97.769, abs=1e-3) and high == pytest.approx(99.929, abs=1e-3)
    assert intervals_overlap((low, high), wilson(250, 250))
    assert not intervals_overlap(wilson(237, 250), wilson(250, 250))   # 94.8 % vs 100 %


def test_wilson_contains_the_estimate_and_narrows_with_n():
    for k, n in [(1, 3), (30, 40), (300, 400)]:
        low, high = wilson(k, n)
        assert low <= 100 * k / n <= high
    assert np.diff(wilson(300, 400)) < np.diff(wilson(30, 40))
    assert all(np.isnan(wilson(0, 0)))
    with pytest.raises(ValueError):
        wilson(5, 4)


def test_bootstrap_is_seeded_by_its_keys_and_brackets_the_estimate():
    values = np.random.default_rng(3).exponential(0.0025, size=250)
    a = bootstrap_inverse_mean(values, "baseline", "magical")
    assert a == bootstrap_inverse_mean(values, "baseline", "magical")
    assert a != bootstrap_inverse_mean(values, "baseline", "dorveaux")
    assert a[0] < 1 / values.mean() < a[1]
    # The relative half-width of a mean of n exponentials is about 1.96 / sqrt(n).
    assert (a[1] - a[0]) / 2 * values.mean() == pytest.approx(1.96 / np.sqrt(250), rel=0.2)


def test_bootstrap_degenerate_inputs():
    assert bootstrap_inverse_mean([0.5, 0.5, 0.5], "x") == pytest.approx((2.0, 2.0))
    assert all(np.isnan(bootstrap_inverse_mean([], "x")))
    assert bootstrap_inverse_mean([np.nan, 0.25], "x") == pytest.approx((4.0, 4.0))


def test_paired_ratio_sees_a_small_difference_on_shared_datasets():
    from magbench.core.intervals import bootstrap_paired_ratio

    difficulty = np.random.default_rng(3).gamma(1.0, 1.0, 200)   # varies 100x between datasets
    lo, hi = bootstrap_paired_ratio(0.95 * difficulty, difficulty, "test")
    assert lo == pytest.approx(0.95) and hi == pytest.approx(0.95)   # exact: no pair noise
    noisy = difficulty * (1 + 0.05 * np.random.default_rng(4).standard_normal(200))
    lo, hi = bootstrap_paired_ratio(0.9 * noisy, difficulty, "test")
    assert lo < 0.9 < hi and hi < 1.0                 # a 10 % gain is seen despite the spread
    assert all(np.isnan(bootstrap_paired_ratio([1.0], [2.0])))      # one pair: no interval


def _one_call_means(x: np.ndarray, generator: np.random.Generator, resamples: int) -> np.ndarray:
    # The bootstrap as it was first written: every index of every resample drawn at once.
    return x[generator.integers(0, x.shape[0], size=(resamples, x.shape[0]))].mean(axis=1)


@pytest.mark.parametrize("n, chunk_values", [(250, 1000), (250, 1 << 21), (1001, 3000),
                                             (7, 5)])
def test_chunked_resampling_draws_the_same_means_as_one_call(n, chunk_values):
    x = np.random.default_rng(n).exponential(0.0025, size=n)
    chunked = resampled_means(x, np.random.default_rng(11), 2000, chunk_values)
    assert np.array_equal(chunked, _one_call_means(x, np.random.default_rng(11), 2000))


def test_chunked_paired_resampling_draws_the_same_means_as_one_call():
    x = np.random.default_rng(5).exponential(1.0, size=(240, 5))
    chunked = resampled_means(x, np.random.default_rng(0), 2000, chunk_values=700)
    assert chunked.shape == (2000, 5)
    assert np.array_equal(chunked, _one_call_means(x, np.random.default_rng(0), 2000))


def test_bootstrap_interval_is_unchanged_by_chunking():
    # The interval of 250 runs as the one-call bootstrap gave it, to the bit.
    values = np.random.default_rng(3).exponential(0.0025, size=250)
    means = _one_call_means(values, rng(0, "bootstrap", "baseline", "magical"), RESAMPLES)
    expected = tuple(np.percentile(1.0 / means, [2.5, 97.5]))
    assert bootstrap_inverse_mean(values, "baseline", "magical") == expected


def test_resampling_memory_does_not_grow_with_the_resamples():
    import tracemalloc

    x = np.random.default_rng(1).exponential(1.0, size=100_000)
    tracemalloc.start()
    resampled_means(x, np.random.default_rng(0), 40, chunk_values=1 << 16)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # One call would hold 40 x 100 000 indices and values (64 MB); a chunk holds one row.
    assert peak < 4e6


def test_bootstrap_mean_and_ratio_bracket_their_estimates():
    x = np.random.default_rng(2).exponential(2.0, size=400)
    low, high = bootstrap_mean(x, "m")
    assert low < x.mean() < high
    assert (high - low) / 2 == pytest.approx(1.96 * x.std() / np.sqrt(400), rel=0.15)
    # A ratio of paired means: a constant ratio has no spread however noisy the pairs.
    assert bootstrap_paired_ratio(3 * x, x, "r") == pytest.approx((3.0, 3.0))
    y = x + np.random.default_rng(4).normal(0, 0.5, size=400)
    low, high = bootstrap_paired_ratio(x, y, "r")
    assert low < x.mean() / y.mean() < high
    assert all(np.isnan(bootstrap_mean([np.nan], "m")))
    assert all(np.isnan(bootstrap_paired_ratio([1.0], [np.inf], "r")))


def test_the_median_interval_is_the_order_statistics_the_binomial_gives():
    from magbench.core.intervals import median_interval

    x = np.arange(1.0, 101.0)                       # x_(k) = k
    assert median_interval(x[::-1]) == (40.0, 61.0)  # the textbook ranks for n = 100
    assert median_interval([3.0, 1.0, np.nan, 2.0]) == (1.0, 3.0)   # too few: the range
    assert all(np.isnan(v) for v in median_interval([np.nan]))
    with pytest.raises(ValueError, match="level must be in"):
        median_interval(x, level=1.0)
    # coverage: the median of a skewed law falls inside in about 95 % of samples of 30
    gen = np.random.default_rng(7)
    hits = [lo <= np.log(2) <= hi for lo, hi in
            (median_interval(gen.exponential(size=30)) for _ in range(2000))]
    assert 0.93 <= np.mean(hits) <= 0.99


def test_resampled_means_asked_again_are_the_same_draws_and_leave_the_stream_alike(
        monkeypatch):
    """A repeat (same values, same generator state) is served from the memo: the same
    means, and the generator left where drawing them again leaves it; other values or
    another state are drawn anew."""
    import magbench.core.intervals as iv

    monkeypatch.setattr(iv, "_MEMO", type(iv._MEMO)())
    monkeypatch.setattr(iv, "_MEMO_SIZE", [0])
    x = np.random.default_rng(1).standard_normal((40, 2))
    first_gen, again_gen = np.random.default_rng(7), np.random.default_rng(7)
    first = iv.resampled_means(x, first_gen, 300)
    assert len(iv._MEMO) == 1
    again = iv.resampled_means(x.copy(), again_gen, 300)
    assert np.array_equal(first, again) and again is not first and len(iv._MEMO) == 1
    assert first_gen.random() == again_gen.random()         # the stream continues alike
    next(iter(iv._MEMO.values()))[0][0] = 99.0              # served from the memo, a copy
    served = iv.resampled_means(x, np.random.default_rng(7), 300)
    assert served[0, 0] == 99.0 and next(iter(iv._MEMO.values()))[0][0, 0] == 99.0
    served[0, 0] = -1.0
    assert next(iter(iv._MEMO.values()))[0][0, 0] == 99.0
    other = iv.resampled_means(x + 1.0, np.random.default_rng(7), 300)
    assert np.allclose(other, first + 1.0) and len(iv._MEMO) == 2
    plain = np.random.default_rng(8).integers(0, 40, size=(300, 40))
    assert np.array_equal(iv.resampled_means(x, np.random.default_rng(8), 300),
                          x[plain].mean(axis=1))


def test_the_memo_keeps_at_most_its_bytes(monkeypatch):
    import magbench.core.intervals as iv

    monkeypatch.setattr(iv, "_MEMO", type(iv._MEMO)())
    monkeypatch.setattr(iv, "_MEMO_SIZE", [0])
    monkeypatch.setattr(iv, "MEMO_BYTES", 3 * 100 * 8)
    for seed in range(5):
        iv.resampled_means(np.arange(10.0), np.random.default_rng(seed), 100)
    assert len(iv._MEMO) == 3 and iv._MEMO_SIZE[0] == 3 * 100 * 8

