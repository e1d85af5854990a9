"""The speed study: ``python -m magbench bench`` or ``make bench``.

Measures, never assumes: the median and spread of one calibration call per method at the
nominal setting, the scaling with K, peers on the same datasets where they are installed, and
the parallel speed-up of a sweep. Unit tests never time anything; this module is where timing
lives. Results go to ``<results_dir>/bench/`` (figure: :mod:`magbench.figures.speed`; report
text: :mod:`magbench.report.speed`).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.core.metrics import accuracy_cost
from magbench.engine.sweep import run_study
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method, methods
from magbench.sources.synthetic import Point, make_dataset
from magbench.studies.review import ReviewStudy

__all__ = ["SIZES", "bench_calibrate", "bench_calls", "bench_first_calls", "bench_parallel",
           "bench_peers", "run_bench"]

SIZES = (50, 150, 300, 1000, 3000, 10000)


def _datasets(K: int, n: int, seed: int) -> list:
    return [make_dataset(np.random.default_rng([seed, K, i]), Point(K=K)) for i in range(n)]


def _time_call(fn: Callable[[], object], repeats: int) -> np.ndarray:
    fn()  # warm-up: first-call imports and caches are not the method's cost
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return np.asarray(times)


def _safe_call(name: str, y: np.ndarray) -> Callable[[], object]:
    def call() -> object:
        try:
            return calibrate(y, name)
        except Exception as exc:  # a failing dataset still costs time; keep measuring
            return exc
    return call


def bench_calls(names: Sequence[str], sizes: Sequence[int] = SIZES, datasets: int = 5,
                repeats: int = 5, seed: int = 0, budget_s: float = 20.0,
                progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Time ``calibrate`` per method and K: ``datasets`` datasets x ``repeats`` calls each.

    A method whose calls at one K take more than ``budget_s`` in total is not timed at larger K
    (the row says so) so one slow method cannot stall the benchmark.
    """
    rows = []
    for name in names:
        skip = False
        for K in sizes:
            if skip or K < get_method(name).min_samples:
                rows.append({"algorithm": name, "K": K, "n": 0, "median_s": np.nan,
                             "q25_s": np.nan, "q75_s": np.nan, "min_s": np.nan,
                             "note": "skipped (time budget)" if skip else "K below minimum"})
                continue
            start = time.perf_counter()
            t = np.concatenate([_time_call(_safe_call(name, d.y), repeats)
                                for d in _datasets(K, datasets, seed)])
            rows.append({"algorithm": name, "K": K, "n": t.size, "median_s": np.median(t),
                         "q25_s": np.quantile(t, 0.25), "q75_s": np.quantile(t, 0.75),
                         "min_s": t.min(), "note": ""})
            skip = time.perf_counter() - start > budget_s
            if progress:
                progress(f"{name} K={K}: median {np.median(t) * 1e3:.3g} ms")
    return pd.DataFrame(rows)


#: Run in a fresh interpreter by :func:`bench_first_calls`: import time, then the first and the
#: second call of one method on one nominal K = 300 dataset, in seconds.
_FIRST_CALL = """
import sys, time
import numpy as np
start = time.perf_counter()
import magbench.methods.algorithms
from magbench.methods.api import calibrate
from magbench.sources.synthetic import Point, make_dataset
imported = time.perf_counter()
y = make_dataset(np.random.default_rng(0), Point(K=300)).y
times = []
for _ in range(2):
    t = time.perf_counter()
    try:
        calibrate(y, sys.argv[1])
    except Exception:
        pass
    times.append(time.perf_counter() - t)
print(imported - start, times[0], times[1])
"""


