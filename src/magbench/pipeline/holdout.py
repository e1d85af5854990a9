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

from collections.abc import Mapping, Sequence

import numpy as np

from magbench.pipeline.fitting import evaluate_recording, summary_records
from magbench.sources.recordings import Recording

__all__ = ["BLOCKS_PER_FOLD", "N_FOLDS", "SPHERE_DIRECTIONS", "estimate", "evaluate_folds",
           "fold_indices", "fold_summary", "held_out_corrected", "sphere_spread"]

#: Folds of the held-out score.
N_FOLDS = 3
#: Test blocks per fold (so ``N_FOLDS * BLOCKS_PER_FOLD`` blocks in all).
BLOCKS_PER_FOLD = 4
#: Directions over the whole sphere on which the fold fits are compared.
SPHERE_DIRECTIONS = 400


def estimate(row: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` of a row of the real-data tables (a record or a pandas row)."""
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
                   call_timeout_s: float | None = None) -> list[dict]:
    """Rows of :func:`magbench.pipeline.fitting.evaluate_recording` with the fits of
    :func:`fold_indices` (``fit_on`` ``all`` and ``fold0``, ``fold1``, ...)."""
    if rec.K < 2 * N_FOLDS:
        tests: list[np.ndarray] = []
    else:
        tests = fold_indices(rec.K)
    return evaluate_recording(rec, algorithms, [preprocess], options=options, seed=seed,
                              call_timeout_s=call_timeout_s, splits=_splits(rec, tests))


def _fold_rows(trials: Sequence[Mapping], method: str) -> list[Mapping]:
    """``method``'s rows of the fold fits (not the fit on all samples), in order."""
    return [r for r in trials if r["algorithm"] == method and r["fit_on"] != "all"]


def _usable(rows: Sequence[Mapping]) -> bool:
    """At least two folds, every fold's fit usable."""
    return len(rows) >= 2 and all(bool(r["usable"]) for r in rows)


def fold_summary(trials: Sequence[Mapping]) -> list[dict]:
    """One record per method: :func:`~magbench.pipeline.fitting.summary_records` of the fit on
    all samples, with ``J_r_out`` the mean over the folds of the held-out J_r and
    ``J_r_worst`` the largest (NaN folds skipped); both NaN unless every fold's fit is
    usable."""
    whole = summary_records([r for r in trials if r["fit_on"] == "all"])
    out = []
    for row in whole:
        rows = _fold_rows(trials, row["algorithm"])
        scores = np.array([r["J_r_test"] for r in rows], dtype=float)
        scores = scores[~np.isnan(scores)]
        ok = _usable(rows) and scores.size > 0
        mean = float(scores.mean()) if ok else np.nan
        out.append({**row, "J_r_out": mean, "J_r_worst": float(scores.max()) if ok else np.nan,
                    "halves_usable": bool(np.isfinite(mean))})
    return out


def sphere_spread(trials: Sequence[Mapping], method: str,
                  directions: int = SPHERE_DIRECTIONS) -> float:
    """The fold fits' disagreement on the whole sphere: the delete-a-group jackknife variance
    of the corrected field magnitude, averaged over ``directions`` field directions.

    Each direction ``u`` of a Fibonacci grid is mapped to the sample the fit on all samples
    says it would give, ``y = T u + h``, and corrected by every fold fit; the variance of
    ``|T_f^-1 (y - h_f)|`` over the ``g`` folds, times ``(g - 1)``, estimates the variance of
    the fit's correction in that direction. Where the data are, it is small when the fit is
    well determined; where they never were (a band, a cap), a model with more freedom than the
    data determine shows it here, however well it does on the held-out time blocks. NaN
    unless every fold's fit is usable.
    """
    from magbench.core.geometry import fibonacci_sphere

    rows = _fold_rows(trials, method)
    whole = [r for r in trials if r["algorithm"] == method and r["fit_on"] == "all"]
    if not _usable(rows) or not whole or not np.isfinite(whole[0]["T_00"]):
        return np.nan
    T, h = estimate(whole[0])
    y = fibonacci_sphere(directions) @ T.T + h
    norms = np.array([np.linalg.norm(np.linalg.solve(Tf, (y - hf).T), axis=0)
                      for Tf, hf in (estimate(r) for r in rows)])
    g = norms.shape[0]
    return float(np.mean((g - 1) * norms.var(axis=0)))


def held_out_corrected(trials: Sequence[Mapping], rec: Recording, method: str
                       ) -> np.ndarray | None:
    """Every sample of ``rec`` corrected by ``method``'s fit on the folds it was held out of,
    in time order; None unless every fold's fit is usable."""
    rows = _fold_rows(trials, method)
    if not _usable(rows):
        return None
    out = np.empty((rec.K, 3))
    for f, test in enumerate(fold_indices(rec.K, len(rows))):
        T, h = estimate(next(r for r in rows if r["fit_on"] == f"fold{f}"))
        out[test] = np.linalg.solve(T, (rec.y[test] - h).T).T
    return out
