"""The speed study: ``python -m magbench bench`` or ``make bench``.

Measures, never assumes: the median and spread of one calibration call per method at the
nominal setting, the scaling with K, peers on the same datasets where they are installed, and
the parallel speed-up of a sweep. Unit tests never time anything; this module is where timing
lives. Results go to ``<results_dir>/bench/`` (figure: :mod:`magbench.figures.speed`; report
text: :mod:`magbench.report.speed`).
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic
from magbench.core.metrics import accuracy_cost
from magbench.engine.isolation import map_supervised
from magbench.engine.plugins import plugin_modules
from magbench.engine.sweep import run_study
from magbench.engine.trial import run_method
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method, methods
from magbench.pipeline.fitting import DEFAULT_MAX_SAMPLES
from magbench.sources.recordings import data_dir
from magbench.sources.synthetic import Point, make_dataset
from magbench.studies.peer_accuracy import peer_accuracy, summarize_peer_accuracy
from magbench.studies.peer_agreement import peer_agreement, summarize_peer_agreement
from magbench.studies.peers import PEER_FITS
from magbench.studies.review import ReviewStudy

__all__ = ["ADDED_METHOD", "ADDED_PLUGIN", "SIZES", "added_method_seconds", "bench_calibrate",
           "bench_calibrate_files", "bench_calls", "bench_first_calls", "bench_parallel",
           "bench_peers", "bench_reproduce", "calls_seconds",
           "format_reproduce_times", "peer_install_size", "reproduce_times", "rounds_won",
           "run_bench", "synthetic_recording"]

SIZES = (50, 150, 300, 1000, 3000, 10000)


def _datasets(K: int, n: int, seed: int) -> list:
    return [make_dataset(np.random.default_rng([seed, K, i]), Point(K=K)) for i in range(n)]


def blas_threads() -> str:
    """The BLAS thread setting the timings ran with (``OPENBLAS_NUM_THREADS``, else
    ``OMP_NUM_THREADS``, else ``"default"``: as many as cores)."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        if os.environ.get(var):
            return os.environ[var]
    return "default"


def _time_call(fn: Callable[[], object], repeats: int) -> np.ndarray:
    fn()  # warm-up: first-call imports and caches are not the method's cost
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return np.asarray(times)


def _method_times(name: str, y: np.ndarray, repeats: int,
                  call_timeout_s: float | None = None) -> tuple[np.ndarray, str]:
    """Wall times of ``repeats`` calls of method ``name`` on ``y`` after one untimed warm-up,
    each through the trial loop (a failing call still costs time; keep measuring), and the
    reason when the supervision skipped the method (it ended or seized its process here).
    The clock is read around the method alone, never around the supervision's messages."""
    def call():
        return run_method(name, lambda o: calibrate(y, name, raw=True, **o),
                          call_timeout_s=call_timeout_s)

    times = []
    for k in range(repeats + 1):
        out = call()
        if out.skipped:
            return np.full(repeats, np.nan), out.error
        if k:                                   # the first call is the warm-up
            times.append(out.time_s)
    return np.asarray(times), ""


def _calls_of(name: str, sizes: Sequence[int], datasets: int, repeats: int, seed: int,
              budget_s: float, call_timeout_s: float | None) -> list[dict]:
    """:func:`bench_calls`' rows of one method (a unit of :func:`map_supervised`)."""
    rows, skip = [], False
    for K in sizes:
        if skip or K < get_method(name).min_samples:
            rows.append({"algorithm": name, "K": K, "n": 0, "median_s": np.nan,
                         "q25_s": np.nan, "q75_s": np.nan, "min_s": np.nan,
                         "note": "skipped (time budget)" if skip else "K below minimum"})
            continue
        start = time.perf_counter()
        timed = [_method_times(name, d.y, repeats, call_timeout_s)
                 for d in _datasets(K, datasets, seed)]
        reason = next((why for _, why in timed if why), "")
        if reason:      # it ended or seized its process at this K: the row says so
            rows.append({"algorithm": name, "K": K, "n": 0, "median_s": np.nan,
                         "q25_s": np.nan, "q75_s": np.nan, "min_s": np.nan, "note": reason})
            continue
        t = np.concatenate([times for times, _ in timed])
        rows.append({"algorithm": name, "K": K, "n": t.size, "median_s": np.median(t),
                     "q25_s": np.quantile(t, 0.25), "q75_s": np.quantile(t, 0.75),
                     "min_s": t.min(), "note": ""})
        skip = time.perf_counter() - start > budget_s
    return rows


