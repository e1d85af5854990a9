"""Monte Carlo trials and their fan-out over workers, with incremental, atomic result files.

A *trial* draws one dataset (seeded from base seed, point and trial index) and runs every
selected method on it, yielding one row per method. Trials are grouped into *chunks*; each
finished chunk is written at once as its own part file (temporary file, then rename), so a
killed sweep loses at most the chunks in flight, and a restarted one runs only what is missing.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.api import calibrate, get_method
from magbench.metrics import accuracy_cost, summarize, trivial_cost
from magbench.model import CalibrationFailed
from magbench.synthetic import Point, make_dataset, trial_seed_sequence

__all__ = ["POINT_COLUMNS", "SweepSpec", "run_sweep", "run_trial", "write_csv_atomic"]

POINT_COLUMNS = ["K", "sigma", "beta", "gamma"]
_T_COLUMNS = [f"T_{i}{j}" for i in range(3) for j in range(3)]
_H_COLUMNS = [f"h_{i}" for i in range(3)]
TRUTH_COLUMNS = [f"h_true_{i}" for i in range(3)] + [f"T_true_{i}{j}" for i in range(3)
                                                      for j in range(3)]
ROW_COLUMNS = (POINT_COLUMNS + ["trial", "seed", "algorithm", "ok", "error", "time_s", "n_iter",
                                "J", "J_h", "J_T", "J0", "meaningful"]
               + TRUTH_COLUMNS + _H_COLUMNS + _T_COLUMNS)


@dataclass(frozen=True)
class SweepSpec:
    """Everything that determines a sweep's numbers (and nothing that does not).

    Attributes
    ----------
    name : str
        Sweep name; results go to ``<results_dir>/<name>/``.
    points : sequence of Point
        The settings, in the order they are reported.
    trials : int
        Datasets per point.
    seed : int
        Base seed of every random stream.
    algorithms : sequence of str
        Registered method names; all see the same dataset in a trial.
    options : dict
        Per-method keyword options, ``{method: {option: value}}``.
    delta : float
        Robustness threshold of eq. (76), in (0, 1).
    """

    name: str
    points: Sequence[Point]
    trials: int
    seed: int
    algorithms: Sequence[str]
    options: dict = field(default_factory=dict)
    delta: float = 0.5

    def fingerprint(self) -> str:
        """Hash of the spec: part files from a run with another spec are never reused."""
        text = json.dumps({**asdict(self), "points": [asdict(p) for p in self.points]},
                          sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _method_rng(seed: int, point: Point, trial: int, name: str) -> np.random.Generator:
    # Keyed by the method's name, so a method's stream does not depend on which others run.
    ss = np.random.SeedSequence(int(seed), spawn_key=(point.key, int(trial),
                                                      zlib.crc32(name.encode())))
    return np.random.default_rng(ss)


def _estimate_columns(T: np.ndarray | None, h: np.ndarray | None) -> dict:
    T = np.full((3, 3), np.nan) if T is None else T
    h = np.full(3, np.nan) if h is None else h
    return {**dict(zip(_H_COLUMNS, h.tolist(), strict=True)),
            **dict(zip(_T_COLUMNS, T.ravel().tolist(), strict=True))}


def run_trial(point: Point, trial: int, seed: int, algorithms: Sequence[str],
              options: dict | None = None, delta: float = 0.5) -> list[dict]:
    """Run every method on the trial's dataset; one row per method, failures included.

    Only the :func:`magbench.calibrate` call is timed. A method that raises, returns a
    non-finite answer or stops at its iteration cap gets ``ok=False`` and the reason in
    ``error``; ``meaningful`` is eq. (76), ``J < delta * J0``, wherever an estimate exists.
    """
    options = options or {}
    data = make_dataset(np.random.default_rng(trial_seed_sequence(seed, point, trial)), point)
    J0 = trivial_cost(data.T, data.h)
    base = {"K": point.K, "sigma": point.sigma, "beta": point.beta, "gamma": point.gamma,
            "trial": int(trial), "seed": int(seed)}
    truth = {**dict(zip(TRUTH_COLUMNS[:3], data.h.tolist(), strict=True)),
             **dict(zip(TRUTH_COLUMNS[3:], data.T.ravel().tolist(), strict=True))}
    rows = []
    for name in algorithms:
        opts = dict(options.get(name) or {})
        if get_method(name).randomized:
            opts["rng"] = _method_rng(seed, point, trial, name)
        T = h = None
        n_iter, error, J, J_h, J_T = 0, "", np.nan, np.nan, np.nan
        start = time.perf_counter()
        try:
            cal = calibrate(data.y, name, **opts)
            elapsed = time.perf_counter() - start
            T, h, n_iter = cal.T, cal.h, cal.n_iter
            J, J_h, J_T = accuracy_cost(T, h, data.T, data.h)
            if not cal.converged:
                error = cal.message
        except (CalibrationFailed, ValueError, ArithmeticError) as exc:
            elapsed = time.perf_counter() - start
            error = f"{type(exc).__name__}: {exc}"
        rows.append({**base, "algorithm": name, "ok": not error, "error": error,
                     "time_s": elapsed, "n_iter": n_iter, "J": J, "J_h": J_h, "J_T": J_T,
                     "J0": J0, "meaningful": bool(np.isfinite(J) and J < delta * J0),
                     **truth, **_estimate_columns(T, h)})
    return rows


def _run_chunk(spec: SweepSpec, point_index: int, trials: range) -> tuple[int, int, list[dict]]:
    point = spec.points[point_index]
    rows = [row for trial in trials
            for row in run_trial(point, trial, spec.seed, spec.algorithms, spec.options,
                                 spec.delta)]
    return point_index, trials.start, rows


def write_csv_atomic(frame: pd.DataFrame, path: Path) -> None:
    """Write a CSV next to its destination, then rename it into place (atomic on POSIX)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    frame.to_csv(tmp, index=False)
    os.replace(tmp, path)


