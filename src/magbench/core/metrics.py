"""Accuracy, robustness and speed metrics of the review's section 10.1.1 (eqs. 69-81)."""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["accuracy_cost", "procrustes_rotation", "real_cost", "summarize", "trivial_cost"]


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
    """J_r of eq. (81): mean of ``(||m_k||^2 - 1)^2`` with ``m_k = T^-1 (y_k - h)`` (82)."""
    m = np.linalg.solve(np.asarray(T), (np.asarray(samples) - np.asarray(h)).T)
    return float(np.mean((np.einsum("ij,ij->j", m, m) - 1.0) ** 2))


def trivial_estimate(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The estimate any calibration must beat: ``h`` the sample mean, ``T = r I`` with ``r``
    the mean distance of the samples from it (no fit at all).

    Scale in, scale out like every method; its J_r (81) is the ceiling of a converged fit.
    """
    y = np.asarray(samples, dtype=float)
    h = y.mean(axis=0)
    r = float(np.mean(np.sqrt(np.einsum("ij,ij->i", y - h, y - h))))
    return r * np.eye(3), h


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
