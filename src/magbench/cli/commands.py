"""The commands: run a sweep (any kind), reproduce, bench, report, calibrate, methods.

A sweep command checks its config (:mod:`magbench.cli.config`), runs its study on the engine,
writes its statistics, draws its figures and writes its report text, in that order; ``report``
redraws every figure and rewrites the report from the CSV files alone.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig, OmegaConf

from magbench.cli.config import (
    UsageError,
    check_common,
    compose_config,
    config_dir,
    writable_folder,
)
from magbench.cli.kinds import Kind, get_kind, kind_names, kind_of, kind_of_sweep, study_for
from magbench.core.files import write_csv_atomic, write_text_atomic
from magbench.engine.plugins import load_plugins, plugin_modules
from magbench.engine.record import cpu_model, cpu_seconds, git_commit, process_age_s
from magbench.engine.sweep import parallel_backend, run_lock, run_study
from magbench.figures.speed import plot_scale, plot_scaling
from magbench.methods.registry import methods
from magbench.report import write_report
from magbench.report.build import write_markdown_report
from magbench.report.speed import bench_report_section
from magbench.studies.speed import format_reproduce_times, reproduce_times, run_bench
from magbench.studies.timing import repeat_timing

__all__ = ["SectionQueue", "bench", "draw_figures", "report", "reproduce", "run", "scale",
           "sweep_names", "timing_check"]


def run(cfg: DictConfig, figures: bool = True, queue: SectionQueue | None = None) -> int:
    """``python -m magbench sweep=NAME``: the study, its statistics, figures and text.

    ``figures=False`` leaves the figures to a later ``report`` (as :func:`reproduce` does);
    with a ``queue`` the sweep's own text (``section.md``) too, and the folder's lock with it.
    """
    kind = kind_of(cfg)
    study, common = study_for(cfg)
    out_dir = writable_folder(common["results_dir"], "results_dir") / study.name
    with contextlib.ExitStack() as held:
        # held until the last file of the run is written (by the queue's worker, with one)
        held.enter_context(run_lock(out_dir))
        run_study(study, out_dir, n_jobs=common["n_jobs"], chunk_size=common["chunk_size"],
                  backend=common["backend"], scheduler_address=common["scheduler_address"],
                  progress=common["progress"], config=OmegaConf.to_container(cfg, resolve=True),
                  overwrite=common["overwrite"])
        kind.finish(study, out_dir, common)
        drawn = kind.figures(study.name, out_dir) if figures and queue is None else []
        if kind.section is not None and queue is None:
            kind.section(out_dir)
        table = next(iter(study.tables.values()))[0]
        trials = pd.read_csv(out_dir / table, usecols=["ok"])
        n_bad = int((~trials["ok"].astype(bool)).sum())
        shown = ", ".join(p.name for p in drawn) or ("no figure for this sweep" if figures
                                                        else "drawn by the report")
        if queue is not None:
            queue.submit(study.name, kind.section, held.pop_all())
        print(f"sweep {study.name}: {len(trials)} rows ({n_bad} not ok) -> {out_dir}/ "
              f"({table}, figures: {shown})")
    return 0


def result_folders(results_dir: Path) -> dict[str, Kind]:
    """The sweeps of ``conf/sweep/`` that have a folder under ``results_dir``, with their
    kinds."""
    out = {}
    for name in sweep_names():
        kind = kind_of_sweep(name)
        if kind is not None and (results_dir / name).is_dir():
            out[name] = kind
    return out


def _bench_figures(name: str, folder: Path) -> list[Path]:
    """The benchmark's figures (``bench/``), from its CSV files."""
    written = []
    if (folder / "calls.csv").exists():
        written.append(plot_scaling(pd.read_csv(folder / "calls.csv"), folder / "scaling.png"))
    if (folder / "scale.csv").exists():
        written.append(plot_scale(pd.read_csv(folder / "scale.csv"), folder / "scale.png"))
    return written