def bench_calls(names: Sequence[str], sizes: Sequence[int] = SIZES, datasets: int = 5,
                repeats: int = 5, seed: int = 0, budget_s: float = 20.0,
                progress: Callable[[str], None] | None = None,
                call_timeout_s: float | None = None) -> pd.DataFrame:
    """Time ``calibrate`` per method and K: ``datasets`` datasets x ``repeats`` calls each.

    A method whose calls at one K take more than ``budget_s`` in total is not timed at larger K
    (the row says so) so one slow method cannot stall the benchmark. The calls run in a
    supervised child process, as a sweep's trials do
    (:func:`magbench.engine.isolation.map_supervised`): a method that ends or seizes its
    process gives a row whose ``note`` says why, and the benchmark goes on; a call past
    ``call_timeout_s`` is a failed call, and one that holds its process past that limit's hard
    end (:func:`magbench.engine.isolation.hard_limit`) a row saying so.
    """
    work = functools.partial(_calls_of, sizes=tuple(sizes), datasets=datasets,
                             repeats=repeats, seed=seed, budget_s=budget_s,
                             call_timeout_s=call_timeout_s)
    rows = []
    for name in names:
        method_rows = map_supervised(work, [name], name="bench",
                                     plugins=plugin_modules([name]))[0]
        rows += method_rows
        for row in method_rows if progress else []:
            if row["n"]:
                progress(f"{name} K={row['K']}: median {row['median_s'] * 1e3:.3g} ms")
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
        calibrate(y, sys.argv[1], raw=True)
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
    methods, which no longer imports numba: numba is imported by the first call of a compiled
    loop (``methods/algorithms/_jit.py``), so for a numba method both first-call columns include
    numba's import (~0.1 s). ``second_s`` is the following, steady-state call.
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
                                     capture_output=True, text=True, check=False)
                if out.returncode != 0:     # the method ended its interpreter: a row says so
                    row.update(dict.fromkeys(("compile_s", "cached_first_s", "import_s",
                                              "second_s"), np.nan))
                    row["note"] = f"interpreter ended with exit status {out.returncode}"
                    break
                imported, first, second = (float(v) for v in out.stdout.split()[-3:])
                row[column] = first
            else:
                row["import_s"], row["second_s"], row["note"] = imported, second, ""
            rows.append(row)
            if progress and not row["note"]:
                progress(f"{name}: first call {row['compile_s'] * 1e3:.4g} ms with an empty "
                         f"numba cache, {row['cached_first_s'] * 1e3:.4g} ms cached, then "
                         f"{second * 1e3:.3g} ms")
    return pd.DataFrame(rows)


# --- peers: measuring sticks only (magbench.studies.peers adapts them) ------------------------

#: The peers timed and compared here: peer -> (package, function, magbench method it is
#: paired with), from :data:`magbench.studies.peers.PEER_FITS` (one adapter per peer).
PEERS = {name: PEER_FITS[name] for name in ("navlib.cal_mag_twostep_hsi",
                                            "navlib.cal_mag_ellipsoid_fit_fang",
                                            "magcal.ellipsoid_fit")}


#: magbench's side of the calibrate comparison: the candidate ``calibrate`` would keep.
BEST = "best"

#: The peers' install cost is counted over these distributions and everything they require
#: that magbench itself does not.
PEER_PACKAGES = ("navlib", "magcal")


def _requirement_closure(names: Sequence[str]) -> set[str]:
    """The installed distributions ``names`` need, themselves included (normalised names);
    environment markers other than extras are not evaluated (a platform-only requirement is
    counted if it is installed)."""
    from importlib import metadata
    from re import split

    todo, seen = [n.lower().replace("_", "-") for n in names], set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        seen.add(name)
        todo += [split(r"[ ;<>=!~\[(]", r, maxsplit=1)[0].lower().replace("_", "-")
                 for r in requires if "extra ==" not in r]
    return seen


def peer_install_size() -> pd.DataFrame:
    """Installed size of each peer and of what it adds to a magbench installation.

    ``own_mb`` is the peer's own files; ``added_mb`` and ``added_packages`` count it with every
    distribution it requires that magbench (with its default dependencies) does not; NaN for a
    peer that is not installed.
    """
    from importlib import metadata

    ours = _requirement_closure(["magbench"])
    rows = []
    for package in PEER_PACKAGES:
        try:
            version = metadata.version(package)
        except metadata.PackageNotFoundError:
            rows.append({"package": package, "version": "", "own_mb": np.nan,
                         "added_mb": np.nan, "added_packages": np.nan})
            continue
        added = sorted(_requirement_closure([package]) - ours)

        def size_mb(name: str) -> float:
            files = metadata.distribution(name).files or []
            return sum(f.locate().stat().st_size for f in files if f.locate().exists()) / 1e6

        rows.append({"package": package, "version": version, "own_mb": size_mb(package),
                     "added_mb": sum(size_mb(n) for n in added),
                     "added_packages": len(added), "added": " ".join(added)})
    return pd.DataFrame(rows)


