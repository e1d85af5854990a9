"""Accuracy, robustness and speed metrics of the review's section 10.1.1 (eqs. 69-81)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pandas is imported by summarize only: calibrate does not need it (~0.2 s)
    import pandas as pd

__all__ = ["accuracy_cost", "procrustes_rotation", "real_cost", "sample_mean", "summarize",
           "trivial_cost", "trivial_estimate"]


def procrustes_rotation(T: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """Orthogonal R minimising ``||T - T_true R||_F`` over O(3) (eqs. 72-73).

    With ``T_true^T T = U S V^T``, the minimiser is ``R = U V^T`` (Schonemann 1966).
    """
    U, _, Vt = np.linalg.svd(np.asarray(T_true).T @ np.asarray(T))
    return U @ Vt


def accuracy_cost(T: np.ndarray, h: np.ndarray, T_true: np.ndarray,
                  h_true: np.ndarray) -> tuple[float, float, float]:
    """The accuracy cost J of eq. (74) and its two parts.

    Returns
    -------
    J, J_h, J_T : float
        ``J_h = ||h_true - h||`` (69), ``J_T = ||T - T_true R||_F`` (71) with R from (73),
        and ``J = J_h + J_T`` (74).
    """
    R = procrustes_rotation(T, T_true)
    J_h = float(np.linalg.norm(np.asarray(h_true) - np.asarray(h)))
    J_T = float(np.linalg.norm(np.asarray(T) - np.asarray(T_true) @ R))
    return J_h + J_T, J_h, J_T


def trivial_cost(T_true: np.ndarray, h_true: np.ndarray) -> float:
    """J_o of eq. (75): the cost (74) of the trivial answer ``(I, 0)``."""
    return accuracy_cost(np.eye(3), np.zeros(3), T_true, h_true)[0]


def real_cost(samples: np.ndarray, T: np.ndarray, h: np.ndarray) -> float:
    """J_r of eq. (81): mean of ``(||m_k||^2 - 1)^2`` with ``m_k = T^-1 (y_k - h)`` (82).

    ``T^-1`` is formed once (3x3) and applied to all samples by one product: the same
    ``m_k`` to rounding as a K-right-hand-side solve, at a fifth of its cost (every
    :func:`~magbench.methods.api.calibrate` call evaluates J_r).
    """
    T_inv = np.linalg.inv(np.asarray(T, dtype=float))
    m = (np.asarray(samples, dtype=float) - np.asarray(h, dtype=float)) @ T_inv.T
    e = np.einsum("ij,ij->i", m, m) - 1.0
    return float(e @ e) / e.shape[0]        # the mean of e^2 as one dot product


def sample_mean(samples: np.ndarray) -> np.ndarray:
    """Mean of the rows of a ``(K, 3)`` array, as one matrix-vector product.

    The same mean to rounding as ``samples.mean(axis=0)``, whose strided reduction costs
    several times as much at K = 300.
    """
    return (np.ones(samples.shape[0]) @ samples) / samples.shape[0]


def trivial_estimate(samples: np.ndarray, mean: np.ndarray | None = None,
                     centred: np.ndarray | None = None,
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """The estimate any calibration must beat: ``h`` the sample mean, ``T = r I`` with ``r``
    the mean distance of the samples from it (no fit at all), and its J_r (81).

    Scale in, scale out like every method; its J_r is the ceiling of a converged fit. With
    ``T = r I``, ``||m_k||^2 = ||y_k - h||^2 / r^2`` (82) needs no solve.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k``.
    mean, centred : ndarray, shape (3,) and (K, 3), optional
        ``sample_mean(samples)`` and ``samples - mean`` if the caller has them already
        (:func:`~magbench.methods.api.calibrate` does); both or neither.

    Returns
    -------
    T : ndarray, shape (3, 3)
        ``r I``.
    h : ndarray, shape (3,)
        The sample mean.
    J_r : float
        Eq. (81) of ``(T, h)`` on ``samples``.
    """
    y = np.asarray(samples, dtype=float)
    h = sample_mean(y) if mean is None else mean
    yc = y - h if centred is None else centred
    d2 = np.einsum("ij,ij->i", yc, yc)
    r = float(np.sqrt(d2).sum()) / d2.shape[0]
    e = d2 / (r * r) - 1.0 if r > 0 else np.full_like(d2, np.nan)
    return r * np.eye(3), h, float(e @ e) / d2.shape[0]


def _inverse(x: float) -> float:
    # sigma = 0 makes the bound 0: its accuracy is unbounded, not an error.
    return 1.0 / x if x > 0 else (np.inf if x == 0 else np.nan)


def summarize(trials: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Per-group RB % (77), rho (78) and tau (79) from trial rows.

    Parameters
    ----------
    trials : DataFrame
        One row per (point, trial, algorithm) with columns ``meaningful`` (bool, eq. 76),
        ``J`` and ``time_s``.
    by : list of str
        Grouping columns, e.g. ``["K", "sigma", "beta", "gamma", "algorithm"]``.

    Returns
    -------
    DataFrame
        One row per group: n, n_meaningful, RB_pct, rho (mean J over meaningful runs),
        accuracy (1/rho), tau_s (mean time over meaningful runs), speed_hz (1/tau), plus
        tau_all_s, the mean time over all runs, since a method that never succeeds still costs.
        When the rows carry the Cramer-Rao columns of :mod:`magbench.core.crb` (``sq_err``, ``crb``,
        ``crb_J``), also: mse (mean ``J_h^2 + J_T^2`` over meaningful runs), crb_mse (mean bound
        over the same runs), efficiency (crb_mse / mse; 1 = optimal) and crb_accuracy
        (1 / mean ``crb_J`` over all runs: the 1/rho of an efficient unbiased estimator).
    """
    import pandas as pd

    with_crb = {"sq_err", "crb", "crb_J"} <= set(trials.columns)

    def one(group: pd.DataFrame) -> pd.Series:
        ok = group["meaningful"].astype(bool).to_numpy()
        n_ok = int(ok.sum())
        rho = float(group["J"].to_numpy()[ok].mean()) if n_ok else np.nan
        tau = float(group["time_s"].to_numpy()[ok].mean()) if n_ok else np.nan
        row = {
            "n": len(group), "n_meaningful": n_ok, "RB_pct": 100.0 * n_ok / len(group),
            "rho": rho, "accuracy": 1.0 / rho if n_ok else np.nan,
            "tau_s": tau, "speed_hz": 1.0 / tau if n_ok else np.nan,
            "tau_all_s": float(group["time_s"].mean()),
        }
        if with_crb:
            mse = float(group["sq_err"].to_numpy()[ok].mean()) if n_ok else np.nan
            bound = float(group["crb"].to_numpy()[ok].mean()) if n_ok else np.nan
            row.update({"mse": mse, "crb_mse": bound,
                        "efficiency": bound / mse if n_ok and mse > 0 else np.nan,
                        "crb_accuracy": _inverse(float(group["crb_J"].mean()))})
        return pd.Series(row)

    columns = ["meaningful", "J", "time_s"] + (["sq_err", "crb", "crb_J"] if with_crb else [])
    # dropna=False: an empty grouping value (an option axis's default run) is a group too.
    out = trials.groupby(by, sort=False, dropna=False)[columns].apply(one)
    out = out.reset_index()
    out["n"] = out["n"].astype(int)
    out["n_meaningful"] = out["n_meaningful"].astype(int)
    return out
