"""The compensation sweep: static against compensated calibration under a current disturbance.

Each trial simulates one manoeuvre (:mod:`magbench.sources.trajectory`) with a distortion drawn
as in the gyro sweep (``T = alpha I + (E + E^T) / 2``, ``h = e``, eq. 68 ranges) and adds a
disturbance proportional to a throttle-like current ``u(t)`` in [0, 1] (a sum of slow random
sinusoids, clipped): ``y = T m + h + C u + eps`` with ``C`` of norm ``strength`` (field units
at full current; the field has norm 1) in a random direction. Every selected method is run
three ways on the same samples:

* ``static``: the method alone, as if the disturbance were not there;
* ``compensated``: the method, then the time-varying terms fitted after it
  (:func:`magbench.methods.regressors.fit_time_varying`), always used;
* ``selected``: the terms kept only when they lower the held-out error on interleaved time
  blocks (:func:`magbench.methods.regressors.held_out_choice`), what ``calibrate`` does.

Scores: J (eq. 74) of ``T = A^-1`` and ``h = b`` against the truth, and the field magnitude
error on fresh samples (directions uniform on the sphere, currents uniform in [0, 1],
noise-free) corrected by each result, RMS of ``|m| - 1`` in %.

Every result is also stored (``estimates.csv``: ``A``, ``b`` and ``C`` of ``m = A (y - b -
C u)`` per strength, trial, method and variant, with the truth and the seed), so the report
section recomputes its field errors from the files (:func:`estimate_field_error`).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import accuracy_cost, trivial_cost
from magbench.core.seeding import rng
from magbench.engine.sweep import Study
from magbench.engine.trial import run_method, time_limit
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method
from magbench.methods.regressors import HeldOutChoice, TimeVarying, held_out_choice
from magbench.sources.trajectory import Trajectory, simulate
from magbench.studies.review import TRUTH_COLUMNS, truth_columns

__all__ = ["COMPENSATION_COLUMNS", "ESTIMATE_COLUMNS", "VARIANTS", "CompensationStudy",
           "compensation_rows", "compensation_tables", "current_profile",
           "estimate_field_error", "summarize_compensation"]

VARIANTS = ("static", "compensated", "selected")
COMPENSATION_COLUMNS = (["strength", "K", "sigma", "trial", "seed", "algorithm", "variant",
                         "ok", "error", "kept", "J", "J_h", "J_T", "J0", "meaningful",
                         "field_err_pct", "C_err"] + TRUTH_COLUMNS
                        + [f"C_true_{i}" for i in range(3)] + [f"C_{i}" for i in range(3)])

#: One fitted correction per strength, trial, method and variant (NaN where none was fitted).
ESTIMATE_COLUMNS = (["strength", "trial", "seed", "algorithm", "variant", "kept"]
                    + [f"A_{i}{j}" for i in range(3) for j in range(3)]
                    + [f"b_{i}" for i in range(3)] + [f"C_{i}" for i in range(3)]
                    + TRUTH_COLUMNS + [f"C_true_{i}" for i in range(3)])

#: Fresh directions on which every result is scored.
TEST_SAMPLES = 500


@dataclass(frozen=True)
class CompensationStudy(Study):
    """Everything that determines the compensation sweep's numbers.

    Attributes
    ----------
    strengths : sequence of float
        ``|C|`` at full current, in units of the field.
    trials, seed : int
    algorithms : sequence of str
        The static methods (each also run compensated).
    options : dict
        Per-method keyword options.
    rate_hz, duration_s : float
        Sampling of every manoeuvre.
    sigma, beta, gamma, alpha
        Noise std and distortion ranges (eq. 68).
    delta : float
        Threshold of eq. (76).
    call_timeout_s : float or None
        Time limit of one static call, and of the whole held-out choice of the terms.
    plugins : sequence of str
        Modules imported in every worker (they register extra methods).
    """

    strengths: Sequence[float]
    trials: int = 50
    seed: int = 2021
    algorithms: Sequence[str] = ("fang", "magical")
    options: dict = field(default_factory=dict)
    rate_hz: float = 20.0
    duration_s: float = 20.0
    sigma: float = 0.005
    beta: float = 0.05
    gamma: float = 0.05
    alpha: tuple[float, float] = (0.8, 1.2)
    delta: float = 0.5
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()
    name: str = "compensation"

    tables: ClassVar[dict] = {"trials": ("trials.csv", COMPENSATION_COLUMNS),
                              "estimates": ("estimates.csv", ESTIMATE_COLUMNS)}

    def units(self) -> list[tuple[int, int]]:
        return [(i, t) for i in range(len(self.strengths)) for t in range(self.trials)]

    def estimated_rows(self, units: Sequence) -> int:
        return len(units) * len(self.algorithms) * len(VARIANTS)

    def run_unit(self, unit: tuple[int, int]) -> dict[str, list[dict]]:
        index, trial = unit
        return compensation_tables(self, float(self.strengths[index]), trial)

    def summarize(self, out_dir: Path | str) -> pd.DataFrame:
        """Write and return ``summary.csv`` from ``trials.csv``."""
        trials = pd.read_csv(Path(out_dir) / "trials.csv", keep_default_na=False,
                             na_values=["", "nan", "NaN"])
        summary = summarize_compensation(trials)
        write_csv_atomic(summary, Path(out_dir) / "summary.csv")
        return summary


def current_profile(gen: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """A throttle-like current in [0, 1]: 0.5 plus three random sinusoids of 0.02-0.3 Hz
    (amplitudes 0.15-0.3), clipped."""
    freq = gen.uniform(0.02, 0.3, 3)
    amp = gen.uniform(0.15, 0.3, 3)
    phase = gen.uniform(0, 2 * np.pi, 3)
    wave = (amp * np.sin(2 * np.pi * freq * t[:, None] + phase)).sum(axis=1)
    return np.clip(0.5 + wave, 0.0, 1.0)


def _draw(spec: CompensationStudy, strength: float, trial: int
          ) -> tuple[Trajectory, np.ndarray, np.ndarray, np.ndarray]:
    """The trial's manoeuvre, current, disturbance ``C`` and disturbed samples."""
    gen = rng(spec.seed, zlib.crc32(f"compensation;{strength!r}".encode()), trial)
    alpha = gen.uniform(*spec.alpha)
    E = gen.uniform(-spec.beta, spec.beta, size=(3, 3))
    h = gen.uniform(-spec.gamma, spec.gamma, size=3)
    direction = gen.normal(size=3)
    C = strength * direction / np.linalg.norm(direction)
    traj = simulate(gen, rate_hz=spec.rate_hz, duration_s=spec.duration_s,
                    T=alpha * np.eye(3) + 0.5 * (E + E.T), h=h, mag_noise=spec.sigma)
    u = current_profile(gen, traj.t)
    return traj, u, C, traj.y + u[:, None] * C