def _best_candidate(y: np.ndarray, candidates: Sequence[str],
                    call_timeout_s: float | None = None) -> str:
    """The candidate with the smallest RMS field-magnitude residual on ``y``: the ranking of
    ``calibrate`` (in sample, meaningful fits alike) without its held-out split."""
    best, best_r = candidates[0], np.inf
    for name in candidates:
        out = run_method(name, lambda o, n=name: calibrate(y, n, raw=True, **o),
                         call_timeout_s=call_timeout_s)
        if out.calibration is None:
            continue
        r = float(np.sqrt(np.mean((np.linalg.norm(out.calibration.apply(y), axis=1) - 1.0)
                                  ** 2)))
        if r < best_r:
            best, best_r = name, r
    return best


def bench_peers(sizes: Sequence[int] = (300, 10000), datasets: int = 20, repeats: int = 3,
                seed: int = 0, large_datasets: int = 5,
                call_timeout_s: float | None = None) -> pd.DataFrame:
    """Each installed peer against magbench on the same nominal datasets, per K.

    Two rows per peer and K: against its counterpart (same algorithm, same samples), and
    against ``best``, what ``python -m magbench calibrate`` does with such a recording: it
    thins it to at most :data:`~magbench.pipeline.fitting.DEFAULT_MAX_SAMPLES` samples (every
    ``ceil(K / 2000)``-th) and keeps the method with the smallest magnitude residual among the
    non-variant, gyro-free ones (chosen here on the first dataset of each K, timed on all).
    The 10 000-sample row of ``best`` is the user-facing comparison; the peers fit
    every sample. K above 1000 uses ``large_datasets`` datasets. A peer that is not installed
    gives one row per K saying so (``pip install 'magbench[peers]'``).
    """
    candidates = [m for m in methods() if get_method(m).family != "variant"
                  and get_method(m).magnetometer_only]
    work = functools.partial(_peers_at, datasets=datasets, repeats=repeats, seed=seed,
                             large_datasets=large_datasets, candidates=tuple(candidates),
                             call_timeout_s=call_timeout_s)
    per_size = map_supervised(work, list(sizes), name="bench peers",
                              plugins=plugin_modules(candidates))
    return pd.DataFrame([row for rows in per_size for row in rows])


def _peers_at(K: int, *, datasets: int, repeats: int, seed: int, large_datasets: int,
              candidates: Sequence[str], call_timeout_s: float | None) -> list[dict]:
    """:func:`bench_peers`' rows at one K (a unit of :func:`map_supervised`)."""
    rows = []
    registered = set(methods())
    data = _datasets(K, datasets if K <= 1000 else large_datasets, seed)
    stride = math.ceil(K / DEFAULT_MAX_SAMPLES)                      # calibrate's thinning
    best = _best_candidate(data[0].y[::stride], candidates, call_timeout_s)
    for peer, (package, fn, counterpart) in PEERS.items():
        if importlib.util.find_spec(package) is None or counterpart not in registered:
            rows.append({"peer": peer, "K": K, "magbench": counterpart,
                         "note": f"{package} not installed (pip install 'magbench[peers]')"
                         if counterpart in registered else f"{counterpart} not registered"})
            continue
        for ours in (counterpart, BEST):
            name, step = (best, stride) if ours == BEST else (ours, 1)
            t_peer, t_ours, J_peer, J_ours, failures = [], [], [], [], 0
            for d in data:
                try:
                    T, h = fn(d.y)
                    J_peer.append(accuracy_cost(T, h, d.T, d.h)[0])
                except Exception:
                    failures += 1
                out = run_method(name, lambda o, y=d.y[::step], n=name:
                                 calibrate(y, n, raw=True, **o), call_timeout_s=call_timeout_s)
                J_ours.append(accuracy_cost(out.T, out.h, d.T, d.h)[0]
                              if out.T is not None else np.nan)
                t_peer.append(np.median(_time_call(lambda y=d.y, f=fn: f(y), repeats)))
                t_ours.append(np.median(_method_times(name, d.y[::step], repeats,
                                                      call_timeout_s)[0]))
            rows.append({"peer": peer, "K": K, "magbench": name,
                         "peer_median_s": np.median(t_peer),
                         "magbench_median_s": np.median(t_ours),
                         "speedup": np.median(t_peer) / np.median(t_ours),
                         "peer_mean_J": np.mean(J_peer) if J_peer else np.nan,
                         "magbench_mean_J": np.mean(J_ours), "peer_failures": failures,
                         "magbench_samples": K // step + (K % step > 0),
                         "note": f"calibrate's choice, 1 sample in {step}"
                         if ours == BEST else ""})
    return rows


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