def bench_first_calls(names: Sequence[str],
                      progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """First-call cost per method: the numba compilation that the steady-state medians exclude.

    Each method runs in two fresh interpreters sharing a numba cache folder that starts empty:
    the first compiles the method's loops (``compile_s``, what a machine pays once after
    installing or changing the code), the second loads them from the on-disk cache
    (``cached_first_s``, what every sweep worker pays once). ``import_s`` is the import of the
    methods (numba included); ``second_s`` is the following, steady-state call.
    """
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            env["NUMBA_CACHE_DIR"] = str(Path(tmp) / name)
            row: dict[str, object] = {"algorithm": name}
            for column in ("compile_s", "cached_first_s"):
                out = subprocess.run([sys.executable, "-c", _FIRST_CALL, name], env=env,
                                     capture_output=True, text=True, check=True)
                imported, first, second = (float(v) for v in out.stdout.split()[-3:])
                row[column] = first
            row["import_s"], row["second_s"] = imported, second
            rows.append(row)
            if progress:
                progress(f"{name}: first call {row['compile_s'] * 1e3:.4g} ms with an empty "
                         f"numba cache, {row['cached_first_s'] * 1e3:.4g} ms cached, then "
                         f"{second * 1e3:.3g} ms")
    return pd.DataFrame(rows)


# --- peers: measuring sticks only, imported here and nowhere else -----------------------------

def _normalise(T: np.ndarray, h: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Rescale T so the calibrated samples have unit mean norm (for scale-free peers)."""
    m = np.linalg.solve(T, (y - h).T)
    return T * float(np.mean(np.linalg.norm(m, axis=0)))


def _navlib_twostep(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_twostep_hsi

    hard_iron, soft_iron = cal_mag_twostep_hsi(y, np.array([1.0, 0.0, 0.0]))[:2]
    return np.asarray(soft_iron), np.asarray(hard_iron).ravel()  # navlib's soft_iron is T


def _navlib_fang(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_ellipsoid_fit_fang

    hard_iron, soft_iron = cal_mag_ellipsoid_fit_fang(y)[:2]
    h = np.asarray(hard_iron).ravel()
    return _normalise(np.asarray(soft_iron), h, y), h


def _magcal_ellipsoid(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from magcal.core import MagnetometerCalibrator

    params = MagnetometerCalibrator.ellipsoid_fit(None, y)
    h = np.asarray(params["center"]).ravel()
    # magcal applies m = W (y - c), so its matrix is T^-1, normalised: invert and rescale.
    return _normalise(np.linalg.inv(params["transform_matrix"]), h, y), h


PEERS = {  # peer -> (package, function, magbench method it is paired with)
    "navlib.cal_mag_twostep_hsi": ("navlib", _navlib_twostep, "twostep"),
    "navlib.cal_mag_ellipsoid_fit_fang": ("navlib", _navlib_fang, "fang"),
    "magcal.ellipsoid_fit": ("magcal", _magcal_ellipsoid, "ellipsoid"),
}


def bench_peers(datasets: int = 20, repeats: int = 3, seed: int = 0) -> pd.DataFrame:
    """Each installed peer against its magbench counterpart on the same nominal datasets."""
    rows = []
    data = _datasets(300, datasets, seed)
    registered = set(methods())
    for peer, (package, fn, ours) in PEERS.items():
        if importlib.util.find_spec(package) is None or ours not in registered:
            rows.append({"peer": peer, "magbench": ours, "note": f"{package} not installed"
                         if ours in registered else f"{ours} not registered"})
            continue
        t_peer, t_ours, J_peer, J_ours, failures = [], [], [], [], 0
        for d in data:
            try:
                T, h = fn(d.y)
                J_peer.append(accuracy_cost(T, h, d.T, d.h)[0])
            except Exception:
                failures += 1
            cal = calibrate(d.y, ours)
            J_ours.append(accuracy_cost(cal.T, cal.h, d.T, d.h)[0])
            t_peer.append(np.median(_time_call(lambda y=d.y, f=fn: f(y), repeats)))
            t_ours.append(np.median(_time_call(lambda y=d.y, o=ours: calibrate(y, o), repeats)))
        rows.append({"peer": peer, "magbench": ours, "peer_median_s": np.median(t_peer),
                     "magbench_median_s": np.median(t_ours),
                     "speedup": np.median(t_peer) / np.median(t_ours),
                     "peer_mean_J": np.mean(J_peer) if J_peer else np.nan,
                     "magbench_mean_J": np.mean(J_ours), "peer_failures": failures,
                     "note": ""})
    return pd.DataFrame(rows)


def bench_parallel(trials: int = 250, algorithms: Sequence[str] | None = None,
                   workdir: Path | None = None) -> pd.DataFrame:
    """Wall-clock time of one sweep with 1 and with 2 workers, and the speed-up."""
    spec = ReviewStudy("bench_parallel", [Point()], trials, 0, list(algorithms or methods()))
    rows = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for n_jobs in (1, 2):
            start = time.perf_counter()
            run_study(spec, Path(tmp) / f"n{n_jobs}", n_jobs=n_jobs, chunk_size=10,
                      progress=False)
            rows.append({"n_jobs": n_jobs, "wall_s": time.perf_counter() - start,
                         "trials": trials, "methods": len(spec.algorithms)})
    out = pd.DataFrame(rows)
    out["speedup"] = out["wall_s"].iloc[0] / out["wall_s"]
    return out


def bench_calibrate(K: int = 10_000, repeats: int = 3, seed: int = 0) -> pd.DataFrame:
    """Wall time of ``python -m magbench calibrate`` with the default settings (picture
    included) on a ``K``-sample synthetic recording with a counts-sized offset.

    Each run is a fresh interpreter after one warm-up run (which fills the numba cache):
    ``process_s`` is the whole process (interpreter, imports, Hydra's config), ``command_s``
    what the command itself reports (reading, fitting, choosing, writing and drawing).
    """
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    rng = np.random.default_rng(seed)
    m = rng.standard_normal((K, 3))
    m /= np.linalg.norm(m, axis=1)[:, None]
    y = m @ np.array([[520.0, 20.0, -8.0], [0.0, 470.0, 15.0], [0.0, 0.0, 610.0]]).T
    y += np.array([900.0, -350.0, 120.0]) + 3.0 * rng.standard_normal((K, 3))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "synthetic.csv"
        pd.DataFrame(y, columns=["mx", "my", "mz"]).assign(t=np.arange(K) * 0.01).to_csv(
            path, index=False)
        command = [sys.executable, "-m", "magbench", "calibrate", f"file={path}",
                   f"out={Path(tmp) / 'out'}", "progress=false"]
        for run in range(repeats + 1):
            start = time.perf_counter()
            out = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
            wall = time.perf_counter() - start
            if run:     # the first run is the warm-up
                reported = float(out.stdout.rsplit("(in ", 1)[1].split(" s)")[0])
                rows.append({"K": K, "run": run, "process_s": wall, "command_s": reported})
    return pd.DataFrame(rows)


def run_bench(results_dir: Path | str, names: Sequence[str] | None = None,
              sizes: Sequence[int] = SIZES, parallel_trials: int = 250,
              progress: Callable[[str], None] | None = print) -> Path:
    """Run every benchmark and write ``calls.csv``, ``first_calls.csv``, ``peers.csv``,
    ``calibrate.csv`` and ``parallel.csv`` under ``<results_dir>/bench``."""
    folder = Path(results_dir) / "bench"
    folder.mkdir(parents=True, exist_ok=True)
    names = list(names or [m for m in methods() if not get_method(m).needs_gyro])
    write_csv_atomic(bench_first_calls(names, progress=progress), folder / "first_calls.csv")
    calls = bench_calls(names, sizes, progress=progress)
    write_csv_atomic(calls, folder / "calls.csv")
    write_csv_atomic(bench_peers(), folder / "peers.csv")
    write_csv_atomic(cal := bench_calibrate(), folder / "calibrate.csv")
    if progress:
        progress(f"calibrate on {cal['K'].iloc[0]} samples (default settings, picture "
                 f"included): median {cal['command_s'].median():.2f} s in the command, "
                 f"{cal['process_s'].median():.2f} s for the whole process")
    if parallel_trials:
        write_csv_atomic(bench_parallel(parallel_trials, names), folder / "parallel.csv")
    return folder