def _test_set(seed: int, strength: float, trial: int) -> tuple[np.ndarray, np.ndarray]:
    """The fresh currents and directions a trial's results are scored on (from its seed)."""
    test = rng(seed, zlib.crc32(f"compensation-test;{strength!r}".encode()), trial)
    return test.uniform(0.0, 1.0, TEST_SAMPLES), fibonacci_sphere(TEST_SAMPLES)


def _field_error(result: TimeVarying, T: np.ndarray, h: np.ndarray, C: np.ndarray,
                 test_u: np.ndarray, directions: np.ndarray) -> float:
    """RMS of ``|m| - 1`` in %, on fresh noise-free samples corrected by ``result``."""
    y = directions @ T.T + h + test_u[:, None] * C
    m = result.apply(y, test_u[:, None])
    return float(100 * np.sqrt(np.mean((np.linalg.norm(m, axis=1) - 1) ** 2)))


def estimate_field_error(row: pd.Series | dict) -> float:
    """The field error (%) of one row of ``estimates.csv``, from that row alone: its
    correction on the trial's fresh samples (rebuilt from ``seed``, ``strength`` and
    ``trial``) of its true distortion; NaN where no correction was fitted."""
    def get(prefix: str, shape: tuple[int, ...]) -> np.ndarray:
        keys = ([f"{prefix}{i}{j}" for i in range(3) for j in range(3)] if len(shape) == 2
                else [f"{prefix}{i}" for i in range(3)])
        return np.array([row[k] for k in keys], dtype=float).reshape(shape)

    A = get("A_", (3, 3))
    if not np.all(np.isfinite(A)):
        return float("nan")
    test_u, directions = _test_set(int(row["seed"]), float(row["strength"]), int(row["trial"]))
    result = TimeVarying(A, get("b_", (3,)), get("C_", (3,))[:, None])
    return _field_error(result, get("T_true_", (3, 3)), get("h_true_", (3,)),
                        get("C_true_", (3,)), test_u, directions)