#: The peers' side of the end-to-end comparison: what a user of each library runs on a file
#: (read it, fit, save the correction), as a fresh interpreter like ``magbench calibrate``.
#: ``{fit}`` must leave the correction's matrix in ``M`` and offset in ``c``. Its arguments:
#: the CSV file, the JSON file to write and the 0-based positions of mx, my, mz ("1,2,3").
PEER_SCRIPT = """import json, sys
import numpy as np
{imports}
y = np.loadtxt(sys.argv[1], delimiter=",", skiprows=1,
               usecols=[int(c) for c in sys.argv[3].split(",")])
{fit}
json.dump({{"M": np.asarray(M).tolist(), "c": np.asarray(c).ravel().tolist()}},
          open(sys.argv[2], "w"))
"""
PEER_FILE_FITS = {  # peer -> (package, imports, fit lines)
    "navlib.cal_mag_ellipsoid_fit_fang": (
        "navlib", "from navlib.cal.cal_mag import cal_mag_ellipsoid_fit_fang",
        "c, M = cal_mag_ellipsoid_fit_fang(y)[:2]"),
    "navlib.cal_mag_twostep_hsi": (
        "navlib", "from navlib.cal.cal_mag import cal_mag_twostep_hsi",
        "c, M = cal_mag_twostep_hsi(y, np.array([1.0, 0.0, 0.0]))[:2]"),
    "magcal.ellipsoid_fit": (
        "magcal", "from magcal.core import MagnetometerCalibrator",
        "p = MagnetometerCalibrator.ellipsoid_fit(None, y)\n"
        "M, c = p['transform_matrix'], p['center']"),
}

#: The tool whose rounds against each peer are counted, and the same without the picture
#: (``picture=false``: the correction and its files only).
MAGBENCH_TOOL = "magbench calibrate"
MAGBENCH_NO_PICTURE = "magbench calibrate picture=false"
MAGBENCH_TOOLS = (MAGBENCH_TOOL, MAGBENCH_NO_PICTURE)


def _timed_run(command: list[str], env: dict) -> tuple[float, float, str]:
    """Wall time, CPU time (user + system of the process and the processes it waited for)
    and stdout of one run of ``command``."""
    import resource

    def children() -> float:
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        return usage.ru_utime + usage.ru_stime

    cpu, start = children(), time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    return time.perf_counter() - start, children() - cpu, done.stdout


def synthetic_recording(path: Path, K: int, seed: int = 0) -> Path:
    """Write a ``K``-sample synthetic recording (``mx, my, mz, t``) with a counts-sized offset
    and scale, as a magnetometer logger would, to ``path``; returns ``path``."""
    rng = np.random.default_rng(seed)
    m = rng.standard_normal((K, 3))
    m /= np.linalg.norm(m, axis=1)[:, None]
    y = m @ np.array([[520.0, 20.0, -8.0], [0.0, 470.0, 15.0], [0.0, 0.0, 610.0]]).T
    y += np.array([900.0, -350.0, 120.0]) + 3.0 * rng.standard_normal((K, 3))
    pd.DataFrame(y, columns=["mx", "my", "mz"]).assign(t=np.arange(K) * 0.01).to_csv(
        path, index=False)
    return path


