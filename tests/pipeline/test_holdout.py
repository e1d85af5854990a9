"""Interleaved time-block folds: a partition, spread over the recording, scored held out."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.pipeline.holdout import (
    BLOCKS_PER_FOLD,
    N_FOLDS,
    evaluate_folds,
    fold_indices,
    fold_summary,
    held_out_corrected,
)
from magbench.sources.recordings import Recording


@pytest.mark.parametrize("K", [7, 100, 1001])
def test_folds_partition_the_samples_in_interleaved_blocks(K):
    tests = fold_indices(K)
    assert len(tests) == N_FOLDS
    assert np.array_equal(np.sort(np.concatenate(tests)), np.arange(K))
    if K >= N_FOLDS * BLOCKS_PER_FOLD:
        for t in tests:      # every fold reaches into each quarter of the recording
            assert len({int(4 * i / K) for i in t}) == 4


def test_noise_free_fits_score_zero_held_out_and_correct_every_sample():
    T = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.05], [0.0, 0.0, 1.1]])
    y = np.random.default_rng(0).permutation(fibonacci_sphere(300)) @ T.T + [0.4, -0.2, 0.1]
    rec = Recording("clean", y, n_rows=300)
    trials = evaluate_folds(rec, ["ellipsoid", "sphere"], "centre")
    assert {r["fit_on"] for r in trials} == {"all", "fold0", "fold1", "fold2"}
    summary = {r["algorithm"]: r for r in fold_summary(trials)}
    assert summary["ellipsoid"]["J_r_out"] < 1e-20
    assert summary["ellipsoid"]["J_r_worst"] >= summary["ellipsoid"]["J_r_out"]
    assert summary["sphere"]["J_r_out"] > 1e-4                     # cannot fit the soft iron
    m = held_out_corrected(trials, rec, "ellipsoid")
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-9)
