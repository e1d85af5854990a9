"""The gyro sweep: gyro-aided and magnetometer-only methods on simulated manoeuvres.

Each trial simulates one manoeuvre (:mod:`magbench.sources.trajectory`) with a drawn distortion
and gyro bias, and runs every selected method on the same magnetometer samples;
gyro-aided methods also get the gyro samples and times (and MagFactor3 the true attitude and field).
Points are the grid of gyro noise levels and coverages (named simulator settings). One row per
(point, trial, method), with the columns of :func:`magbench.runner.run_trial` plus the gyro bias.

The distortion is ``T = alpha I + (E + E^T) / 2`` (symmetric: the magnetometer's axes are the
gyro's, as SAR and MAGYC assume; the review's non-symmetric ``E`` would add a magnetometer-gyro
misalignment none of them models) and ``h = e``, with alpha, E, e drawn as in eq. (68).

``python -m magbench sweep=gyro [sweep.trials=10] [n_jobs=2]`` runs it;
:func:`gyro_report_section` turns its results into Markdown.
"""

from __future__ import annotations

import sys
import time as _time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic, write_text_atomic
from magbench.core.metrics import accuracy_cost, summarize, trivial_cost
from magbench.core.model import CalibrationFailed
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method, methods
from magbench.sources.trajectory import Trajectory, simulate
from magbench.studies.review import TRUTH_COLUMNS

__all__ = ["GYRO_POINT_COLUMNS", "GyroPoint", "GyroSweepSpec", "gyro_report_section",
           "run_gyro_methods_on_recording", "run_gyro_sweep", "run_gyro_trial"]

GYRO_POINT_COLUMNS = ["coverage", "gyro_noise", "sigma"]
_T_COLUMNS = [f"T_{i}{j}" for i in range(3) for j in range(3)]
_H_COLUMNS = [f"h_{i}" for i in range(3)]
_WB_TRUE = [f"wb_true_{i}" for i in range(3)]
_WB = [f"wb_{i}" for i in range(3)]
GYRO_ROW_COLUMNS = (GYRO_POINT_COLUMNS + ["K", "trial", "seed", "algorithm", "gyro", "ok",
                                          "error", "time_s", "n_iter", "J", "J_h", "J_T", "J0",
                                          "meaningful", "J_wb"]
                    + TRUTH_COLUMNS + _H_COLUMNS + _T_COLUMNS + _WB_TRUE + _WB)

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
class GyroSweepSpec:
    """Everything that determines the gyro sweep's numbers.

    Attributes
    ----------
    points : sequence of GyroPoint
    trials, seed : int
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
    """

    points: Sequence[GyroPoint]
    trials: int = 50
    seed: int = 2021
    algorithms: Sequence[str] = ()
    options: dict = field(default_factory=dict)
    coverages: dict = field(default_factory=lambda: dict(DEFAULT_COVERAGES))
    rate_hz: float = 25.0
    duration_s: float = 24.0
    beta: float = 0.05
    gamma: float = 0.05
    alpha: tuple[float, float] = (0.8, 1.2)
    gyro_bias_max: float = 0.02
    delta: float = 0.5


