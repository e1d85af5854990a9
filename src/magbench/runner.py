"""Monte Carlo trials and their fan-out over workers, with incremental, atomic result files.

A *trial* draws one dataset (seeded from base seed, point and trial index) and runs every
selected method on it, yielding one row per method. Trials are grouped into *chunks*; each
finished chunk is written at once as its own part file (temporary file, then rename), so a
killed sweep loses at most the chunks in flight, and a restarted one runs only what is missing.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import os
import shutil
import signal
import threading
import time
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.crb import crb_mse, efficient_expected_J
from magbench.core.metrics import accuracy_cost, summarize, trivial_cost
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method
from magbench.sources.synthetic import Point, make_dataset, trial_seed_sequence

__all__ = ["POINT_COLUMNS", "SweepSpec", "run_sweep", "run_trial", "write_csv_atomic"]

POINT_COLUMNS = ["K", "sigma", "beta", "gamma", "cap_deg", "band_deg"]
_T_COLUMNS = [f"T_{i}{j}" for i in range(3) for j in range(3)]
_H_COLUMNS = [f"h_{i}" for i in range(3)]
TRUTH_COLUMNS = [f"h_true_{i}" for i in range(3)] + [f"T_true_{i}{j}" for i in range(3)
                                                      for j in range(3)]
ROW_COLUMNS = (POINT_COLUMNS + ["trial", "seed", "algorithm", "ok", "error", "time_s", "n_iter",
                                "J", "J_h", "J_T", "J0", "meaningful", "sq_err", "crb", "crb_J"]
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
    call_timeout_s : float or None
        Time limit of one calibration call; a call past it becomes a row with ``ok=False``.
    plugins : sequence of str
        Modules imported in every worker before it runs (they register extra methods).
    """

    name: str
    points: Sequence[Point]
    trials: int
    seed: int
    algorithms: Sequence[str]
    options: dict = field(default_factory=dict)
    delta: float = 0.5
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()

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


class CallTimeout(Exception):
    """A calibration call ran past ``call_timeout_s``."""


