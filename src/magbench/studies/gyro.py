"""The gyro sweep: gyro-aided and magnetometer-only methods on simulated manoeuvres.

Each trial simulates one manoeuvre (:mod:`magbench.sources.trajectory`) with a drawn distortion
and gyro bias, and runs every selected method on the same magnetometer samples; gyro-aided
methods also get the gyro samples and times (and MagFactor3 the true attitude and field). Points
are the grid of gyro noise levels and coverages (named simulator settings). One row per (point,
trial, method), with the columns of :func:`magbench.studies.review.trial_rows` plus the gyro
bias.

The distortion is ``T = alpha I + (E + E^T) / 2`` (symmetric: the magnetometer's axes are the
gyro's, as SAR and MAGYC assume; the review's non-symmetric ``E`` would add a magnetometer-gyro
misalignment none of them models) and ``h = e``, with alpha, E, e drawn as in eq. (68).

``python -m magbench sweep=gyro [trials=10] [n_jobs=2]`` runs it on :mod:`magbench.engine`
(same containment, seeding, resume and workers as every study).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.core.metrics import accuracy_cost, summarize, trivial_cost
from magbench.core.model import Calibration
from magbench.core.seeding import rng
from magbench.engine.sweep import Study
from magbench.engine.trial import H_COLUMNS, T_COLUMNS, estimate_columns, run_method
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method
from magbench.sources.trajectory import Trajectory, simulate
from magbench.studies.review import TIME_COLUMNS, TRUTH_COLUMNS, read_trials, truth_columns
from magbench.studies.times import split_times

__all__ = ["DEFAULT_COVERAGES", "GYRO_POINT_COLUMNS", "GYRO_ROW_COLUMNS", "GyroPoint",
           "GyroStudy", "draw_trajectory", "gyro_trial_rows", "summarize_gyro"]

GYRO_POINT_COLUMNS = ["coverage", "gyro_noise", "sigma"]
_WB_TRUE = [f"wb_true_{i}" for i in range(3)]
_WB = [f"wb_{i}" for i in range(3)]
GYRO_ROW_COLUMNS = (GYRO_POINT_COLUMNS + ["K", "trial", "seed", "algorithm", "gyro", "ok",
                                          "error", "n_iter", "J", "J_h", "J_T", "J0",
                                          "meaningful", "J_wb"]
                    + TRUTH_COLUMNS + H_COLUMNS + T_COLUMNS + _WB_TRUE + _WB)

#: Named coverages (simulator settings): a full tumble, Wu and Shi's pattern, mostly yaw.
DEFAULT_COVERAGES: dict[str, dict] = {
    "wide": {"motion": "random", "rate_rms": 0.8},
    "wu_shi": {"motion": "euler", "tilt_deg": 20.0},
    "low": {"motion": "random", "rate_rms": 0.8, "axis_weights": (0.15, 0.15, 1.0)},
}


@dataclass(frozen=True)
class GyroPoint:
    """One setting: coverage name, gyro noise std (rad/s), magnetometer noise std."""

    coverage: str
    gyro_noise: float
    sigma: float

    @property
    def key(self) -> int:
        """Stable 32-bit identity keying the point's random streams."""
        return zlib.crc32(f"{self.coverage};{self.gyro_noise!r};{self.sigma!r}".encode())


@dataclass(frozen=True)
class GyroStudy(Study):
    """Everything that determines the gyro sweep's numbers.

    Attributes
    ----------
    points : sequence of GyroPoint
    trials, seed : int
        Manoeuvres per point; base seed.
    algorithms : sequence of str
        Registered names, gyro-aided or not.
    options : dict
        Per-method keyword options.
    coverages : dict
        Coverage name -> keyword arguments of :func:`magbench.sources.trajectory.simulate`.
    rate_hz, duration_s : float
        Sampling of every manoeuvre.
    beta, gamma, alpha : float, float, (float, float)
        Distortion ranges (eq. 68), ``T`` symmetrised.
    gyro_bias_max : float
        Gyro bias components uniform in ``[-gyro_bias_max, gyro_bias_max]`` rad/s.
    delta : float
        Threshold of eq. (76).
    call_timeout_s : float or None
        Time limit of one calibration call.
    plugins : sequence of str
        Modules imported in every worker (they register extra methods).
    """

    points: Sequence[GyroPoint]
    trials: int = 50
    seed: int = 2021
    algorithms: Sequence[str] = ()
    options: dict = field(default_factory=dict)
    coverages: dict = field(default_factory=lambda: dict(DEFAULT_COVERAGES))
    rate_hz: float = 20.0
    duration_s: float = 15.0
    beta: float = 0.05
    gamma: float = 0.05
    alpha: tuple[float, float] = (0.8, 1.2)
    gyro_bias_max: float = 0.02
    delta: float = 0.5
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()
    name: str = "gyro"

    #: Rows are cached per method (:mod:`magbench.engine.sweep`): one row per method and unit.
    method_column: ClassVar[str] = "algorithm"
    tables: ClassVar[dict] = {"trials": ("trials.csv", GYRO_ROW_COLUMNS),
                              "times": ("trials_times.csv", TIME_COLUMNS)}

    def units(self) -> list[tuple[int, int]]:
        return [(i, t) for i in range(len(self.points)) for t in range(self.trials)]

    def run_unit(self, unit: tuple[int, int]) -> dict[str, list[dict]]:
        point_index, trial = unit
        rows, times = split_times(gyro_trial_rows(self, self.points[point_index], trial),
                                  "trial")
        return {"trials": rows, "times": times}

    def summarize(self, out_dir: Path | str) -> pd.DataFrame:
        """Write and return ``summary.csv`` from ``trials.csv``."""
        summary = summarize_gyro(read_trials(Path(out_dir) / "trials.csv"))
        write_csv_atomic(summary, Path(out_dir) / "summary.csv")
        return summary