def _compensate(spec: CompensationStudy, name: str, y: np.ndarray, u: np.ndarray,
                trial: int, strength: float) -> tuple[HeldOutChoice | None, str]:
    """The held-out choice of the time-varying terms after ``name``, contained: any failure of
    the method (or its time limit, ``call_timeout_s`` for the whole choice) is the reason."""
    opts = dict(spec.options.get(name) or {})
    if get_method(name).randomized and "rng" not in opts:
        opts["rng"] = rng(spec.seed, zlib.crc32(f"compensation;{strength!r}".encode()), trial,
                          name, "compensated")

    def static_fit(samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return calibrate(samples, name, **opts).correction()

    try:
        with time_limit(spec.call_timeout_s):
            choice = held_out_choice(y, u[:, None], static_fit)
    except Exception as exc:   # failures are data: a row with the reason
        return None, f"{type(exc).__name__}: {exc}"
    return choice, "" if choice.fit is not None else choice.reason


def compensation_rows(spec: CompensationStudy, strength: float, trial: int) -> list[dict]:
    """Every selected method, static, compensated and selected, on one disturbed manoeuvre."""
    return compensation_tables(spec, strength, trial)["trials"]


def _estimate_row(base: dict, name: str, variant: str, result: TimeVarying | None,
                  kept: bool) -> dict:
    """A row of ``estimates.csv``: the correction ``result`` (NaN when there is none)."""
    nan = np.full(3, np.nan)
    A, b, C = ((result.A, result.b, result.C[:, 0]) if result is not None
               else (np.full((3, 3), np.nan), nan, nan))
    return {**{k: base[k] for k in ("strength", "trial", "seed")}, "algorithm": name,
            "variant": variant, "kept": kept,
            **{f"A_{i}{j}": float(A[i, j]) for i in range(3) for j in range(3)},
            **{f"b_{i}": float(v) for i, v in enumerate(b)},
            **{f"C_{i}": float(v) for i, v in enumerate(C)},
            **{k: base[k] for k in TRUTH_COLUMNS},
            **{f"C_true_{i}": base[f"C_true_{i}"] for i in range(3)}}


def compensation_tables(spec: CompensationStudy, strength: float, trial: int
                        ) -> dict[str, list[dict]]:
    """The ``trials`` and ``estimates`` rows of one disturbed manoeuvre: every selected
    method, static, compensated and selected."""
    traj, u, C, y = _draw(spec, strength, trial)
    key = zlib.crc32(f"compensation;{strength!r}".encode())
    test_u, directions = _test_set(spec.seed, strength, trial)
    J0 = trivial_cost(traj.T, traj.h)
    base = {"strength": strength, "K": len(y), "sigma": spec.sigma, "trial": int(trial),
            "seed": int(spec.seed), "J0": J0, **truth_columns(traj.T, traj.h),
            **{f"C_true_{i}": float(c) for i, c in enumerate(C)}}
    rows, estimates = [], []
    for name in spec.algorithms:
        out = run_method(name, lambda o, name=name: calibrate(y, name, **o),
                         options=spec.options.get(name) or {}, seed=spec.seed,
                         stream=(key, trial), call_timeout_s=spec.call_timeout_s)
        static, static_error = None, out.error
        if out.calibration is not None:
            try:
                A, b = out.calibration.correction()
                static = TimeVarying(A, b, np.zeros((3, 1)))
            except (ValueError, np.linalg.LinAlgError) as exc:   # a singular estimate
                static_error = f"{type(exc).__name__}: {exc}"
        choice, error = _compensate(spec, name, y, u, trial, strength)
        fit = choice.fit if choice is not None else None
        kept = bool(choice is not None and choice.kept)
        results = {"static": (static, static_error, False), "compensated": (fit, error, kept),
                   "selected": (fit, error, True) if kept else (static, static_error, False)}
        for variant in VARIANTS:
            result, why, kept_here = results[variant]
            rows.append({**base, "algorithm": name, "variant": variant,
                         **_scores(result, why, kept_here, traj, C, test_u, directions,
                                   spec.delta * J0)})
            estimates.append(_estimate_row(base, name, variant, result, kept_here))
    return {"trials": rows, "estimates": estimates}


def _scores(result: TimeVarying | None, error: str, kept: bool, traj: Trajectory,
            C: np.ndarray, test_u: np.ndarray, directions: np.ndarray,
            threshold: float) -> dict:
    if result is None:
        nan = float("nan")
        return {"ok": False, "error": error, "kept": kept, "J": nan, "J_h": nan, "J_T": nan,
                "meaningful": False, "field_err_pct": nan, "C_err": nan,
                **{f"C_{i}": nan for i in range(3)}}
    J, J_h, J_T = accuracy_cost(np.linalg.inv(result.A), result.b, traj.T, traj.h)
    C_hat = result.C[:, 0]
    return {"ok": not error, "error": error, "kept": kept, "J": J, "J_h": J_h, "J_T": J_T,
            "meaningful": bool(np.isfinite(J) and J < threshold),
            "field_err_pct": _field_error(result, traj.T, traj.h, C, test_u, directions),
            "C_err": float(np.linalg.norm(C_hat - C)),
            **{f"C_{i}": float(c) for i, c in enumerate(C_hat)}}


def summarize_compensation(trials: pd.DataFrame) -> pd.DataFrame:
    """Per strength, method and variant: runs, runs with an estimate, share kept, RB % (eq. 77),
    median J and median field error (%) over the runs with an estimate."""
    by = ["strength", "algorithm", "variant"]
    has = trials["J"].notna()
    grouped = trials.assign(has=has).groupby(by, sort=False)
    out = grouped.agg(n=("trial", "size"), n_ok=("has", "sum"),
                      kept_pct=("kept", lambda k: 100 * k.astype(bool).mean()),
                      RB_pct=("meaningful", lambda m: 100 * m.astype(bool).mean()),
                      median_J=("J", "median"), median_field_err_pct=("field_err_pct", "median"),
                      median_C_err=("C_err", "median")).reset_index()
    return out