def _figure_jobs(results_dir: Path) -> list[tuple]:
    """``(figures, name, folder)`` of every folder with figures: each sweep's, the bench's."""
    jobs = [(kind.figures, name, results_dir / name)
            for name, kind in result_folders(results_dir).items()]
    return [*jobs, (_bench_figures, "bench", results_dir / "bench")]


def draw_figures(results_dir: Path | str, n_jobs: int = 1, *, meanwhile: object = None,
                 queue: SectionQueue | None = None) -> list[Path]:
    """Redraw every figure under ``results_dir`` from its CSV files.

    Parameters
    ----------
    results_dir : path
        The results folder.
    n_jobs : int
        Worker processes drawing the folders' figures side by side (1: here, one after
        another); each figure is drawn by one process as it would be alone, so the files
        are the same either way.
    meanwhile : callable, optional
        Work for this process while the workers draw (the report's text), called once.
    queue : SectionQueue, optional
        The sweeps whose own text (their kind's ``section``) was left for now: written by
        the same process as the folder's figures, before them.

    Returns
    -------
    list of Path
        The figures written, folder by folder in :func:`result_folders` order.
    """
    sections = {} if queue is None else queue.sections()
    jobs = [(*job, sections.get(job[1])) for job in _figure_jobs(Path(results_dir))]
    if n_jobs == 1 or len(jobs) < 2:
        written = [path for figures, name, folder, section in jobs
                   for path in _draw_with_plugins(figures, name, folder, (), section)]
        if meanwhile is not None:
            meanwhile()
        return written
    from joblib import Parallel, delayed

    # The sweeps' worker pool (reproduce has it warm, magbench imported); one task a folder;
    # the generator dispatches them at once, so this process is free to do ``meanwhile``
    # before it collects the figures.
    with parallel_backend("loky", n_jobs) as engine:
        parallel = Parallel(n_jobs=engine["n_jobs"], backend=engine["backend"], batch_size=1,
                            return_as="generator")
        # a worker knows the plugins' methods (their labels and colours) only once it has
        # imported them, as this process has
        plugins = plugin_modules(methods())
        results = parallel(delayed(_draw_with_plugins)(figures, name, folder, plugins, section)
                           for figures, name, folder, section in jobs)
        if meanwhile is not None:
            meanwhile()
        return [path for paths in results for path in paths]


class SectionQueue:
    """The finished sweeps' own text (their kind's ``section``: ``section.md`` and the like),
    left by ``reproduce`` to its report step, which writes each on the worker that draws the
    folder's figures while this process writes the report's text: the folder's files are
    final once its run returns, and the text reads nothing else, so it is the file the sweep
    would have written. Each folder's lock is held until then (:meth:`release`)."""

    def __init__(self) -> None:
        self._sections: dict[str, object] = {}
        self._locks: list[contextlib.ExitStack] = []

    def submit(self, name: str, section: object, lock: contextlib.ExitStack | None = None,
               ) -> None:
        """Leave sweep ``name``'s ``section`` (None: it has none) to the report; ``lock``, its
        folder's lock, is released by :meth:`release`."""
        if section is not None:
            self._sections[name] = section
        if lock is not None:
            self._locks.append(lock)

    def sections(self) -> dict[str, object]:
        """Folder name -> the section left to write there."""
        return dict(self._sections)

    def release(self) -> None:
        """Release the folders' locks (their files all written, or the run failed)."""
        for lock in self._locks:
            lock.close()
        self._locks.clear()


def _draw_with_plugins(figures: object, name: str, folder: Path, plugins: Sequence[str],
                       section: object = None) -> list[Path]:
    """``figures(name, folder)`` in a worker, the ``plugins`` imported first, and before them
    ``section(folder)`` if given (a sweep's own text, which a run writes before any figure)."""
    load_plugins(plugins)
    if section is not None:
        section(folder)
    return figures(name, folder)