def draw_trajectory(rng: np.random.Generator, spec: GyroStudy,
                    point: GyroPoint) -> Trajectory:
    """The trial's distortion, gyro bias and manoeuvre (drawn in that order)."""
    alpha = rng.uniform(*spec.alpha)
    E = rng.uniform(-spec.beta, spec.beta, size=(3, 3))
    h = rng.uniform(-spec.gamma, spec.gamma, size=3)
    bias = rng.uniform(-spec.gyro_bias_max, spec.gyro_bias_max, size=3)
    settings = dict(spec.coverages[point.coverage])
    if "axis_weights" in settings:
        settings["axis_weights"] = tuple(settings["axis_weights"])
    return simulate(rng, rate_hz=spec.rate_hz, duration_s=spec.duration_s,
                    T=alpha * np.eye(3) + 0.5 * (E + E.T), h=h, mag_noise=point.sigma,
                    gyro_noise=point.gyro_noise, gyro_bias=bias, **settings)


def _fit(name: str, traj: Trajectory) -> Callable[[dict], Calibration]:
    """How a method is called on a manoeuvre: gyro-aided ones also get rate and time (and
    MagFactor3 the true attitude and field, which it takes as inputs)."""
    spec = get_method(name)
    extra: dict = {}
    if spec.needs_gyro:
        extra = {"angular_rate": traj.angular_rate, "time": traj.t}
        if "attitude" in spec.option_names() and traj.R is not None:
            extra.update(attitude=traj.R, reference_field=traj.m0)

    def fit(options: dict) -> Calibration:
        return calibrate(traj.y, name, raw=True, **{**extra, **options})

    return fit


def gyro_trial_rows(spec: GyroStudy, point: GyroPoint, trial: int) -> list[dict]:
    """Every selected method on one simulated manoeuvre; one row per method."""
    traj = draw_trajectory(rng(spec.seed, point.key, trial), spec, point)
    J0 = trivial_cost(traj.T, traj.h)
    base = {"coverage": point.coverage, "gyro_noise": point.gyro_noise, "sigma": point.sigma,
            "K": traj.y.shape[0], "trial": int(trial), "seed": int(spec.seed), "J0": J0,
            **truth_columns(traj.T, traj.h),
            **dict(zip(_WB_TRUE, traj.gyro_bias.tolist(), strict=True))}
    rows = []
    for name in spec.algorithms:
        out = run_method(name, _fit(name, traj), options=spec.options.get(name) or {},
                         seed=spec.seed, stream=(point.key, trial),
                         call_timeout_s=spec.call_timeout_s)
        J, J_h, J_T = (accuracy_cost(out.T, out.h, traj.T, traj.h) if out.calibration
                       else (np.nan, np.nan, np.nan))
        wb = out.calibration.gyro_bias if out.calibration is not None else None
        wb = np.full(3, np.nan) if wb is None else np.asarray(wb)
        J_wb = float(np.linalg.norm(wb - traj.gyro_bias)) if np.all(np.isfinite(wb)) \
            else np.nan
        rows.append({**base, "algorithm": name, "gyro": get_method(name).needs_gyro,
                     "ok": out.ok, "error": out.error, "time_s": out.time_s,
                     "n_iter": out.n_iter, "J": J, "J_h": J_h, "J_T": J_T, "J_wb": J_wb,
                     "meaningful": bool(np.isfinite(J) and J < spec.delta * J0),
                     **estimate_columns(out.T, out.h),
                     **dict(zip(_WB, wb.tolist(), strict=True))})
    return rows


def summarize_gyro(trials: pd.DataFrame) -> pd.DataFrame:
    """RB %, rho, tau per (point, algorithm) (eqs. 77-79), plus median J, J_h and gyro-bias
    error over the runs that returned an estimate."""
    by = GYRO_POINT_COLUMNS + ["algorithm"]
    summary = summarize(trials, by)
    extra = trials.groupby(by, sort=False).agg(
        median_J=("J", "median"), median_J_h=("J_h", "median"),
        median_J_wb=("J_wb", "median"), n_ok=("ok", "sum")).reset_index()
    return summary.merge(extra, on=by, how="left")
