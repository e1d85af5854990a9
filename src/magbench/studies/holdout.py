"""Held-out scores of calibrate's candidates on interleaved time-block folds.

The recording (in time order) is cut into ``n_folds * blocks_per_fold`` blocks of consecutive
samples; fold ``f`` is fitted on every block but the ones numbered ``f, f + n_folds, ...`` and
scored on those. Every sample is held out exactly once, each fold's test blocks are spread over
the whole recording (a slow drift or a turn done only at the end is in every fold's fitting
set), and neighbouring samples of a slow rotation, which are nearly equal, stay together in one
block (an even/odd split of samples would test on the training data). A candidate is scored by
the mean over the folds of its held-out J_r (eq. 81) and by its worst fold: a model that wins
on average but loses badly on one part of the recording is seen.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from magbench.sources.recordings import Recording
from magbench.studies.real import evaluate_recording, recording_summary

__all__ = ["BLOCKS_PER_FOLD", "N_FOLDS", "estimate", "evaluate_folds", "fold_indices",
           "fold_summary", "held_out_corrected"]

#: Folds of the held-out score.
N_FOLDS = 3
#: Test blocks per fold (so ``N_FOLDS * BLOCKS_PER_FOLD`` blocks in all).
BLOCKS_PER_FOLD = 4


def estimate(row: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` of a row of the real-data tables."""
    T = np.array([[row[f"T_{i}{j}"] for j in range(3)] for i in range(3)], dtype=float)
    return T, np.array([row[f"h_{i}"] for i in range(3)], dtype=float)


def fold_indices(K: int, n_folds: int = N_FOLDS, blocks_per_fold: int = BLOCKS_PER_FOLD
                 ) -> list[np.ndarray]:
    """The test indices of each fold (see the module notes); together they are ``0..K-1``."""
    blocks = np.array_split(np.arange(K), max(1, min(K, n_folds * blocks_per_fold)))
    return [np.concatenate(blocks[f::n_folds]) if blocks[f::n_folds] else np.arange(0)
            for f in range(n_folds)]


def _splits(rec: Recording, tests: list[np.ndarray]) -> list[tuple]:
    out = [("all", rec, [("", None)])]
    for f, test in enumerate(tests):
        train = np.setdiff1d(np.arange(rec.K), test)
        out.append((f"fold{f}", rec.rows(train), [(f"fold{f}", rec.rows(test))]))
    return out


def evaluate_folds(rec: Recording, algorithms: Sequence[str], preprocess: str, *,
                   options: dict | None = None, seed: int = 0,
                   call_timeout_s: float | None = None) -> pd.DataFrame:
    """Rows of :func:`magbench.studies.real.evaluate_recording` with the fits of
    :func:`fold_indices` (``fit_on`` ``all`` and ``fold0``, ``fold1``, ...)."""
    if rec.K < 2 * N_FOLDS:
        tests: list[np.ndarray] = []
    else:
        tests = fold_indices(rec.K)
    return pd.DataFrame(evaluate_recording(rec, algorithms, [preprocess], options=options,
                                           seed=seed, call_timeout_s=call_timeout_s,
                                           splits=_splits(rec, tests)))


def fold_summary(trials: pd.DataFrame) -> pd.DataFrame:
    """One row per method: :func:`~magbench.studies.real.recording_summary` of the fit on all
    samples, with ``J_r_out`` the mean over the folds of the held-out J_r and ``J_r_worst``
    the largest; both NaN unless every fold's fit is usable."""
    whole = recording_summary(trials[trials["fit_on"] == "all"])
    folds = trials[trials["fit_on"] != "all"]
    means, worst = [], []
    for name in whole["algorithm"]:
        rows = folds[folds["algorithm"] == name]
        ok = len(rows) >= 2 and rows["usable"].astype(bool).all()
        means.append(float(rows["J_r_test"].mean()) if ok else np.nan)
        worst.append(float(rows["J_r_test"].max()) if ok else np.nan)
    return whole.assign(J_r_out=means, J_r_worst=worst,
                        halves_usable=np.isfinite(np.asarray(means)))


def held_out_corrected(trials: pd.DataFrame, rec: Recording, method: str) -> np.ndarray | None:
    """Every sample of ``rec`` corrected by ``method``'s fit on the folds it was held out of,
    in time order; None unless every fold's fit is usable."""
    rows = trials[(trials["algorithm"] == method) & (trials["fit_on"] != "all")]
    if len(rows) < 2 or not rows["usable"].astype(bool).all():
        return None
    out = np.empty((rec.K, 3))
    for f, test in enumerate(fold_indices(rec.K, len(rows))):
        T, h = estimate(rows[rows["fit_on"] == f"fold{f}"].iloc[0])
        out[test] = np.linalg.solve(T, (rec.y[test] - h).T).T
    return out