def draw_trajectory(rng: np.random.Generator, spec: GyroSweepSpec,
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


def _method_rng(seed: int, point: GyroPoint, trial: int, name: str) -> np.random.Generator:
    ss = np.random.SeedSequence(int(seed), spawn_key=(point.key, int(trial),
                                                      zlib.crc32(name.encode())))
    return np.random.default_rng(ss)


def _evaluate(name: str, traj: Trajectory, y: np.ndarray, opts: dict) -> dict:
    """Run one method and measure it; failures become a reason in ``error``."""
    spec = get_method(name)
    kwargs = dict(opts)
    if spec.needs_gyro:
        kwargs.update(angular_rate=traj.angular_rate, time=traj.t)
        if "attitude" in spec.option_names() and traj.R is not None:
            kwargs.setdefault("attitude", traj.R)
            kwargs.setdefault("reference_field", traj.m0)
    T = h = wb = None
    n_iter, error, J, J_h, J_T = 0, "", np.nan, np.nan, np.nan
    start = _time.perf_counter()
    try:
        cal = calibrate(y, name, **kwargs)
        elapsed = _time.perf_counter() - start
        T, h, n_iter, wb = cal.T, cal.h, cal.n_iter, cal.gyro_bias
        if traj.T is not None:
            J, J_h, J_T = accuracy_cost(T, h, traj.T, traj.h)
        if not cal.converged:
            error = cal.message
    except (CalibrationFailed, ValueError, ArithmeticError) as exc:
        elapsed = _time.perf_counter() - start
        error = f"{type(exc).__name__}: {exc}"
    T = np.full((3, 3), np.nan) if T is None else T
    h = np.full(3, np.nan) if h is None else h
    wb = np.full(3, np.nan) if wb is None else np.asarray(wb)
    J_wb = (float(np.linalg.norm(wb - traj.gyro_bias))
            if traj.gyro_bias is not None and np.all(np.isfinite(wb)) else np.nan)
    return {"algorithm": name, "gyro": spec.needs_gyro, "ok": not error, "error": error,
            "time_s": elapsed, "n_iter": n_iter, "J": J, "J_h": J_h, "J_T": J_T, "J_wb": J_wb,
            **dict(zip(_H_COLUMNS, h.tolist(), strict=True)),
            **dict(zip(_T_COLUMNS, T.ravel().tolist(), strict=True)),
            **dict(zip(_WB, wb.tolist(), strict=True))}


def run_gyro_trial(spec: GyroSweepSpec, point: GyroPoint, trial: int) -> list[dict]:
    """Every selected method on one simulated manoeuvre; one row per method."""
    rng = np.random.default_rng(np.random.SeedSequence(int(spec.seed),
                                                       spawn_key=(point.key, int(trial))))
    traj = draw_trajectory(rng, spec, point)
    J0 = trivial_cost(traj.T, traj.h)
    base = {"coverage": point.coverage, "gyro_noise": point.gyro_noise, "sigma": point.sigma,
            "K": traj.y.shape[0], "trial": int(trial), "seed": int(spec.seed), "J0": J0,
            **dict(zip(TRUTH_COLUMNS[:3], traj.h.tolist(), strict=True)),
            **dict(zip(TRUTH_COLUMNS[3:], traj.T.ravel().tolist(), strict=True)),
            **dict(zip(_WB_TRUE, traj.gyro_bias.tolist(), strict=True))}
    rows = []
    for name in spec.algorithms:
        opts = dict(spec.options.get(name) or {})
        if get_method(name).randomized:
            opts["rng"] = _method_rng(spec.seed, point, trial, name)
        row = {**base, **_evaluate(name, traj, traj.y, opts)}
        row["meaningful"] = bool(np.isfinite(row["J"]) and row["J"] < spec.delta * J0)
        rows.append(row)
    return rows


def _run_chunk(spec: GyroSweepSpec, point_index: int, trials: range) -> list[dict]:
    point = spec.points[point_index]
    return [row for trial in trials for row in run_gyro_trial(spec, point, trial)]


def summarize_gyro(trials: pd.DataFrame) -> pd.DataFrame:
    """RB %, rho, tau per (point, algorithm) (eqs. 77-79), plus median J, J_h and gyro-bias
    error over the runs that returned an estimate."""
    by = GYRO_POINT_COLUMNS + ["algorithm"]
    summary = summarize(trials, by)
    extra = trials.groupby(by, sort=False).agg(
        median_J=("J", "median"), median_J_h=("J_h", "median"),
        median_J_wb=("J_wb", "median"), n_ok=("ok", "sum")).reset_index()
    return summary.merge(extra, on=by, how="left")


def run_gyro_sweep(spec: GyroSweepSpec, out_dir: Path | str, *, n_jobs: int = 1,
                   chunk_size: int = 10, progress=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run the sweep; write ``trials.csv``, ``summary.csv`` and the figure under ``out_dir``.

    Chunks of trials run under joblib; results are written once, atomically, at the end (a
    full sweep takes about a minute, so there are no part files to resume from).
    """
    from joblib import Parallel, delayed

    out_dir = Path(out_dir)
    tasks = [(i, range(s, min(s + chunk_size, spec.trials)))
             for i in range(len(spec.points)) for s in range(0, spec.trials, chunk_size)]
    results: dict[tuple[int, int], list[dict]] = {}
    with Parallel(n_jobs=n_jobs, return_as="generator") as parallel:
        for (i, r), rows in zip(tasks, parallel(delayed(_run_chunk)(spec, i, r)
                                                for i, r in tasks), strict=True):
            results[(i, r.start)] = rows
            if progress is not None:
                progress(len(r))
    rows = [row for i, r in tasks for row in results[(i, r.start)]]
    trials = pd.DataFrame(rows, columns=GYRO_ROW_COLUMNS)
    summary = summarize_gyro(trials)
    write_csv_atomic(trials, out_dir / "trials.csv")
    write_csv_atomic(summary, out_dir / "summary.csv")
    write_gyro_figure(summary, out_dir)
    return trials, summary


def figure_table(summary: pd.DataFrame) -> pd.DataFrame:
    """What the figure plots: median J per coverage, gyro noise and algorithm."""
    return summary[["coverage", "gyro_noise", "algorithm", "median_J", "RB_pct"]].copy()


def write_gyro_figure(summary: pd.DataFrame, out_dir: Path) -> Path:
    """``gyro_J.png`` (median J against gyro noise, one panel per coverage) and
    ``gyro_J.csv``, the numbers plotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = figure_table(summary)
    write_csv_atomic(table, out_dir / "gyro_J.csv")
    coverages = list(dict.fromkeys(table["coverage"]))
    gyro = {m for m in methods() if get_method(m).needs_gyro}
    # Two rows, so 20-odd lines stay readable: gyro-aided methods on top, the magnetometer-only
    # methods (same samples) below; each row has its own legend outside the axes.
    fig, axes = plt.subplots(2, len(coverages), figsize=(4.2 * len(coverages) + 3.2, 7.6),
                             sharey=True, squeeze=False, layout="constrained")
    colours = plt.get_cmap("tab20").colors
    for row, (title, members) in enumerate([("gyro-aided", gyro), ("magnetometer only", None)]):
        for ax, cov in zip(axes[row], coverages, strict=True):
            sub = table[table["coverage"] == cov]
            names = [n for n in dict.fromkeys(sub["algorithm"])
                     if (n in gyro) == (members is not None)]
            for i, name in enumerate(names):
                grp = sub[sub["algorithm"] == name]
                x = grp["gyro_noise"].to_numpy()
                # Noise 0 cannot sit on a log axis: plot it at a tenth of the smallest level.
                pos = x[x > 0]
                x = np.where(x > 0, x, (pos.min() / 10) if pos.size else 1e-4)
                ax.plot(x, grp["median_J"], marker="osD^v<>phX*P"[i % 12],
                        color=colours[i % len(colours)], linestyle="-" if row == 0 else "--",
                        label=get_method(name).label)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title(f"{title}, coverage: {cov}")
            ax.set_xlabel("gyro noise std (rad/s; leftmost = 0)")
            ax.grid(True, which="both", alpha=0.3)
        axes[row][0].set_ylabel("median J (74)")
        if axes[row][-1].get_legend_handles_labels()[0]:
            axes[row][-1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    path = out_dir / "gyro_J.png"
    tmp = path.with_name(f".tmp-{path.name}")
    fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    tmp.replace(path)
    return path


def gyro_report_section(results_dir: Path | str) -> str:
    """Markdown for the report: median J (RB %) per method and coverage at the lowest non-zero
    gyro noise, median gyro-bias error, and the figure. Reads only ``<results_dir>/gyro``."""
    path = Path(results_dir) / "gyro" / "summary.csv"
    if not path.exists():
        return "## Gyro-aided calibration\n\nNo results yet: run `python -m magbench sweep=gyro`.\n"
    s = pd.read_csv(path)
    levels = sorted(s["gyro_noise"].unique())
    level = next((g for g in levels if g > 0), levels[0])
    sub = s[s["gyro_noise"] == level]
    coverages = list(dict.fromkeys(sub["coverage"]))
    order = list(dict.fromkeys(sub["algorithm"]))
    lines = ["## Gyro-aided calibration (simulated manoeuvres)", "",
             f"Median J (eq. 74) and, in brackets, RB % (eq. 77) at gyro noise {level:g} rad/s "
             f"and magnetometer noise {sub['sigma'].iloc[0]:g}; gyro-bias error |d - d_true| "
             "(rad/s, median) for the methods that estimate it. Gyro-aided methods are marked *."
             " SAR methods and MagFactor3 estimate no soft iron (T = I, T = s I), so their J "
             "includes the whole soft-iron error; MAGYC-LS and SAR assume an unbiased gyro.", "",
             "| method | " + " | ".join(coverages) + " | gyro bias error |",
             "|---|" + "---|" * (len(coverages) + 1)]
    for name in order:
        cells = []
        for cov in coverages:
            r = sub[(sub["algorithm"] == name) & (sub["coverage"] == cov)]
            cells.append(f"{r['median_J'].iloc[0]:.2e} ({r['RB_pct'].iloc[0]:.0f})"
                         if len(r) else "-")
        wb = sub[sub["algorithm"] == name]["median_J_wb"]
        wb_text = f"{wb.median():.1e}" if wb.notna().any() else "-"
        try:
            spec = get_method(name)
            label = spec.label + (" *" if spec.needs_gyro else "")
        except ValueError:
            label = name
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {wb_text} |")
    lines += ["", "![median J against gyro noise](gyro/gyro_J.png) "
              "(numbers: `gyro/gyro_J.csv`)", ""]
    return "\n".join(lines)


def run_gyro_methods_on_recording(y: np.ndarray, w: np.ndarray, t: np.ndarray,
                                  algorithms: Sequence[str] | None = None,
                                  options: dict | None = None) -> list[dict]:
    """Every gyro-aided method on a real recording; one row per method.

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        Magnetometer samples (any unit).
    w : ndarray, shape (K, 3)
        Gyro samples in rad/s, already in the magnetometer's axes.
    t : ndarray, shape (K,)
        Sample times in seconds.
    algorithms : sequence of str, optional
        Default: every registered gyro-aided method except MagFactor3 (it needs an attitude).

    Returns
    -------
    list of dict
        ``algorithm, ok, error, time_s, n_iter, h_*, T_*, wb_*`` (no truth, so no J; compute
        J_r of eq. 81 from ``T`` and ``h`` with :func:`magbench.core.metrics.real_cost`).
    """
    names = list(algorithms) if algorithms is not None else [
        m for m in methods() if get_method(m).needs_gyro and m != "magfactor3"]
    traj = Trajectory(t=np.asarray(t, float), y=np.asarray(y, float),
                      angular_rate=np.asarray(w, float), w=None, R=None, m=None, m0=None,
                      T=None, h=None, gyro_bias=None)
    rows = []
    for name in names:
        row = _evaluate(name, traj, traj.y, dict((options or {}).get(name) or {}))
        for key in ("J", "J_h", "J_T", "J_wb"):
            row.pop(key)
        rows.append(row)
    return rows


def spec_from_config(cfg) -> tuple[GyroSweepSpec, Path, int]:
    """The sweep spec, output folder and n_jobs from the composed Hydra config (checked)."""
    from omegaconf import OmegaConf

    from magbench.cli import UsageError, selected_algorithms

    sweep = cfg.sweep
    coverages = OmegaConf.to_container(sweep.get("coverages"), resolve=True) or dict(
        DEFAULT_COVERAGES)
    chosen = list(sweep.get("coverage") or coverages)
    unknown = [c for c in chosen if c not in coverages]
    if unknown:
        raise UsageError(f"unknown coverage(s) {', '.join(unknown)}; defined: "
                         f"{', '.join(coverages)}")
    noises = [float(g) for g in (sweep.get("gyro_noise") or [0.0])]
    if any(not (g >= 0 and np.isfinite(g)) for g in noises):
        raise UsageError(f"sweep.gyro_noise values must be >= 0, got {noises}")
    trials = int(sweep.get("trials") or cfg.trials)
    if trials < 1:
        raise UsageError(f"sweep.trials must be >= 1, got {trials}")
    # 'all' here means every method, gyro-aided ones included (the static sweeps exclude them).
    algorithms = methods() if cfg.algorithms == "all" else selected_algorithms(cfg)
    options = OmegaConf.to_container(cfg.options, resolve=True) or {}
    for name, opts in options.items():
        if name not in algorithms:
            raise UsageError(f"options given for {name!r}, which is not among the selected "
                             "algorithms")
        bad = sorted(set(opts or {}) - set(get_method(name).option_names()))
        if bad:
            raise UsageError(f"unknown option(s) {', '.join(bad)} for {name}")
    sigma = float(cfg.nominal.sigma)
    points = [GyroPoint(c, g, sigma) for c in chosen for g in noises]
    spec = GyroSweepSpec(points=points, trials=trials, seed=int(cfg.seed),
                         algorithms=algorithms, options={k: dict(v or {}) for k, v in
                                                         options.items()},
                         coverages=coverages, rate_hz=float(sweep.get("rate_hz", 25.0)),
                         duration_s=float(sweep.get("duration_s", 24.0)),
                         beta=float(cfg.nominal.beta), gamma=float(cfg.nominal.gamma),
                         alpha=(float(cfg.nominal.alpha[0]), float(cfg.nominal.alpha[1])),
                         gyro_bias_max=float(sweep.get("gyro_bias_max", 0.02)),
                         delta=float(cfg.delta))
    n_jobs = int(cfg.n_jobs)
    return spec, Path(str(cfg.results_dir)) / str(sweep.name), n_jobs


def run_gyro_command(cfg) -> int:
    """``python -m magbench sweep=gyro``: run the gyro sweep and write its files."""
    from tqdm import tqdm

    spec, out_dir, n_jobs = spec_from_config(cfg)
    with tqdm(total=spec.trials * len(spec.points), desc="sweep gyro", unit="trial",
              disable=not cfg.progress, file=sys.stderr) as bar:
        trials, _ = run_gyro_sweep(spec, out_dir, n_jobs=n_jobs, progress=bar.update)
    write_text_atomic(gyro_report_section(out_dir.parent), out_dir / "section.md")
    n_bad = int((~trials["ok"].astype(bool)).sum())
    print(f"sweep gyro: {len(trials)} rows ({n_bad} not ok) -> {out_dir}/trials.csv, "
          "summary.csv, gyro_J.png")
    return 0