def bench(cfg: DictConfig) -> int:
    """``python -m magbench bench``: time every method; writes ``<results_dir>/bench/``."""
    from magbench.cli.config import check_common, check_flag, check_scale, selected_algorithms

    common = check_common(cfg)
    names = selected_algorithms(cfg)
    sizes = check_scale(cfg)
    writable_folder(common["results_dir"], "results_dir")
    if check_flag(cfg.get("timing_check", False), "timing_check"):
        return timing_check(cfg)
    if sizes is not None:
        return scale(sizes, common)
    folder = run_bench(common["results_dir"], names, call_timeout_s=common["call_timeout_s"],
                       progress=(lambda line: print(line, file=sys.stderr))
                       if common["progress"] else None)
    plot_scaling(pd.read_csv(folder / "calls.csv"), folder / "scaling.png")
    write_text_atomic(bench_report_section(common["results_dir"]), folder / "bench.md")
    print(f"benchmark written to {folder}/ (calls.csv, first_calls.csv, scaling.png, peers.csv, "
          "peer_accuracy.csv, peer_accuracy_summary.csv, peer_install.csv, calibrate.csv, "
          "parallel.csv, bench.md)")
    return 0


def scale(sizes: Sequence[int], common: dict) -> int:
    """``python -m magbench bench scale=[...]``: one sweep point at each number of trials
    (:func:`magbench.studies.scale.bench_scale`); writes ``<results_dir>/bench/scale.csv`` and
    ``scale.png`` and prints the paragraph the report gives them."""
    from magbench.report.scale import scale_lines
    from magbench.studies.scale import bench_scale

    folder = common["results_dir"] / "bench"
    folder.mkdir(parents=True, exist_ok=True)
    table = bench_scale(sizes, n_jobs=common["n_jobs"], workdir=folder,
                        progress=(lambda line: print(line, file=sys.stderr))
                        if common["progress"] else None)
    write_csv_atomic(table, folder / "scale.csv")
    plot_scale(table, folder / "scale.png")
    print("\n".join(scale_lines(table)).strip())
    print(f"scale written to {folder}/ (scale.csv, scale.png)")
    return 0


#: The order of ``make reproduce``; sweeps found in ``conf/sweep/`` but not named here follow.
REPRODUCE_ORDER = ("baseline", "gamma", "beta", "K", "sigma", "coverage", "wushi", "gyro", "real")


def sweep_names() -> list[str]:
    """Every sweep of ``conf/sweep/``, in :data:`REPRODUCE_ORDER` and then by name."""
    found = sorted(p.stem for p in (config_dir() / "sweep").glob("*.yaml"))
    return [s for s in REPRODUCE_ORDER if s in found] + [s for s in found
                                                         if s not in REPRODUCE_ORDER]



def reproduce(overrides: Sequence[str]) -> int:
    """``python -m magbench reproduce`` (``make reproduce``): every sweep, then the report.

    Each sweep is composed as ``sweep=NAME overwrite=true`` plus ``overrides`` and run as
    ``python -m magbench sweep=NAME`` would run it, but all in this one process: the worker
    processes (joblib's reusable pool) start, import magbench and load the compiled loops once
    instead of once per sweep, and every figure is drawn once, by the report. The real sweep is
    skipped, with a line, when no ``data_dir`` (``$MAGBENCH_DATA``) is set. The wall and CPU
    time of each step (workers included) are printed and written to
    ``<results_dir>/bench/reproduce_times.csv`` with the CPU model.
    """
    steps = [{"step": "start-up", "wall_s": process_age_s(), "cpu_s": cpu_seconds(),
              "load_1min": os.getloadavg()[0]}]
    cfg = compose_config(list(overrides))
    common = check_common(cfg)

    def timed(step: str, work: object) -> None:
        wall, cpu, load = time.perf_counter(), cpu_seconds(), os.getloadavg()[0]
        work()
        steps.append({"step": step, "wall_s": time.perf_counter() - wall,
                      "cpu_s": cpu_seconds() - cpu, "load_1min": load})

    sweeps = []
    for name in sweep_names():
        sweep_cfg = compose_config([*overrides, f"sweep={name}", "overwrite=true"])
        if kind_of(sweep_cfg).needs_data and not sweep_cfg.get("data_dir"):
            print(f"sweep {name} skipped: set MAGBENCH_DATA to a folder of recordings "
                  "(see docs/sweeps.md, Real data)")
            continue
        study_for(sweep_cfg)  # every sweep's config is checked before any of them runs
        sweeps.append(sweep_cfg)
    # Each sweep's own text is written by the report step's figure workers, not here
    # between sweeps (its folder held until then).
    queue = SectionQueue()
    try:
        for sweep_cfg in sweeps:
            timed(str(sweep_cfg.sweep.name),
                  lambda c=sweep_cfg: run(c, figures=False, queue=queue))
        timed("report", lambda: report(cfg, queue=queue))
    finally:
        queue.release()
    machine = {"cpu_model": cpu_model(), "cpu_count": os.cpu_count(),
               "n_jobs": common["n_jobs"], "git_commit": git_commit()}
    table = reproduce_times(steps, common["results_dir"], machine)
    path = common["results_dir"] / "bench" / "reproduce_times.csv"
    write_csv_atomic(table, path)
    print(format_reproduce_times(table))
    print(f"per-step times written to {path} ({machine['cpu_model']}, "
          f"{machine['cpu_count']} CPUs, n_jobs={machine['n_jobs']})")
    return 0