@contextlib.contextmanager
def time_limit(seconds: float | None):
    """Raise :class:`CallTimeout` in the block once ``seconds`` have passed.

    Uses a real-time interval timer, so it works where the work runs in the main thread of its
    process (in-process runs and joblib's process workers). Elsewhere (threads, such as a Dask
    worker's) no limit can be imposed safely and the block runs unlimited.
    """
    if not seconds or threading.current_thread() is not threading.main_thread():
        yield
        return

    def expire(signum, frame):
        raise CallTimeout(f"call exceeded call_timeout_s = {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def load_plugins(modules: Iterable[str]) -> None:
    """Import modules that register extra methods (a user's own, or the tests' faulty ones)."""
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise ValueError(f"cannot import plugin module {name!r}: {exc}") from None


def run_trial(point: Point, trial: int, seed: int, algorithms: Sequence[str],
              options: dict | None = None, delta: float = 0.5,
              call_timeout_s: float | None = None) -> list[dict]:
    """Run every method on the trial's dataset; one row per method, failures included.

    Only the :func:`magbench.calibrate` call is timed. A method that raises (anything but a
    programming error in the harness), returns a non-finite answer, runs past
    ``call_timeout_s`` or stops at its iteration cap gets ``ok=False`` and the reason in
    ``error``; ``meaningful`` is eq. (76), ``J < delta * J0``, wherever an estimate exists.
    """
    options = options or {}
    data = make_dataset(np.random.default_rng(trial_seed_sequence(seed, point, trial)), point)
    J0 = trivial_cost(data.T, data.h)
    # Cramer-Rao bound on E[J_h^2 + J_T^2] and E[J] of an efficient estimator (crb.py).
    bound = {"crb": crb_mse(data.T, data.h, data.m, point.sigma).total,
             "crb_J": efficient_expected_J(data.T, data.m, point.sigma)}
    base = {**{c: getattr(point, c) for c in POINT_COLUMNS},
            "trial": int(trial), "seed": int(seed)}
    truth = {**dict(zip(TRUTH_COLUMNS[:3], data.h.tolist(), strict=True)),
             **dict(zip(TRUTH_COLUMNS[3:], data.T.ravel().tolist(), strict=True))}
    rows = []
    for name in algorithms:
        opts = dict(options.get(name) or {})
        spec = get_method(name)
        if spec.randomized:
            opts["rng"] = _method_rng(seed, point, trial, name)
        if "sigma" in spec.option_names() and "sigma" not in opts and point.sigma > 0:
            # Methods that weight by an assumed noise level (TWOSTEP's and the EKF's eq. 5)
            # are told the true one, as the review assumes ("sigma_k^2 ... similar to the
            # measurement's output error variance").
            opts["sigma"] = point.sigma
        T = h = None
        n_iter, error, J, J_h, J_T = 0, "", np.nan, np.nan, np.nan
        start = time.perf_counter()
        try:
            with time_limit(call_timeout_s):
                cal = calibrate(data.y, name, **opts)
            elapsed = time.perf_counter() - start
            T, h, n_iter = cal.T, cal.h, cal.n_iter
            J, J_h, J_T = accuracy_cost(T, h, data.T, data.h)
            if not cal.converged:
                error = cal.message
        except Exception as exc:
            elapsed = time.perf_counter() - start
            error = f"{type(exc).__name__}: {exc}"
        rows.append({**base, "algorithm": name, "ok": not error, "error": error,
                     "time_s": elapsed, "n_iter": n_iter, "J": J, "J_h": J_h, "J_T": J_T,
                     "J0": J0, "meaningful": bool(np.isfinite(J) and J < delta * J0),
                     "sq_err": J_h ** 2 + J_T ** 2, **bound,
                     **truth, **_estimate_columns(T, h)})
    return rows


def _run_chunk(spec: SweepSpec, point_index: int, trials: range) -> tuple[int, int, list[dict]]:
    load_plugins(spec.plugins)
    point = spec.points[point_index]
    rows = [row for trial in trials
            for row in run_trial(point, trial, spec.seed, spec.algorithms, spec.options,
                                 spec.delta, spec.call_timeout_s)]
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


@contextlib.contextmanager
def parallel_engine(backend: str, n_jobs: int, scheduler_address: str | None = None):
    """joblib arguments for ``backend``, with a Dask client open for ``"dask"``.

    ``"loky"`` runs worker processes on this machine. ``"dask"`` sends the tasks to the Dask
    cluster at ``scheduler_address`` or, when that is None, to a ``LocalCluster`` of ``n_jobs``
    single-threaded worker processes bound to 127.0.0.1.
    """
    if backend == "loky":
        yield {"backend": "loky", "n_jobs": n_jobs}
        return
    if backend != "dask":
        raise ValueError(f"backend must be 'loky' or 'dask', got {backend!r}")
    from distributed import Client, LocalCluster
    from joblib import parallel_config

    with contextlib.ExitStack() as stack:
        if scheduler_address:
            client = stack.enter_context(Client(scheduler_address))
        else:
            cluster = stack.enter_context(LocalCluster(
                n_workers=max(n_jobs, 1), threads_per_worker=1, processes=True,
                host="127.0.0.1", dashboard_address=None))
            client = stack.enter_context(Client(cluster))
        stack.enter_context(parallel_config(backend="dask"))
        yield {"n_jobs": -1, "client": client}


def run_sweep(spec: SweepSpec, out_dir: Path | str, *, n_jobs: int = 1, chunk_size: int = 25,
              progress: Callable[[int], None] | None = None, backend: str = "loky",
              scheduler_address: str | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
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
    backend : str
        ``"loky"`` (processes on this machine) or ``"dask"`` (see :func:`parallel_engine`).
    scheduler_address : str, optional
        Dask scheduler to use with ``backend="dask"``; a local cluster when None.

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
    load_plugins(spec.plugins)
    if todo:
        with parallel_engine(backend, n_jobs, scheduler_address) as engine, \
                Parallel(n_jobs=engine["n_jobs"], backend=engine.get("backend"),
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
    return [point_with(nominal, {vary: v}) for v in values]


def point_with(nominal: Point, changes: dict) -> Point:
    """The nominal point with some parameters (from POINT_COLUMNS) changed."""
    unknown = sorted(set(changes) - set(POINT_COLUMNS))
    if unknown:
        raise ValueError(f"cannot set {', '.join(unknown)}; a point has "
                         f"{', '.join(POINT_COLUMNS)}")
    fields = asdict(nominal)
    fields.update({k: int(v) if k == "K" else float(v) for k, v in changes.items()})
    return Point(**fields)