def write_text_atomic(text: str, path: Path) -> None:
    """Write text to a temporary file beside ``path``, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    tmp.write_text(text)
    os.replace(tmp, path)


def _prepare_parts_dir(out_dir: Path, spec: SweepSpec) -> Path:
    """The folder of finished chunks; emptied when it belongs to a different spec."""
    parts = out_dir / "parts"
    manifest = parts / "manifest.json"
    fingerprint = spec.fingerprint()
    if manifest.exists() and json.loads(manifest.read_text()).get("fingerprint") != fingerprint:
        shutil.rmtree(parts)
    if not manifest.exists():
        parts.mkdir(parents=True, exist_ok=True)
        write_text_atomic(json.dumps({"fingerprint": fingerprint, "sweep": spec.name}), manifest)
    return parts


def run_sweep(spec: SweepSpec, out_dir: Path | str, *, n_jobs: int = 1, chunk_size: int = 25,
              progress: Callable[[int], None] | None = None,
              parallel_backend: str = "loky") -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run (or finish) a sweep and write ``trials.csv`` and ``summary.csv`` under ``out_dir``.

    Parameters
    ----------
    spec : SweepSpec
        What to run.
    out_dir : path
        ``<results_dir>/<sweep name>``; holds ``parts/`` while the sweep is unfinished.
    n_jobs : int
        joblib workers (1 runs in this process; -1 uses every core).
    chunk_size : int
        Trials per task: large enough that worker start-up and data transfer are small next to
        the work, small enough that a kill loses little.
    progress : callable, optional
        Called with the number of trials each finished chunk adds (a progress bar's update).
    parallel_backend : str
        joblib backend name (``"loky"``, or ``"dask"`` with a registered client).

    Returns
    -------
    trials, summary : DataFrame
        The rows of ``trials.csv`` and ``summary.csv``.
    """
    from joblib import Parallel, delayed

    out_dir = Path(out_dir)
    parts = _prepare_parts_dir(out_dir, spec)
    tasks = [(i, range(s, min(s + chunk_size, spec.trials)))
             for i in range(len(spec.points)) for s in range(0, spec.trials, chunk_size)]

    def part_path(point_index: int, start: int) -> Path:
        return parts / f"p{spec.points[point_index].key:08x}-t{start:06d}.csv"

    todo = [t for t in tasks if not part_path(t[0], t[1].start).exists()]
    if progress is not None:
        progress(sum(len(r) for _, r in tasks) - sum(len(r) for _, r in todo))
    if todo:
        with Parallel(n_jobs=n_jobs, backend=parallel_backend,
                      return_as="generator_unordered") as parallel:
            for point_index, start, rows in parallel(delayed(_run_chunk)(spec, i, r)
                                                     for i, r in todo):
                write_csv_atomic(pd.DataFrame(rows, columns=ROW_COLUMNS),
                                 part_path(point_index, start))
                if progress is not None:
                    progress(len({row["trial"] for row in rows}))
    frame = pd.concat([pd.read_csv(part_path(i, r.start), dtype={"error": "string"})
                       for i, r in tasks], ignore_index=True)
    # Task order is point order then trial order, and a chunk's rows are trial-major in the
    # order of spec.algorithms: the concatenation is already canonical, whatever finished first.
    trials = frame.assign(error=frame["error"].fillna(""))
    summary = summarize(trials, POINT_COLUMNS + ["algorithm"])
    write_csv_atomic(trials, out_dir / "trials.csv")
    write_csv_atomic(summary, out_dir / "summary.csv")
    shutil.rmtree(parts)
    return trials, summary


def points_for(nominal: Point, vary: str | None, values: Iterable[float]) -> list[Point]:
    """The sweep's points: the nominal point with one parameter set to each value in turn."""
    if not vary:
        return [nominal]
    if vary not in POINT_COLUMNS:
        raise ValueError(f"cannot sweep {vary!r}; expected one of {', '.join(POINT_COLUMNS)}")
    out = []
    for v in values:
        fields = asdict(nominal)
        fields[vary] = int(v) if vary == "K" else float(v)
        out.append(Point(**fields))
    return out