def timing_check(cfg: DictConfig) -> int:
    """``python -m magbench bench timing_check=true [sweep=NAME]``: the sweep's timing protocol
    run twice in a row; writes ``<results_dir>/bench/timing_check.csv`` (both passes) and
    ``timing_check_summary.csv`` (per method: worst ratio of pass 2 to pass 1, agreement within
    10 %) and prints the comparison."""
    from magbench.cli.config import UsageError

    if not kind_of(cfg).timed:
        timed = [k.name for k in map(get_kind, kind_names()) if k.timed]
        raise UsageError(f"timing_check times a sweep with a timing protocol (kind "
                         f"{', '.join(timed)}), got sweep={cfg.sweep.name}")
    study, common = study_for(cfg)
    folder = common["results_dir"] / "bench"
    passes, comparison = repeat_timing(
        study, progress=(lambda line: print(line, file=sys.stderr)) if common["progress"]
        else None)
    write_csv_atomic(passes, folder / "timing_check.csv")
    write_csv_atomic(comparison, folder / "timing_check_summary.csv")
    print(comparison.to_string(index=False))
    print(f"{int(comparison['agree'].sum())} of {len(comparison)} methods within 10 % in every "
          f"cell ({passes['cpu_model'].iloc[0]}); the whole machine ran "
          f"{comparison['common_ratio'].iloc[0]:.3g}x as long in pass 2, and relative to that "
          f"{int(comparison['agree_relative'].sum())} of {len(comparison)} agree within 10 %; "
          f"written to {folder}/timing_check.csv")
    return 0


def report(cfg: DictConfig, queue: SectionQueue | None = None) -> int:
    """``python -m magbench report``: redraw the figures and rewrite ``report.md``.

    The figures are drawn by ``n_jobs`` worker processes while this one writes the Markdown
    report; the HTML page, which embeds the figures, comes last. ``queue``: the
    sweeps' own texts left to it (``reproduce``), written by the figures' processes."""
    results_dir = Path(str(cfg.results_dir)).expanduser()
    if not results_dir.is_dir():
        raise UsageError(f"results_dir={results_dir} is not a folder of results; expected the "
                         "folder a sweep wrote (python -m magbench sweep=NAME results_dir=...)")
    writable_folder(results_dir, "results_dir")
    n_jobs = check_common(cfg)["n_jobs"]
    sections = [k.report for k in map(get_kind, kind_names()) if k.report is not None]
    path, texts = results_dir / "report.md", {}     # each section computed once for both
    figures = draw_figures(results_dir, os.cpu_count() or 1 if n_jobs < 0 else n_jobs,
                           meanwhile=lambda: write_markdown_report(results_dir, sections, texts),
                           queue=queue)
    write_report(results_dir, sections, markdown=False, texts=texts)
    print(f"report written to {path} ({len(figures)} figures redrawn from the CSV files)")
    return 0
