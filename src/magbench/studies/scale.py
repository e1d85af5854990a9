"""Scale: one sweep point with many trials, its peak memory and its time per phase.

A sweep's memory must not grow with its trials beyond the columns its statistics read: the
trials are written per chunk and merged on disk (:mod:`magbench.engine.sweep`), the summary
reads its columns in chunks (:func:`magbench.core.files.read_csv_columns`) and the bootstrap
draws its resamples in chunks (:func:`magbench.core.intervals.resampled_means`).
:func:`bench_scale` checks that: it runs the nominal point of eq. (80) with a growing number
of trials for two methods, each size in a fresh interpreter (so each peak is its own), and
records the wall time of each phase and the peak resident memory of the process that runs
the sweep and summarises it, and of its largest worker.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pandas as pd

from magbench.core.files import read_csv_columns
from magbench.core.intervals import bootstrap_inverse_mean
from magbench.engine.record import cpu_model
from magbench.engine.sweep import run_study
from magbench.sources.synthetic import Point
from magbench.studies.review import ReviewStudy

__all__ = ["SCALE_ALGORITHMS", "SCALE_SIZES", "bench_scale", "scale_point"]

#: Two fast methods: the trials' cost is then mostly the dataset and its bound, the same for
#: any method, and the memory is what the engine and the statistics hold.
SCALE_ALGORITHMS = ("fang", "sphere")
#: Trials per run of :func:`bench_scale`: enough to show the growth in an afternoon's budget
#: (10^6 is an argument away).
SCALE_SIZES = (10_000, 30_000, 100_000)

_CHILD = """import json, sys
from magbench.cli.process import configure_process
configure_process()
from magbench.studies.scale import scale_point
print(json.dumps(scale_point(**json.loads(sys.argv[1]))))
"""


def _peak_mb(who: int) -> float:
    # ru_maxrss is in KiB on Linux.
    return resource.getrusage(who).ru_maxrss / 1024.0


def scale_point(out_dir: str, trials: int, algorithms: Sequence[str], n_jobs: int = 2,
                chunk_size: int | None = None, seed: int = 2021) -> dict:
    """Run, summarise and bootstrap ``trials`` datasets at the nominal point, in this process.

    Parameters
    ----------
    out_dir : str
        Folder of the run (``trials.csv``, ``summary.csv``); replaced if it holds one.
    trials : int
        Datasets (each fitted by every method of ``algorithms``).
    algorithms : sequence of str
        Registered methods.
    n_jobs : int
        Workers of the sweep.
    chunk_size : int, optional
        Trials per task; by default ``trials / 400`` (at least 25), so a run has a few hundred
        part files whatever its size.
    seed : int
        Base seed.

    Returns
    -------
    dict
        ``trials``, ``rows``, ``run_s``, ``summarize_s``, ``intervals_s`` (wall times),
        ``trials_mb`` (the size of ``trials.csv``), ``peak_rss_mb`` (this process, the whole
        run), ``peak_rss_after_run_mb`` (before the statistics) and ``worker_peak_rss_mb``
        (the largest worker), and each method's bootstrap interval of 1/rho.
    """
    study = ReviewStudy(name="scale", points=[Point()], trials=int(trials), seed=seed,
                        algorithms=list(algorithms))
    out = Path(out_dir)
    chunk = chunk_size or max(25, int(trials) // 400)
    start = time.perf_counter()
    run_study(study, out, n_jobs=n_jobs, chunk_size=chunk, progress=False, overwrite=True)
    ran = time.perf_counter()
    after_run = _peak_mb(resource.RUSAGE_SELF)
    study.summarize(out)
    summarized = time.perf_counter()
    rows = read_csv_columns(out / "trials.csv", ["algorithm", "meaningful", "J"])
    intervals = {}
    for name, g in rows.groupby("algorithm", sort=False):
        ok = g["J"].to_numpy(float)[g["meaningful"].astype(bool).to_numpy()]
        intervals[str(name)] = list(bootstrap_inverse_mean(ok, "scale", f"algorithm={name}"))
    done = time.perf_counter()
    # The workers are reaped only when the pool shuts down: then RUSAGE_CHILDREN has them.
    from joblib.externals.loky import get_reusable_executor

    get_reusable_executor().shutdown(wait=True)
    return {"trials": int(trials), "methods": len(study.algorithms), "rows": len(rows),
            "n_jobs": n_jobs, "chunk_size": chunk, "run_s": ran - start,
            "summarize_s": summarized - ran, "intervals_s": done - summarized,
            "trials_mb": (out / "trials.csv").stat().st_size / 1e6,
            "peak_rss_mb": _peak_mb(resource.RUSAGE_SELF),
            "peak_rss_after_run_mb": after_run,
            "worker_peak_rss_mb": _peak_mb(resource.RUSAGE_CHILDREN),
            "intervals": intervals}


def bench_scale(sizes: Sequence[int] = SCALE_SIZES,
                algorithms: Sequence[str] = SCALE_ALGORITHMS, n_jobs: int = 2,
                workdir: Path | str | None = None,
                progress: Callable[[str], None] | None = print) -> pd.DataFrame:
    """:func:`scale_point` at each size, each in a fresh interpreter; one row per size.

    The interpreter is set up as a magbench command is (:mod:`magbench.cli.process`), and its
    files go to a temporary folder under ``workdir`` (removed after each size; a 10^6-trial
    run of two methods writes ~1.5 GB of ``trials.csv`` and, while merging, twice that).

    Returns
    -------
    DataFrame
        The :func:`scale_point` numbers per size (intervals as ``acc_lo_<m>``, ``acc_hi_<m>``),
        with the CPU model, the load average before the size and ``per_trial_ms``, the
        sweep's wall time per trial.
    """
    rows = []
    for trials in sizes:
        folder = Path(tempfile.mkdtemp(prefix="magbench-scale-", dir=workdir))
        try:
            load = os.getloadavg()[0]
            args = json.dumps({"out_dir": str(folder / "scale"), "trials": int(trials),
                               "algorithms": list(algorithms), "n_jobs": n_jobs})
            done = subprocess.run([sys.executable, "-c", _CHILD, args], capture_output=True,
                                  text=True, check=True)
            found = json.loads(done.stdout.strip().splitlines()[-1])
        finally:
            shutil.rmtree(folder, ignore_errors=True)
        for name, (low, high) in found.pop("intervals").items():
            found[f"acc_lo_{name}"], found[f"acc_hi_{name}"] = low, high
        found.update({"load_1min": load, "cpu_model": cpu_model(),
                      "per_trial_ms": 1e3 * found["run_s"] / found["trials"]})
        rows.append(found)
        if progress:
            progress(f"scale: {trials} trials x {found['methods']} methods: run "
                     f"{found['run_s']:.1f} s, summary {found['summarize_s']:.1f} s, intervals "
                     f"{found['intervals_s']:.1f} s; peak RSS {found['peak_rss_mb']:.0f} MB "
                     f"(worker {found['worker_peak_rss_mb']:.0f} MB)")
    return pd.DataFrame(rows)