def bench_calibrate(K: int = 10_000, repeats: int = 10, seed: int = 0,
                    path: Path | str | None = None) -> pd.DataFrame:
    """Wall time from file to written correction: ``python -m magbench calibrate`` with the
    default settings (picture included) and each installed peer library, on the CSV file
    ``path`` (a header naming ``mx, my, mz``) or, without one, on a ``K``-sample synthetic
    recording (:func:`synthetic_recording`).

    Every run is a fresh interpreter: ``process_s`` is the whole process (interpreter,
    imports, configuration, reading, fitting, writing), ``cpu_s`` its CPU time with its child
    processes' (magbench's picture process), ``command_s`` what ``calibrate`` itself reports
    (reading, fitting, choosing, writing and drawing). A peer's process is the least a user of
    it runs (:data:`PEER_SCRIPT`): NumPy's ``loadtxt``, one fit, the matrix and offset saved
    as JSON; no choice, verdict, exports or picture. Each tool runs once as a warm-up (filling
    the numba and bytecode caches: ``PYTHONDONTWRITEBYTECODE`` is unset for the runs, as an
    installed package has its bytecode), then the tools take turns ``repeats`` times, so that
    a machine that slows down mid-way slows every tool alike; ``load_1min`` is the load
    average as each round starts, ``cpu_model`` and ``cpu_count`` the machine's.
    """
    from importlib.util import find_spec

    from magbench.engine.record import cpu_model

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if path is None:
            path, name = synthetic_recording(Path(tmp) / "synthetic.csv", K, seed), "synthetic"
        else:
            path = Path(path)
            name = f"{path.parent.name}/{path.name}" if path.name == "data.csv" else path.name
        with open(path) as handle:
            header = [c.strip() for c in handle.readline().split(",")]
            K = sum(1 for line in handle if line.strip())
        usecols = ",".join(str(header.index(c)) for c in ("mx", "my", "mz"))
        ours = [sys.executable, "-m", "magbench", "calibrate", f"file={path}",
                f"out={Path(tmp) / 'out'}", "progress=false", "overwrite=true"]
        tools = {MAGBENCH_TOOL: ours, MAGBENCH_NO_PICTURE: [*ours, "picture=false"]}
        for peer, (package, imports, fit) in PEER_FILE_FITS.items():
            if find_spec(package) is not None:
                script = PEER_SCRIPT.format(imports=imports, fit=fit)
                tools[peer] = [sys.executable, "-c", script, str(path),
                               str(Path(tmp) / "peer.json"), usecols]
        for command in tools.values():
            _timed_run(command, env)                              # warm-up
        machine = {"cpu_model": cpu_model(), "cpu_count": os.cpu_count()}
        for run in range(1, repeats + 1):
            load = os.getloadavg()[0]
            for tool, command in tools.items():
                wall, cpu, stdout = _timed_run(command, env)
                reported = (float(stdout.rsplit("(in ", 1)[1].split(" s)")[0])
                            if tool in MAGBENCH_TOOLS else np.nan)
                rows.append({"tool": tool, "file": name, "K": K, "run": run,
                             "process_s": wall, "cpu_s": cpu, "command_s": reported,
                             "load_1min": load, **machine})
    return pd.DataFrame(rows)


def rounds_won(table: pd.DataFrame) -> pd.DataFrame:
    """Per recording, magbench variant (:data:`MAGBENCH_TOOLS`) and peer of a
    :func:`bench_calibrate` table: the rounds in which the variant took less wall time than
    the peer, the rounds run and both medians."""
    table = table if "file" in table else table.assign(file="synthetic")
    rows = []
    for (name, K), runs in table.groupby(["file", "K"], sort=False):
        peers = runs[~runs["tool"].isin(MAGBENCH_TOOLS)]
        for variant in MAGBENCH_TOOLS:
            ours = runs[runs["tool"] == variant].set_index("run")["process_s"]
            if ours.empty:
                continue
            for tool, peer in peers.groupby("tool", sort=False):
                ahead = ours.reindex(peer["run"]).to_numpy() < peer["process_s"].to_numpy()
                rows.append({"file": name, "K": K, "magbench": variant, "peer": tool,
                             "won": int(ahead.sum()), "rounds": len(peer),
                             "magbench_median_s": ours.median(),
                             "peer_median_s": peer["process_s"].median()})
    return pd.DataFrame(rows)


#: The recordings of the file-to-correction comparison: a real one from ``$MAGBENCH_DATA``
#: (skipped when absent) and synthetic ones of these sizes.
CALIBRATE_RECORDING = "qmc5883l_filtered"
CALIBRATE_SIZES = (10_000, 100_000)


def bench_calibrate_files(repeats: int = 10, data: Path | str | None = None) -> pd.DataFrame:
    """:func:`bench_calibrate` on each synthetic size of :data:`CALIBRATE_SIZES` and on the real
    recording :data:`CALIBRATE_RECORDING` of ``data`` (default ``$MAGBENCH_DATA``) when it is
    there, in one table (``file`` tells them apart)."""
    tables = [bench_calibrate(K=K, repeats=repeats) for K in CALIBRATE_SIZES]
    folder = data if data is not None else os.environ.get("MAGBENCH_DATA")
    real = Path(folder) / CALIBRATE_RECORDING / "data.csv" if folder else None
    if real is not None and real.is_file():
        tables.insert(0, bench_calibrate(path=real, repeats=repeats))
    return pd.concat(tables, ignore_index=True)


