"""Wu and Shi's (2015) own simulation study, section IV: Table I and Figures 3, 5 and 6.

``python -m magbench sweep=wushi`` simulates their magnetometer
(:mod:`magbench.sources.wushi_sim`),

    y_k = S C_k m_n + h + e_k,   e_k ~ N(0, sigma^2 I),   k = 1..N          (their eq. 1)

with the Changsha field ``m_n``, ``S`` and ``h`` of their eq. (24), ``sigma = 0.003`` gauss,
``N = 300`` and the Euler-angle attitude pattern of section IV (roll and pitch within +-20 deg,
one yaw turn: only a band of the sphere is covered), over 50 Monte Carlo runs (``trials``),
and writes to
``<results_dir>/wushi/``:

``runs.csv``
    Every magnetometer-only method on every run: Wu and Shi's error metrics ``e_s`` (%),
    ``e_o`` (deg), ``e_h`` (gauss) and the review's accuracy cost J (eq. 74).
``table1.csv``
    Their Table I (mean and std over the runs) for ML (``wu_shi``) and NM (``wu_shi_nm``) beside
    the paper's numbers, plus every other method as extra rows.
``fig3_objective.csv/png``
    Objective per Gauss-Newton iteration, (4) for ML (gauss^2) and (11) for NM, every run.
``fig5_time.csv/png``
    Execution time against N for ML and NM, and their ratio.
``fig6_divergence.csv/png`` (and ``perturbation_runs.csv``)
    Divergences out of the runs as the initial estimate is perturbed by alpha.
``claims.csv`` and ``wushi.md``
    The paper's claims, each with the evidence and a verdict (written by the command from
    :mod:`magbench.report.wushi`; the figures by :mod:`magbench.figures.wushi`).

One Monte Carlo run is one work unit of :mod:`magbench.engine` (``trials`` runs; containment,
seeding, resume and workers as in every study).

The error metrics use the decomposition of their section II: ``S^-1 = Q R`` (R upper
triangular, positive diagonal), ``R = M Lambda`` (Lambda diagonal, M unit diagonal). A method's
``T`` is defined up to an orthogonal factor on the right (``T -> T Q`` leaves ``T m`` on the
unit sphere), so every method's ``T`` is first brought to that gauge: ``T^-1 = Q R_est`` by QR
with positive diagonal, and ``R_est`` is used. For ``wu_shi`` and ``wu_shi_nm``, whose ``T`` is
already upper triangular with positive diagonal, this is the identity (``R_est = T^-1``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from magbench.core.crb import crb_covariance
from magbench.core.files import write_csv_atomic
from magbench.core.metrics import accuracy_cost
from magbench.core.model import CalibrationFailed
from magbench.core.reference import paper_values
from magbench.core.seeding import rng
from magbench.engine.sweep import Study
from magbench.engine.trial import run_method
from magbench.methods.algorithms import wu_shi, wu_shi_nm
from magbench.methods.algorithms._wu_shi_init import initial_estimate, upper_inverse
from magbench.methods.api import calibrate, unit_scale
from magbench.methods.registry import get_method, method_label, methods
from magbench.sources.wushi_sim import WuShiData, attitude_matrices, simulate, truth
from magbench.studies.times import split_times, with_times

__all__ = [
    "CRB_ROW",
    "ML",
    "NM",
    "RUN_COLUMNS",
    "SHORT",
    "WuShiStudy",
    "count_divergences",
    "crb_reference",
    "decompose",
    "divergence_table",
    "error_metrics",
    "finish",
    "gauge_R",
    "iterations_to_converge",
    "read_settings",
    "table1",
    "timing",
]

#: ML and NM: the registered names of Wu and Shi's two estimators.
ML, NM = "wu_shi", "wu_shi_nm"
SHORT = {ML: "ML", NM: "NM"}
#: Tolerance of "the objective has reached its final value" (relative), for Fig. 3's claim.
SETTLED_RTOL = 1e-6
RUN_COLUMNS = ["run", "algorithm", "offset_removed", "ok", "converged", "error", "n_iter",
               "e_s", "e_o", "e_h", "J", "J_h", "J_T"]


# ----------------------------------------------------------------------------------------
# Error metrics of section IV
# ----------------------------------------------------------------------------------------

def gauge_R(T: np.ndarray) -> np.ndarray:
    """``R`` upper triangular with positive diagonal such that ``T^-1 = Q R`` (Q orthogonal).

    Invariant to ``T -> T Q'`` for any orthogonal ``Q'``: ``(T Q')^-1 = Q'^T T^-1`` has the same
    triangular factor. For the truth, ``T = S`` gives Wu and Shi's ``S^-1 = Q R``.
    """
    _, R = np.linalg.qr(np.linalg.inv(np.asarray(T, dtype=float)))
    signs = np.sign(np.diag(R))
    signs[signs == 0] = 1.0
    return signs[:, None] * R


def decompose(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R = M Lambda`` with Lambda diagonal and unit-diagonal M: returns ``(diag(Lambda), M)``."""
    lam = np.diag(R).copy()
    return lam, R / lam[None, :]


def error_metrics(T: np.ndarray, h: np.ndarray, S: np.ndarray, h_true: np.ndarray,
                  ) -> dict[str, float]:
    """Wu and Shi's ``e_s`` (%), ``e_o`` (degrees) and ``e_h`` (field units) of section IV.

    ``e_s = ||diag(Lambda^-1 Lambda_hat - I)|| / 3 * 100``, ``e_o = 180 / (3 pi)
    ||vec(M_hat - M)||``, ``e_h = ||h_hat - h|| / 3``, after bringing ``T`` to the gauge of
    :func:`gauge_R`.
    """
    lam_true, M_true = decompose(gauge_R(S))
    lam, M = decompose(gauge_R(T))
    return {"e_s": float(np.linalg.norm(lam / lam_true - 1.0) / 3.0 * 100.0),
            "e_o": float(180.0 / (3.0 * np.pi) * np.linalg.norm(M - M_true)),
            "e_h": float(np.linalg.norm(np.asarray(h) - np.asarray(h_true)) / 3.0)}


def crb_reference(N: int, sigma: float, draws: int = 2000, seed: int = 0) -> dict[str, float]:
    """Mean and std of e_s, e_o, e_h and J of an efficient unbiased estimator on these data.

    The attitude pattern is deterministic, so every run has the same directions ``m_k`` and the
    same Cramer-Rao bound (:func:`magbench.core.crb.crb_covariance`, gauge-projected). Errors
    ``(dT, dh)`` are drawn from it (the asymptotic error of maximum likelihood) and the metrics
    computed on ``(S + dT, h + dh)``: what no unbiased method can beat on average.
    """
    m_n, S, h = truth()
    m = attitude_matrices(N) @ m_n
    C = crb_covariance(S, m, sigma)
    w, V = np.linalg.eigh(C)
    z = np.random.default_rng(seed).standard_normal((draws, 12)) @ (
        V * np.sqrt(np.clip(w, 0.0, None))).T
    rows = [{**error_metrics(S + d[:9].reshape(3, 3), h + d[9:], S, h),
             "J": accuracy_cost(S + d[:9].reshape(3, 3), h + d[9:], S, h)[0]} for d in z]
    frame = pd.DataFrame(rows)
    return {**{f"{c}_mean": float(frame[c].mean()) for c in frame},
            **{f"{c}_std": float(frame[c].std(ddof=1)) for c in frame}}


# ----------------------------------------------------------------------------------------
# Convergence and divergence from objective histories
# ----------------------------------------------------------------------------------------

def iterations_to_converge(history: Sequence[float], rtol: float = SETTLED_RTOL) -> int:
    """First iteration from which the objective stays within ``rtol`` (relative) of its final
    value: the iteration at which a Fig. 3 curve has flattened."""
    f = np.asarray(history, dtype=float)
    final = f[-1]
    off = np.abs(f - final) > rtol * max(abs(final), np.finfo(float).tiny)
    bad = np.flatnonzero(off)
    return int(bad[-1] + 1) if bad.size else 0


def count_divergences(final_objectives: Sequence[float], threshold: float) -> int:
    """Runs whose final objective exceeds ``threshold`` (Wu and Shi's divergence, Fig. 6);
    NaN (a run that failed: singular Hessian, non-finite iterate) counts as divergent."""
    f = np.asarray(final_objectives, dtype=float)
    return int(np.sum(~(f <= threshold)))


# ----------------------------------------------------------------------------------------
# The study
# ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class WuShiStudy(Study):
    """Settings of the study; defaults are the paper's (section IV)."""

    runs: int = 50                            # Monte Carlo runs (the top-level trials)
    N: int = 300
    sigma: float = 0.003
    seed: int = 2021
    algorithms: tuple[str, ...] = ()          # empty: every magnetometer-only method
    alphas_pct: tuple[float, ...] = (0, 1, 2, 3, 4, 5, 6, 7)
    thresholds: dict = field(default_factory=lambda: {"ML": 0.004, "NM": 0.018})
    time_N: tuple[int, ...] = (100, 200, 500, 1000, 2000, 3000)
    time_repeats: int = 5
    time_calls: int = 3
    max_iter: int = 50
    converge_within: int = 5
    control_runs: int = 10                    # runs also calibrated with the offset removed
    claimed_ratio: float = 10.0
    options: dict = field(default_factory=dict)
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()
    name: str = "wushi"
    only: tuple[str, ...] | None = None       # the entrants a cached run computes (None: all)

    tables: ClassVar[dict] = {
        "runs": ("runs.csv", RUN_COLUMNS),
        "times": ("runs_times.csv", ["run", "algorithm", "time_s"]),
        "history": ("fig3_objective.csv", ["method", "run", "iteration", "objective"]),
        "perturbation": ("perturbation_runs.csv", ["alpha_pct", "run", "method",
                                                   "final_objective", "n_iter", "converged",
                                                   "reason"]),
    }

    #: Rows cached per method: a run's rows come method by method (its control row beside
    #: its row, on the first ``control_runs`` runs: rows per unit differ); Figures 3 and 6's
    #: Gauss-Newton runs belong to ML, whose key holds NM's too (they refine with both).
    method_column: ClassVar[str] = "algorithm"
    method_fields: ClassVar[tuple[str, ...]] = ("algorithms", "options", "plugins", "only")
    table_owner: ClassVar[dict] = {"history": ML, "perturbation": ML}
    ragged: ClassVar[bool] = True

    def entrants(self) -> list[str]:
        names = self.method_names()
        return names if self.only is None else [n for n in names if n in self.only]

    def with_methods(self, names: Sequence[str]) -> WuShiStudy:
        return replace(self, only=tuple(names))

    def method_key(self, name: str) -> dict[str, str]:
        if name != ML:
            return super().method_key(name)
        ml, nm = super().method_key(ML), super().method_key(NM)
        return {"options": f"{ml['options']}+{nm['options']}", "code": f"{ml['code']}+{nm['code']}"}

    def units(self) -> list[int]:
        return list(range(self.runs))

    def run_unit(self, run: int) -> dict[str, list[dict]]:
        tables = run_one(self, run)
        tables["runs"], tables["times"] = split_times(tables["runs"], "run")
        return tables

    def method_names(self) -> list[str]:
        """ML, NM, then every other selected method that needs no gyroscope."""
        chosen = list(self.algorithms) or methods()
        rest = [n for n in chosen if n not in (ML, NM) and get_method(n).magnetometer_only]
        return [ML, NM] + rest


def refine_unit(method: str, y: np.ndarray, R0: np.ndarray, h0: np.ndarray, max_iter: int,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Run ML or NM Gauss-Newton from ``(R0, h0)`` (in gauss) on data normalised as
    :func:`magbench.calibrate` does (divided by the power of two nearest the RMS norm).

    Returns ``(T, h, history, converged)`` in gauss: the ML objective (4) is scaled back to
    gauss^2; the NM objective (11) is dimensionless (``R u`` does not change with the unit).
    """
    scale = unit_scale(y)
    module = wu_shi if method == ML else wu_shi_nm
    cal, history = module.refine(y / scale, upper_inverse(R0 * scale), h0 / scale,
                                 max_iter=max_iter)
    factor = scale ** 2 if method == ML else 1.0
    return cal.T * scale, cal.h * scale, history * factor, cal.converged


def _method_row(spec: WuShiStudy, name: str, data: WuShiData, run: int,
                offset_removed: bool = False) -> dict:
    """One method on one data set; with ``offset_removed`` on the control data ``y - h``
    (true offset subtracted, so the truth is ``(S, 0)``). ``ok`` means an estimate came back
    (a capped one included, ``converged`` False)."""
    if offset_removed:
        data = WuShiData(data.y - data.h, data.m, data.C, data.S, np.zeros(3))
    out = run_method(name, lambda o: calibrate(data.y, name, raw=True, **o),
                     options=spec.options.get(name) or {}, seed=spec.seed,
                     stream=(4 if offset_removed else 2, run),
                     call_timeout_s=spec.call_timeout_s)
    row = {"algorithm": name, "offset_removed": offset_removed, "ok": False,
           "converged": False, "error": out.error, "n_iter": out.n_iter, "e_s": np.nan,
           "e_o": np.nan, "e_h": np.nan, "J": np.nan, "J_h": np.nan, "J_T": np.nan,
           "time_s": out.time_s}
    cal = out.calibration
    if cal is not None:
        J, J_h, J_T = accuracy_cost(cal.T, cal.h, data.S, data.h)
        row.update(ok=True, converged=out.ok, J=J, J_h=J_h, J_T=J_T,
                   **error_metrics(cal.T, cal.h, data.S, data.h))
    return row


def perturb(rng: np.random.Generator, R0: np.ndarray, h0: np.ndarray, alpha: float,
            ) -> tuple[np.ndarray, np.ndarray]:
    """``R0 .* (1 + alpha sign(randn(3,3)))`` and ``h0 .* (1 + alpha sign(randn(3,1)))``."""
    return (R0 * (1.0 + alpha * np.sign(rng.standard_normal((3, 3)))),
            h0 * (1.0 + alpha * np.sign(rng.standard_normal(3))))


def run_one(spec: WuShiStudy, run: int) -> dict[str, list[dict]]:
    """Everything for one Monte Carlo run: table rows, Fig. 3 histories, Fig. 6 outcomes."""
    data = simulate(rng(spec.seed, 0, run), spec.N, spec.sigma)
    table = []
    names = spec.entrants()
    for name in names:
        table.append({"run": run, **_method_row(spec, name, data, run)})
        if run < spec.control_runs:
            table.append({"run": run, **_method_row(spec, name, data, run,
                                                    offset_removed=True)})
    if ML not in names:         # Figures 3 and 6 are ML's rows (a cached run without it)
        return {"runs": table, "history": [], "perturbation": []}
    scale = unit_scale(data.y)
    history_rows, perturbation_rows = [], []
    try:
        T0, h0 = initial_estimate(data.y / scale)
    except CalibrationFailed as exc:
        perturbation_rows = [{"alpha_pct": a, "run": run, "method": SHORT[m],
                              "final_objective": np.nan, "n_iter": 0, "converged": False,
                              "reason": f"initial estimate: {exc}"}
                             for a in spec.alphas_pct for m in (ML, NM)]
        return {"runs": table, "history": [], "perturbation": perturbation_rows}
    R0, h0 = upper_inverse(T0) / scale, h0 * scale                  # in gauss
    for method in (ML, NM):
        try:
            _, _, history, _ = refine_unit(method, data.y, R0, h0, spec.max_iter)
        except CalibrationFailed:
            continue
        history_rows += [{"method": SHORT[method], "run": run, "iteration": i, "objective": f}
                         for i, f in enumerate(history)]
    for ia, alpha_pct in enumerate(spec.alphas_pct):
        R0p, h0p = perturb(rng(spec.seed, 1, run, ia), R0, h0, alpha_pct / 100.0)
        for method in (ML, NM):
            row = {"alpha_pct": alpha_pct, "run": run, "method": SHORT[method]}
            try:
                _, _, history, converged = refine_unit(method, data.y, R0p, h0p,
                                                       spec.max_iter)
                row.update(final_objective=float(history[-1]), n_iter=len(history) - 1,
                           converged=converged, reason="" if converged else "iteration cap")
            except CalibrationFailed as exc:
                row.update(final_objective=np.nan, n_iter=0, converged=False, reason=str(exc))
            perturbation_rows.append(row)
    return {"runs": table, "history": history_rows, "perturbation": perturbation_rows}


def timing(spec: WuShiStudy) -> pd.DataFrame:
    """Fig. 5: wall time of ``calibrate(y, ML)`` and ``calibrate(y, NM)`` (initial estimate
    plus Gauss-Newton) against N.

    Each of ``time_repeats`` data sets per N is calibrated in ``time_calls`` rounds, every round
    sweeping all N and both methods, so a burst of load from other processes on a shared machine
    hits different N in different rounds; per data set the fastest round counts (load only ever
    adds time), then the median over the data sets is reported.
    """
    datasets = {(N, rep): simulate(rng(spec.seed, 3, int(N), rep), int(N), spec.sigma).y
                for N in spec.time_N for rep in range(spec.time_repeats)}
    best = {(key, name): np.inf for key in datasets for name in (ML, NM)}
    iters: dict[tuple, int] = {}
    for _ in range(spec.time_calls):
        for key, y in datasets.items():
            for name in (ML, NM):
                start = time.perf_counter()
                try:
                    cal = calibrate(y, name, raw=True)
                except CalibrationFailed:
                    continue
                best[key, name] = min(best[key, name], time.perf_counter() - start)
                iters[key, name] = cal.n_iter
    rows = []
    for N in spec.time_N:
        row: dict[str, float] = {"N": int(N)}
        for name, short in ((ML, "ml"), (NM, "nm")):
            t = [best[(N, r), name] for r in range(spec.time_repeats)
                 if np.isfinite(best[(N, r), name])]
            its = [iters[(N, r), name] for r in range(spec.time_repeats)
                   if ((N, r), name) in iters]
            row[f"{short}_time_s"] = float(np.median(t)) if t else np.nan
            row[f"{short}_iterations"] = float(np.median(its)) if its else np.nan
        row["ml_over_nm"] = row["ml_time_s"] / row["nm_time_s"]
        row["repeats"] = spec.time_repeats
        rows.append(row)
    return pd.DataFrame(rows, columns=["N", "ml_time_s", "nm_time_s", "ml_over_nm",
                                       "ml_iterations", "nm_iterations", "repeats"])


#: The pseudo-method name of the Cramer-Rao reference row in ``table1.csv``.
CRB_ROW = "crb"


def table1(runs: pd.DataFrame, crb: dict[str, float] | None = None) -> pd.DataFrame:
    """Mean and std (ddof 1, as Matlab's) of e_s, e_o, e_h and J per method, beside the paper;
    with ``crb`` (from :func:`crb_reference`) a last row for the efficient estimator."""
    paper = paper_values()["wu_shi"]["table1"]
    removed = runs["offset_removed"].astype(bool)
    control = runs[removed & runs["ok"].astype(bool)].groupby("algorithm")["J"].median()
    rows = []
    for name, group in runs[~removed].groupby("algorithm", sort=False):
        good = group[group["ok"].astype(bool)]
        errors = group.loc[~group["ok"].astype(bool), "error"]
        capped = group.loc[group["ok"].astype(bool) & ~group["converged"].astype(bool), "error"]
        reasons = pd.concat([errors, capped])
        label = method_label(name)
        row = {"algorithm": name, "label": label, "runs": len(group),
               "estimates": len(good), "failures": len(errors),
               "at_cap": len(capped),
               "note": str(reasons.mode().iloc[0])[:120] if len(reasons) else ""}
        for metric in ("e_s", "e_o", "e_h", "J"):
            row[f"{metric}_mean"] = good[metric].mean() if len(good) else np.nan
            row[f"{metric}_std"] = good[metric].std(ddof=1) if len(good) > 1 else np.nan
        row["J_median"] = good["J"].median() if len(good) else np.nan
        row["J_median_offset_removed"] = control.get(name, np.nan)
        row["time_ms_median"] = 1e3 * group["time_s"].median()
        key = SHORT.get(name)
        for metric in ("e_s", "e_o", "e_h"):
            mean, std = paper[key][metric] if key else (np.nan, np.nan)
            row[f"paper_{metric}_mean"], row[f"paper_{metric}_std"] = mean, std
        rows.append(row)
    if crb is not None:
        rows.append({"algorithm": CRB_ROW, "label": "efficient estimator (Cramer-Rao bound)",
                     "runs": len(runs["run"].unique()), "estimates": 0, "failures": 0,
                     "at_cap": 0, "note": "errors drawn from the bound, not a method", **crb,
                     "J_median": np.nan, "J_median_offset_removed": np.nan,
                     "time_ms_median": np.nan})
    return pd.DataFrame(rows)


def divergence_table(perturbation: pd.DataFrame, thresholds: dict) -> pd.DataFrame:
    """Fig. 6: divergences per alpha for ML and NM (final objective above its threshold)."""
    rows = []
    for alpha, group in perturbation.groupby("alpha_pct", sort=True):
        row = {"alpha_pct": float(alpha), "runs": int(group["run"].nunique())}
        for short in ("ML", "NM"):
            sub = group[group["method"] == short]
            row[f"{short}_divergences"] = count_divergences(sub["final_objective"],
                                                            thresholds[short])
            row[f"{short}_failed"] = int(sub["final_objective"].isna().sum())
        rows.append(row)
    return pd.DataFrame(rows)


def finish(spec: WuShiStudy, folder: Path | str) -> None:
    """From ``runs.csv`` and ``perturbation_runs.csv``: ``table1.csv`` (with the Cramer-Rao
    row), ``fig6_divergence.csv``, the timing of Fig. 5 (``fig5_time.csv``, measured here, in
    this process) and ``settings.csv``."""
    folder = Path(folder)
    runs = pd.read_csv(folder / "runs.csv", dtype={"error": str})
    runs["error"] = runs["error"].fillna("")
    runs = with_times(runs, folder / "runs.csv", "run")
    perturbation = pd.read_csv(folder / "perturbation_runs.csv", dtype={"reason": str})
    settings = {"runs": spec.runs, "N": spec.N, "sigma": spec.sigma, "seed": spec.seed,
                "max_iter": spec.max_iter, "control_runs": spec.control_runs,
                "time_repeats": spec.time_repeats, "time_calls": spec.time_calls,
                "threshold_ML": spec.thresholds["ML"], "threshold_NM": spec.thresholds["NM"],
                "claimed_ratio": spec.claimed_ratio, "converge_within": spec.converge_within}
    write_csv_atomic(pd.DataFrame({"key": list(settings), "value": list(settings.values())}),
                     folder / "settings.csv")
    write_csv_atomic(table1(runs, crb_reference(spec.N, spec.sigma, seed=spec.seed)),
                     folder / "table1.csv")
    write_csv_atomic(divergence_table(perturbation, spec.thresholds),
                     folder / "fig6_divergence.csv")
    write_csv_atomic(timing(spec), folder / "fig5_time.csv")


def read_settings(folder: Path | str) -> dict[str, str]:
    """``settings.csv`` of a finished study as a key -> value mapping (values as text)."""
    frame = pd.read_csv(Path(folder) / "settings.csv", dtype=str)
    return dict(zip(frame["key"], frame["value"], strict=True))