def malloc_thresholds() -> str:
    """glibc's malloc thresholds the timings ran with, from the environment that
    ``python -m magbench`` sets (:mod:`magbench.cli.process`): ``"mmap <a>, trim <b>"`` in
    bytes, or ``"default"`` (glibc's 128 KiB, adjusted as it goes)."""
    mmap, trim = (os.environ.get(v) for v in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"))
    return f"mmap {mmap or 'default'}, trim {trim or 'default'}" if mmap or trim else "default"


def _data_root() -> Path | None:
    """The real recordings' folder, None when it is not configured or absent."""
    try:
        root = data_dir()
    except (ValueError, OSError):
        return None
    return root if root.is_dir() else None


def run_bench(results_dir: Path | str, names: Sequence[str] | None = None,
              sizes: Sequence[int] = SIZES, parallel_trials: int = 250,
              progress: Callable[[str], None] | None = print,
              peer_datasets: int = 200, reproduce: bool = True,
              call_timeout_s: float | None = None) -> Path:
    """Run every benchmark and write ``calls.csv``, ``first_calls.csv``, ``peers.csv``,
    ``peer_accuracy.csv`` and ``peer_accuracy_summary.csv`` (``peer_datasets`` datasets per
    geometry, 0 = none; :mod:`magbench.studies.peer_accuracy`), ``peer_agreement.csv`` and
    ``peer_agreement_summary.csv`` (with the peer accuracy;
    :mod:`magbench.studies.peer_agreement`), ``peer_install.csv``,
    ``calibrate.csv``, ``parallel.csv`` and, with ``reproduce``, ``reproduce_cases.csv``
    (:func:`bench_reproduce`) under ``<results_dir>/bench``."""
    folder = Path(results_dir) / "bench"
    folder.mkdir(parents=True, exist_ok=True)
    names = list(names or [m for m in methods() if get_method(m).magnetometer_only])
    threads = blas_threads()
    if threads != "1" and progress:
        # BLAS threads wake up for every call above a size threshold, which looks like
        # nonlinear growth with K (docs/decisions.md, "One BLAS thread").
        progress(f"warning: BLAS threads {threads!r}, not 1: large-K timings include thread "
                 "start-up (python -m magbench sets 1 unless OPENBLAS_NUM_THREADS is set)")
    malloc = malloc_thresholds()
    if malloc == "default" and progress:
        # glibc's defaults hand large arrays back to the kernel after every call: at K = 10 000
        # the NumPy-heavy methods took 1.4-1.6x longer, growing faster than K
        progress("warning: glibc's default malloc thresholds: large-K timings include page "
                 "faults (python -m magbench sets MALLOC_MMAP_THRESHOLD_ and "
                 "MALLOC_TRIM_THRESHOLD_)")
    write_csv_atomic(bench_first_calls(names, progress=progress), folder / "first_calls.csv")
    calls = bench_calls(names, sizes, progress=progress, call_timeout_s=call_timeout_s)
    calls["blas_threads"] = threads
    calls["malloc"] = malloc
    write_csv_atomic(calls, folder / "calls.csv")
    write_csv_atomic(bench_peers(call_timeout_s=call_timeout_s), folder / "peers.csv")
    if peer_datasets:
        accuracy = peer_accuracy(PEERS, datasets=peer_datasets)
        write_csv_atomic(accuracy, folder / "peer_accuracy.csv")
        write_csv_atomic(summarize_peer_accuracy(accuracy), folder / "peer_accuracy_summary.csv")
        # every reimplemented peer function beside magbench's (one row per missing peer)
        agreement = peer_agreement(data_root=_data_root())
        write_csv_atomic(agreement, folder / "peer_agreement.csv")
        write_csv_atomic(summarize_peer_agreement(agreement),
                         folder / "peer_agreement_summary.csv")
    write_csv_atomic(peer_install_size(), folder / "peer_install.csv")
    write_csv_atomic(cal := bench_calibrate_files(), folder / "calibrate.csv")
    if progress:
        for row in rounds_won(cal).itertuples(index=False):
            progress(f"file to correction, {row.file} ({row.K} samples): magbench calibrate "
                     f"median {row.magbench_median_s:.2f} s, {row.peer} "
                     f"{row.peer_median_s:.2f} s; magbench faster in {row.won} of "
                     f"{row.rounds} rounds")
    if parallel_trials:
        write_csv_atomic(bench_parallel(parallel_trials, names), folder / "parallel.csv")
    if reproduce:
        write_csv_atomic(bench_reproduce(data_dir=os.environ.get("MAGBENCH_DATA"),
                                         progress=progress), folder / "reproduce_cases.csv")
    return folder


# --- a new method in seconds: first run, full reproduce, one method added ----------------------

#: The plugin the incremental case adds to a finished reproduce: Fang's fit under a new name.
ADDED_PLUGIN = """from magbench.methods.registry import get_method, register

_fang = get_method("fang").fit


@register("bench_added", label="added method (Fang's fit)", min_samples=10, family="extra")
def added(samples):
    return _fang(samples)
"""
ADDED_METHOD = "bench_added"
#: The same fit as a variant, which ``calibrate`` never takes for a candidate (nor, as shipped,
#: a plugin: the generalisation sweep's calibrate rows stay as they are either way).
ADDED_VARIANT = ADDED_PLUGIN.replace('"bench_added"', '"bench_variant"').replace(
    'family="extra"', 'family="variant"')


def added_method_seconds(results_dir: Path | str, name: str = ADDED_METHOD) -> float:
    """Seconds spent in ``name``'s own calls under ``results_dir``: its trials' ``time_s``
    (every ``*times.csv`` sidecar) and its timing-pass calls (``spent_s`` of ``timing.csv``)."""
    total = 0.0
    for pattern, column in (("*/*times.csv", "time_s"), ("*/timing.csv", "spent_s")):
        for path in Path(results_dir).glob(pattern):
            frame = pd.read_csv(path)
            if {"algorithm", column} <= set(frame.columns):   # not reproduce_times.csv
                total += float(frame.loc[frame["algorithm"] == name, column].sum())
    return total


def bench_reproduce(n_jobs: int = 2, data_dir: str | None = None,
                    progress: Callable[[str], None] | None = print) -> pd.DataFrame:
    """``make reproduce`` timed three ways, each a fresh ``python -m magbench`` in a temporary
    folder (never ``results/``): the first run's compilation (``warmup`` with an empty numba
    cache), a full reproduce into an empty folder, and the same reproduce again with one
    plugin method added (:data:`ADDED_PLUGIN`), which computes only that method's rows (the
    generalisation sweep scores it as a fixed fit beside calibrate as shipped); and, from a
    copy of the full reproduce, with the method added as a variant (:data:`ADDED_VARIANT`),
    which no sweep treats differently any more: the two cases should agree.

    Returns one row per case: ``case``, ``wall_s``, ``cpu_s`` (the process and its workers),
    ``method_s`` (the added method's own calls, for the incremental case) and
    ``beyond_method_s`` (wall minus those calls).
    """
    from magbench.engine.record import cpu_model

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = dict(os.environ)
        if data_dir:
            env["MAGBENCH_DATA"] = str(data_dir)
        cold = dict(env, NUMBA_CACHE_DIR=str(tmp / "numba"))
        wall, cpu, _ = _timed_run([sys.executable, "-m", "magbench", "warmup",
                                   "progress=false"], cold)
        rows.append({"case": "first run: compile the numba kernels (warmup, empty cache)",
                     "wall_s": wall, "cpu_s": cpu})
        out = tmp / "repro"
        base = [sys.executable, "-m", "magbench", "reproduce", f"results_dir={out}",
                f"n_jobs={n_jobs}", "progress=false"]
        wall, cpu, _ = _timed_run(base, env)
        rows.append({"case": "make reproduce, empty results_dir", "wall_s": wall,
                     "cpu_s": cpu})
        if progress:
            progress(f"make reproduce: {wall:.1f} s wall, {cpu:.1f} CPU-s")
        (tmp / "plugin").mkdir()
        (tmp / "plugin" / "bench_added_plugin.py").write_text(ADDED_PLUGIN)
        (tmp / "plugin" / "bench_variant_plugin.py").write_text(ADDED_VARIANT)
        added_env = dict(env, PYTHONPATH=os.pathsep.join(
            filter(None, [str(tmp / "plugin"), env.get("PYTHONPATH")])))
        shutil.copytree(out, tmp / "repro_variant")
        for case, module, name, folder in (
                ("make reproduce again, one plugin method added", "bench_added_plugin",
                 ADDED_METHOD, out),
                ("the same, the method a variant (not a calibrate candidate)",
                 "bench_variant_plugin", "bench_variant", tmp / "repro_variant")):
            command = [*base[:4], f"results_dir={folder}", *base[5:], f"plugins=[{module}]"]
            wall, cpu, _ = _timed_run(command, added_env)
            own = added_method_seconds(folder, name)
            rows.append({"case": case, "wall_s": wall, "cpu_s": cpu, "method_s": own,
                         "beyond_method_s": wall - own})
            if progress:
                progress(f"{case}: {wall:.1f} s wall ({own:.1f} s in its own calls), "
                         f"{cpu:.1f} CPU-s")
    table = pd.DataFrame(rows, columns=["case", "wall_s", "cpu_s", "method_s",
                                        "beyond_method_s"])
    table["cpu_model"] = cpu_model()
    table["cpu_count"] = os.cpu_count()
    table["load_1min"] = os.getloadavg()[0]
    return table


# --- make reproduce: where its time goes, per sweep ------------------------------------------

def reproduce_times(steps: Sequence[Mapping[str, object]], results_dir: Path | str,
                    machine: Mapping[str, object] | None = None) -> pd.DataFrame:
    """Per-step table of one ``make reproduce`` run, with a ``total`` row.

    Parameters
    ----------
    steps : sequence of mappings
        One per step in the order run, each with ``step`` (a sweep's folder name or
        ``report``), ``wall_s`` and ``cpu_s`` (this process and its workers, see
        :func:`magbench.engine.record.cpu_seconds`); other keys (the load average, say) are
        kept as columns.
    results_dir : path
        Where the sweeps wrote their tables: ``method_s``, the seconds spent in calibration
        calls (:func:`calls_seconds` of ``<results_dir>/<step>``), is read from there; NaN for
        steps without any (the report).
    machine : mapping, optional
        Columns repeated on every row (CPU model, core count, workers, commit).

    Returns
    -------
    DataFrame
        ``step, wall_s, cpu_s, cpu_per_wall, method_s, overhead_cpu_s, share_wall`` and the
        extra columns; ``overhead_cpu_s = cpu_s - method_s`` is what the step spent outside the
        calibration calls (start-up, data, metrics, files, figures) on a quiet machine. The
        calls are timed by the wall clock, so on a busy one ``method_s`` includes waiting for
        a CPU and the overhead can come out negative: a sign to rerun when the machine is
        quiet (``load_1min`` records the load). ``share_wall`` is the step's part of the total
        wall time.
    """
    table = pd.DataFrame([dict(row) for row in steps])
    if table.empty:
        table = pd.DataFrame(columns=["step", "wall_s", "cpu_s"])
    table["method_s"] = [calls_seconds(Path(results_dir) / str(step)) for step in table["step"]]
    total = {"step": "total", "wall_s": table["wall_s"].sum(), "cpu_s": table["cpu_s"].sum(),
             "method_s": table["method_s"].sum(min_count=1)}
    table = pd.concat([table, pd.DataFrame([total])], ignore_index=True)
    table["cpu_per_wall"] = table["cpu_s"] / table["wall_s"]
    table["overhead_cpu_s"] = table["cpu_s"] - table["method_s"]
    table["share_wall"] = table["wall_s"] / total["wall_s"] if total["wall_s"] else np.nan
    for key, value in (machine or {}).items():
        table[key] = value
    first = ["step", "wall_s", "cpu_s", "cpu_per_wall", "method_s", "overhead_cpu_s",
             "share_wall"]
    return table[first + [c for c in table.columns if c not in first]]


def calls_seconds(folder: Path) -> float:
    """Seconds a step spent in calibration calls: every ``*_times.csv`` sidecar of its trials
    tables (the studies' timed calls) plus its timing pass's calls (``spent_s`` of
    ``timing.csv``); NaN when the folder holds neither (the report)."""
    parts = [(path, "time_s") for path in sorted(folder.glob("*_times.csv"))]
    parts.append((folder / "timing.csv", "spent_s"))
    total, found = 0.0, False
    for path, column in parts:
        try:
            total += float(pd.read_csv(path, usecols=[column])[column].sum())
            found = True
        except (OSError, ValueError):  # absent, or a table without that column
            continue
    return total if found else np.nan


def format_reproduce_times(table: pd.DataFrame) -> str:
    """The table of :func:`reproduce_times` as aligned text lines (what ``reproduce`` prints)."""
    lines = [f"{'step':<12}{'wall s':>9}{'CPU s':>9}{'CPU/wall':>10}{'in calls s':>12}"
             f"{'share':>8}"]
    for row in table.itertuples():
        method = "-" if pd.isna(row.method_s) else f"{row.method_s:.1f}"
        lines.append(f"{row.step!s:<12}{row.wall_s:>9.1f}{row.cpu_s:>9.1f}"
                     f"{row.cpu_per_wall:>10.2f}{method:>12}{row.share_wall:>8.0%}")
    total = table[table["step"] == "total"]
    if len(total):
        minutes, seconds = divmod(float(total["wall_s"].iloc[0]), 60)
        lines.append(f"make reproduce: {int(minutes)} min {seconds:.0f} s wall")
    return "\n".join(lines)
