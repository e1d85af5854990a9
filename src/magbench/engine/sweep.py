"""The one sweep runner: a study's work units, in chunks, over workers, resumable.

A *study* (:class:`Study`) lists its work units (a point and a trial, a recording, a Monte
Carlo run) and computes the rows of one unit; this module does everything else the same way for
every study:

* chunks of ``chunk_size`` consecutive units run as tasks on joblib workers (``n_jobs``) or a
  Dask cluster (``backend="dask"``); plugin modules are imported in every worker first;
* each finished chunk is written at once as part files (one per table) plus a small JSON
  record of their row counts and SHA-256 checksums, each renamed into place; a killed run
  loses at most the chunks in flight;
* a rerun reuses a part only if its record is intact, its checksums match and it belongs to
  the same study fingerprint; anything else is recomputed, with a warning naming it;
* the parts are merged on disk into the final CSV files (rows in unit order, whatever finished
  first), ``run.json`` is written beside them and the parts are removed;
* one run per folder at a time: a second run on the same folder is refused (:class:`FolderBusy`);
  the lock is the operating system's, so a killed run leaves no stale lock behind;
* a finished run is never silently replaced: rerun with the same fingerprint, its tables are
  reused as they are (and it says so); with another configuration the run is refused
  (:class:`ResultsExist`) unless ``overwrite=True``;
* rows are cached per method where the study allows it (``method_column``): each method's
  rows are keyed by the study's other settings (:meth:`Study.base_fingerprint`) and by the
  method's own key (its name, options and code, :meth:`Study.method_key`). A run of another
  selection of methods into a finished run's folder reuses, byte for byte, the rows of every
  method whose key is unchanged and computes only the others (a new method, changed options,
  changed code); it says which. It is refused, as before, when it would drop a method of the
  finished run or when any other setting differs.

How a cached run goes: the rows it reuses are first copied out of the finished tables into
``parts/reused.*`` (with a checksummed record), the other methods run as a study of their own
(:meth:`Study.with_methods`) in chunks as usual, and the merge interleaves both per unit in the
study's method order: the tables are those a full run would write (its times aside). A kill at
any point resumes from the parts.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import io
import json
import os
import shutil
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, ClassVar

from magbench.core.files import (
    LockHeld,
    atomic_path,
    exclusive_lock,
    file_sha256,
    write_rows_csv,
    write_text_atomic,
)
from magbench.engine.isolation import die_with_parent, run_isolated, watch_calls
from magbench.engine.plugins import load_plugins
from magbench.engine.record import fit_module, method_code, study_code, write_run_record
from magbench.engine.warm import warm_methods

__all__ = ["FolderBusy", "ResultsExist", "Study", "TooLarge", "check_capacity", "finished_run",
           "folder_lock", "parallel_backend", "run_lock", "run_study", "settings_hash"]


class FolderBusy(RuntimeError):
    """Another run holds the results folder."""


class ResultsExist(RuntimeError):
    """The results folder holds a finished run of another configuration."""


class TooLarge(RuntimeError):
    """The run's estimated output exceeds the free disk space or memory."""


class Study:
    """Base of every study: a frozen dataclass whose fields determine its rows.

    Subclasses set ``name`` and ``tables`` (table name -> (file name, columns); the first is
    the main table) and implement :meth:`units` and :meth:`run_unit`. Every field of the
    dataclass enters the fingerprint, so parts of a run with other settings are never reused.
    """

    # Set by every subclass: ``name`` and ``plugins`` as dataclass fields, ``tables`` as a
    # class attribute (no defaults here: a dataclass would take them for field defaults).
    name: str
    plugins: Sequence[str]
    tables: Mapping[str, tuple[str, Sequence[str]]]

    #: The column naming the method of every row of every table, for a study whose rows are
    #: cached per method (it has ``algorithms`` and ``options`` fields, and each unit gives
    #: its rows one entrant after another in :meth:`entrants` order, which depend on nothing
    #: but the unit and that entrant; how many may differ from unit to unit when each chunk
    #: holds one unit); None: whole runs only.
    method_column: ClassVar[str | None] = None
    #: Tables without ``method_column`` whose rows all belong to one entrant: {table: name}.
    table_owner: ClassVar[Mapping[str, str]] = {}
    #: True when an entrant's rows per unit may differ from unit to unit (a skipped case):
    #: the run then cuts chunks of one unit, whatever ``chunk_size``, so that each chunk's
    #: record says how many rows each entrant gave (rows cached per method need it).
    ragged: ClassVar[bool] = False
    #: Settings that are not part of :meth:`base_fingerprint`: the methods' own.
    method_fields: ClassVar[tuple[str, ...]] = ("algorithms", "options", "plugins")

    def units(self) -> list:
        """The work units, in the order their rows appear in the results."""
        raise NotImplementedError

    def unit_weight(self, unit: object) -> int:
        """Progress counted for one unit (trials, for instance); 1 by default."""
        return 1

    def estimated_rows(self, units: Sequence) -> int:
        """Rows of the main table, roughly: one per unit and selected method by default."""
        return len(units) * max(1, len(getattr(self, "algorithms", ()) or ()))

    def run_unit(self, unit: object) -> dict[str, list[dict]]:
        """Rows of one unit, per table. Must not raise for a method's failure."""
        raise NotImplementedError

    def describe(self) -> dict:
        """The settings as plain data (for ``run.json`` and the fingerprint); fields marked
        ``metadata={"setting": False}`` (values a run knows already, :meth:`given_reused`)
        are left out."""
        hidden = [f.name for f in dataclasses.fields(self) if not f.metadata.get("setting", True)]
        data = dataclasses.asdict(dataclasses.replace(self, **dict.fromkeys(hidden))
                                  if hidden else self)
        for name in hidden:
            data.pop(name)
        return json.loads(json.dumps(data, default=str))

    def fingerprint(self) -> str:
        """Hash of the settings and tables: parts of another configuration are never reused."""
        return settings_hash({"study": type(self).__name__, "settings": self.describe(),
                      "tables": {k: list(v[1]) for k, v in self.tables.items()}})

    def base_fingerprint(self) -> str:
        """Hash of everything that determines the rows except the methods (their selection,
        options, plugins and code): the settings, the tables and the code of the study's
        module and of the magbench modules it uses (:func:`magbench.engine.record.study_code`).
        Rows of two runs with the same base are interchangeable method by method."""
        settings = {k: v for k, v in self.describe().items() if k not in self.method_fields}
        return settings_hash({"study": type(self).__name__, "settings": settings,
                      "tables": {k: list(v[1]) for k, v in self.tables.items()},
                      "code": study_code(type(self).__module__)})

    def entrants(self) -> list[str]:
        """The names whose rows are cached one by one (the ``method_column`` values, in row
        order within a unit): the selected ``algorithms`` unless a study has entrants of its
        own (an automatic choice, peers), with keys from :meth:`method_key`."""
        return list(self.algorithms)

    def with_methods(self, names: Sequence[str]) -> Study:
        """The same study on the entrants ``names`` only (their options kept)."""
        options = getattr(self, "options", None) or {}
        return dataclasses.replace(self, algorithms=tuple(names),
                                   options={k: v for k, v in options.items() if k in names})

    def given_reused(self, tables: Mapping[str, Path]) -> Study:
        """This study (the entrants a run computes) told the rows reused beside it
        (``tables``: table name -> the staged CSV of the reused entrants' rows), to take from
        them what does not depend on the entrant instead of computing it again; the rows must
        be those computed without it. The default takes nothing."""
        return self

    def method_key(self, name: str) -> dict[str, str]:
        """What determines the rows of method ``name`` besides the base: its options in this
        study and its code (:func:`magbench.engine.record.method_code` of its module), each
        hashed."""
        from magbench.methods.registry import get_method

        options = (getattr(self, "options", None) or {}).get(name) or {}
        module = fit_module(get_method(name).fit)
        return {"options": settings_hash(json.loads(json.dumps(options, default=str))),
                "code": f"{module}:{method_code(module)}"}

def settings_hash(data: object) -> str:
    """SHA-256 (16 hex digits) of ``data`` as sorted JSON: the fingerprints' and keys' hash.

    Parameters
    ----------
    data : object
        Plain data (anything JSON takes; other values as their ``str``).

    Returns
    -------
    str
    """
    text = json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@contextlib.contextmanager
def folder_lock(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``folder`` (``.lock``) for the block; :class:`FolderBusy` if
    another holder (another process, or another block of this one) has it. The lock dies with
    its process, so a killed run leaves none (:func:`magbench.core.files.exclusive_lock`)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    note = f"pid {os.getpid()} since {datetime.now(UTC):%Y-%m-%d %H:%M:%S} UTC"
    try:
        with exclusive_lock(folder / ".lock", note) as held:
            if not held:
                _warn("no file locking on this system: two runs on one results folder are not "
                      "refused")
            yield
    except LockHeld as exc:
        raise FolderBusy(f"{folder} is in use by a running magbench ({exc.holder}); wait for "
                         "it to finish or choose another results_dir") from None


#: Folders held by :func:`run_lock` in this process: :func:`run_study` runs in them without
#: taking the lock again.
_HELD: set[Path] = set()


@contextlib.contextmanager
def run_lock(folder: Path | str) -> Iterator[None]:
    """Hold ``folder`` for a whole command: the trials (:func:`run_study` inside the block uses
    this lock), then the timing, statistics, figures and report text written after them, so
    that no other run can start in the folder until all of its files are in place.

    Raises
    ------
    FolderBusy
        Another run holds ``folder``.
    """
    key = Path(folder).resolve()
    with folder_lock(Path(folder)):
        _HELD.add(key)
        try:
            yield
        finally:
            _HELD.discard(key)


def _lock_for_run(folder: Path) -> contextlib.AbstractContextManager:
    """The folder's lock, unless a :func:`run_lock` of this process holds it already."""
    return contextlib.nullcontext() if folder.resolve() in _HELD else folder_lock(folder)


@contextlib.contextmanager
def parallel_backend(backend: str, n_jobs: int,
                     scheduler_address: str | None = None) -> Iterator[dict]:
    """joblib arguments for ``backend``, with a Dask client open for ``"dask"``.

    ``"loky"`` runs worker processes on this machine. ``"dask"`` sends the tasks to the Dask
    cluster at ``scheduler_address`` or, when that is None, to a ``LocalCluster`` of ``n_jobs``
    single-threaded worker processes bound to 127.0.0.1.
    """
    if backend == "loky":
        yield {"backend": _loky_backend(), "n_jobs": n_jobs}
        return
    if backend != "dask":
        raise ValueError(f"backend must be 'loky' or 'dask', got {backend!r}")
    from distributed import Client, LocalCluster
    from joblib import parallel_config

    with contextlib.ExitStack() as stack:
        if scheduler_address:
            client = stack.enter_context(Client(scheduler_address))
        else:
            # A task whose worker dies is failed at the first death, not retried on three
            # more workers: the run finds the call that kills in a supervised process.
            import dask

            stack.enter_context(dask.config.set({"distributed.scheduler.allowed-failures": 0}))
            cluster = stack.enter_context(LocalCluster(
                n_workers=max(n_jobs, 1), threads_per_worker=1, processes=True,
                host="127.0.0.1", dashboard_address=None))
            client = stack.enter_context(Client(cluster))
        stack.enter_context(parallel_config(backend="dask"))
        yield {"n_jobs": -1, "client": client}


#: loky's resource tracker warns at exit of the semaphores an interrupted pool left, which it
#: then removes: noise after a Ctrl-C, whose one line is the run's own.
_TRACKER_FILTER = "ignore::UserWarning:joblib.externals.loky.backend.resource_tracker"


def _quiet_resource_tracker() -> None:
    """Pass :data:`_TRACKER_FILTER` to the processes started from here on (the tracker among
    them), keeping any ``PYTHONWARNINGS`` the user set."""
    current = os.environ.get("PYTHONWARNINGS", "")
    if _TRACKER_FILTER not in current.split(","):
        os.environ["PYTHONWARNINGS"] = ",".join(filter(None, [current, _TRACKER_FILTER]))


def _loky_backend() -> object:
    """joblib's loky backend whose workers, from their start, end with the run (even those
    that never get a chunk)."""
    from joblib.parallel import LokyBackend

    _quiet_resource_tracker()

    return LokyBackend(initializer=_worker_start, initargs=(os.getpid(),))


@contextlib.contextmanager
def _interrupt_blocked() -> Iterator[None]:
    """Block SIGINT in this thread for the block: processes and threads started in it inherit
    the block, so a Ctrl-C (sent to the whole process group) reaches only the run, which
    stops its workers itself, and no worker prints a traceback of its own. A Ctrl-C in the
    block is delivered when it ends."""
    mask = getattr(signal, "pthread_sigmask", None)
    if mask is None or threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = mask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        mask(signal.SIG_SETMASK, previous)


def _worker_start(parent_pid: int) -> None:
    """A loky worker's first act: die with the run that started it, and leave Ctrl-C to the
    run, which stops its workers itself (the blocked mask covers only the worker's start)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()
    _exit_with_parent(parent_pid)


_WATCHED_PARENT: list[int] = []


def _exit_with_parent(parent_pid: int | None, poll_s: float = 1.0) -> None:
    """In a loky worker, exit as soon as the run that started it is gone.

    A run killed with SIGKILL cannot shut its worker pool down, and loky's idle workers (and,
    through them, the resource trackers) would otherwise live on, orphaned, for many minutes.
    On Linux the kernel's parent-death signal (:func:`die_with_parent`) ends them even inside
    one long compiled call; polling the parent's pid from a daemon thread covers the other
    POSIX systems. ``parent_pid`` is None on Dask, whose workers have their own parents.
    """
    if parent_pid is None or os.getpid() == parent_pid or _WATCHED_PARENT:
        return
    _WATCHED_PARENT.append(parent_pid)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="magbench-parent-watch", daemon=True).start()


def _run_chunk(study: Study, units: list, start: int, parent_pid: int | None = None,
               marker: str | None = None, writer: _ChunkWriter | None = None,
               ) -> tuple[int, dict[str, list[dict]] | None]:
    """A worker's task: the rows of one chunk. ``marker`` is touched first, so that after a
    worker's death the run knows which chunks were under way (:func:`_run_todo`). With a
    ``writer`` (a worker that sees the run's folder) the worker writes the chunk's part files
    and returns None for its rows."""
    _exit_with_parent(parent_pid)
    if marker is not None:
        with contextlib.suppress(OSError):      # a remote worker may not see the folder
            Path(marker).touch()
    load_plugins(study.plugins)
    watch_calls()
    out: dict[str, list[dict]] = {name: [] for name in study.tables}
    for unit in units:
        for name, rows in study.run_unit(unit).items():
            out[name].extend(rows)
    if writer is not None:
        writer.write(start, start + len(units), out)
        return start, None
    return start, out


def _chunk_stem(start: int, stop: int) -> str:
    return f"c{start:07d}-{stop:07d}"


@dataclasses.dataclass(frozen=True)
class _ChunkWriter:
    """Writes one chunk's part files and then its record: picklable, so that a local worker
    writes the chunk it computed instead of sending its rows to the main process."""

    dir: Path
    fingerprint: str
    tables: Mapping[str, tuple[str, Sequence[str]]]
    method_column: str | None
    table_owner: Mapping[str, str]

    def write(self, start: int, stop: int, rows: dict[str, list[dict]]) -> None:
        sums: dict[str, object] = {"fingerprint": self.fingerprint}
        layout = {}
        for table, (_, columns) in self.tables.items():
            path = self.dir / f"{_chunk_stem(start, stop)}.{table}.csv"
            write_rows_csv(rows.get(table, []), columns, path)
            sums[table] = {"rows": len(rows.get(table, [])), "sha256": file_sha256(path)}
            if self.method_column is not None:
                owner = self.table_owner.get(table)
                layout[table] = (_layout(rows.get(table, []), stop - start, self.method_column)
                                 if owner is None else
                                 _owned_layout(rows.get(table, []), stop - start, owner))
        if self.method_column is not None:
            sums["layout"] = layout
        # The record goes last: a chunk counts as done only once all its tables are in place.
        write_text_atomic(json.dumps(sums), self.dir / f"{_chunk_stem(start, stop)}.json")


class _Parts:
    """The part files of one study run under ``<out_dir>/parts``."""

    def __init__(self, out_dir: Path, study: Study, work: Study | None = None) -> None:
        # ``work`` computes the chunks: the study itself, or its methods not reused from a
        # finished run; the manifest names the study, each chunk's record the work.
        self.dir = out_dir / "parts"
        self.study = study
        manifest = self.dir / "manifest.json"
        fingerprint = study.fingerprint()
        self.fingerprint = (work or study).fingerprint()
        if self.dir.exists():
            try:
                found = json.loads(manifest.read_text()).get("fingerprint")
            except (OSError, ValueError, AttributeError):
                found = "damaged or missing manifest"
            if found != fingerprint:
                n = len(list(self.dir.glob("*.json"))) - manifest.exists()
                if n > 0:
                    _warn(f"{self.dir}: discarding {n} finished chunk(s) of another "
                          f"configuration ({found}); they are recomputed")
                shutil.rmtree(self.dir)
        if not self.dir.exists():
            self.dir.mkdir(parents=True)
            write_text_atomic(json.dumps({"fingerprint": fingerprint, "study": study.name}),
                              manifest)
        self.clear_markers()        # a killed run's markers say nothing about this one

    def _stem(self, start: int, stop: int) -> str:
        return _chunk_stem(start, stop)

    @property
    def writer(self) -> _ChunkWriter:
        """What writes a chunk's files (:meth:`write`), to hand to a local worker."""
        return _ChunkWriter(self.dir, self.fingerprint, dict(self.study.tables),
                            self.study.method_column, dict(self.study.table_owner))

    def path(self, start: int, stop: int, table: str) -> Path:
        return self.dir / f"{self._stem(start, stop)}.{table}.csv"

    def marker(self, start: int, stop: int) -> Path:
        """Touched by the worker that starts the chunk."""
        return self.dir / f"{self._stem(start, stop)}.started"

    def started(self, start: int, stop: int) -> bool:
        return self.marker(start, stop).exists()

    def has_record(self, start: int, stop: int) -> bool:
        return (self.dir / f"{self._stem(start, stop)}.json").exists()

    def clear_markers(self) -> None:
        for path in self.dir.glob("*.started"):
            path.unlink(missing_ok=True)

    def done(self, start: int, stop: int) -> bool:
        """True if the chunk's parts are complete and unchanged and were written by this
        configuration (the fingerprint in its record); others are removed, with a warning."""
        record = self.dir / f"{self._stem(start, stop)}.json"
        if not record.exists():
            return False
        try:
            sums = json.loads(record.read_text())
            ours = sums.get("fingerprint") == self.fingerprint
            intact = ours and all(file_sha256(self.path(start, stop, t)) == sums[t]["sha256"]
                                  for t in self.study.tables)
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            ours = intact = False
        if not intact:
            why = ("damaged or incomplete" if ours else
                   "written by another configuration (its record's fingerprint)")
            _warn(f"{record.name}: part files {why}; units {start}-{stop - 1} are recomputed")
            record.unlink(missing_ok=True)
        return intact

    def drop_other_chunking(self, chunks: Sequence[tuple[int, int]]) -> None:
        """Remove finished chunks whose unit ranges are not among ``chunks`` (a rerun with
        another ``chunk_size``), saying how many units they held."""
        wanted = {self._stem(a, b) for a, b in chunks}
        other = [r for r in self.dir.glob("c*.json") if r.stem not in wanted]
        if not other:
            return
        units = sum(int(b) - int(a[1:]) for a, b in (r.stem.split("-") for r in other))
        _warn(f"{self.dir}: {len(other)} finished chunk(s) ({units} units) were cut with "
              "another chunk_size and are not reused; their units are recomputed (rerun with "
              "the first run's chunk_size to reuse them)")
        for record in other:
            for path in self.dir.glob(f"{record.stem}.*"):
                path.unlink(missing_ok=True)

    def write(self, start: int, stop: int, rows: dict[str, list[dict]]) -> None:
        self.writer.write(start, stop, rows)

    def layout(self, chunks: Sequence[tuple[int, int]]) -> list[dict[str, list]] | None:
        """The rows of each entrant in every table, one ``{table: [[method, n], ...]}`` per
        unit of ``chunks`` (each chunk's units alike), or None when a chunk's units differ
        (or for a study without ``method_column``)."""
        out: list[dict[str, list]] = []
        for start, stop in chunks:
            try:
                layout = json.loads((self.dir / f"{self._stem(start, stop)}.json")
                                    .read_text()).get("layout")
            except (OSError, ValueError, AttributeError):
                return None
            if not layout or any(v is None for v in layout.values()):
                return None
            out.extend([layout] * (stop - start))
        return out

    def merge_with(self, chunks: Sequence[tuple[int, int]], table: str, dest: Path,
                   staged: _Staged, computed: Sequence[Mapping[str, list]],
                   order: Sequence[str]) -> int:
        """Interleave, unit by unit, the reused rows (``staged``) and the chunks' rows
        (``computed``: each unit's ``{table: [[method, n], ...]}``, :meth:`layout`) into
        ``dest``, methods in ``order``."""
        column = self.study.method_column
        n = 0
        with atomic_path(dest) as tmp, open(tmp, "w", newline="") as out, \
                open(staged.path(table), newline="") as old:
            header = old.readline()
            out.write(header)
            index = _column_index(header, column, table in self.study.table_owner)
            old_records = _records(old)
            for start, stop in chunks:
                with open(self.path(start, stop, table), newline="") as part:
                    if part.readline() != header:
                        raise ValueError(f"{part.name}: header differs from the reused rows'")
                    new_records = _records(part)
                    for u in range(start, stop):
                        unit = _take(old_records, staged.layout(table, u), index, old.name)
                        unit.update(_take(new_records, computed[u].get(table, []), index,
                                          part.name))
                        for method in order:
                            for record in unit.get(method, ()):
                                out.write(record)
                                n += 1
            if not chunks:
                for u in range(staged.units):
                    unit = _take(old_records, staged.layout(table, u), index, old.name)
                    for method in order:
                        for record in unit.get(method, ()):
                            out.write(record)
                            n += 1
            if next(old_records, None) is not None:
                raise ValueError(f"{old.name}: more rows than its record says")
        return n

    def merge(self, chunks: Sequence[tuple[int, int]], table: str, dest: Path) -> int:
        """Concatenate the chunks' parts of ``table`` into ``dest`` on disk; rows written."""
        n = 0
        with atomic_path(dest) as tmp, open(tmp, "w") as out:
            for i, (start, stop) in enumerate(chunks):
                with open(self.path(start, stop, table)) as part:
                    header = part.readline()
                    if i == 0:
                        out.write(header)
                    for line in part:
                        out.write(line)
                        n += 1
        return n


def _layout(rows: Sequence[dict], n_units: int, column: str) -> list[list] | None:
    """``[[method, rows per unit], ...]`` when each of ``n_units`` units gave the same rows
    per method, one method after another (the rows' ``column`` repeats one pattern); else
    None, and the rows are not cached per method."""
    if n_units <= 0 or len(rows) % n_units:
        return None if rows else []
    per = len(rows) // n_units
    names = [str(r.get(column)) for r in rows]
    if names != names[:per] * n_units:
        return None
    runs: list[list] = []
    for name in names[:per]:
        if runs and runs[-1][0] == name:
            runs[-1][1] += 1
        elif any(r[0] == name for r in runs):
            return None                 # a method's rows split by another's
        else:
            runs.append([name, 1])
    return runs


def _owned_layout(rows: Sequence[dict], n_units: int, owner: str) -> list[list] | None:
    """:func:`_layout` of a table whose rows all belong to ``owner``: known for a chunk of
    one unit (or without rows); with more, nothing tells how the rows split among them."""
    if not rows:
        return []
    return [[owner, len(rows)]] if n_units == 1 else None


def _column_index(header: str, column: str | None, owned: bool) -> int | None:
    """Where ``column`` is in a table's header (None for a table owned by one entrant)."""
    return None if owned else next(csv.reader([header])).index(column)


def _count(value: int | Sequence[int], unit: int) -> int:
    """An entrant's rows in ``unit``: ``run.json`` keeps one number when every unit gives
    the same, else one per unit."""
    return int(value) if isinstance(value, int) else int(value[unit])


def _compact(counts: Sequence[int]) -> int | list[int]:
    """One number when every unit gives the same rows, else the list (for ``run.json``)."""
    return int(counts[0]) if counts and all(c == counts[0] for c in counts) else \
        [int(c) for c in counts] if counts else 0


def _records(handle: IO[str]) -> Iterator[str]:
    """The raw CSV records of ``handle`` (read with ``newline=""``), each with its line end:
    a quoted field may hold line breaks, so lines are joined while a quote is open."""
    pending = ""
    for line in handle:
        pending += line
        if pending.count('"') % 2 == 0:
            yield pending
            pending = ""
    if pending:
        yield pending


def _field(record: str, index: int) -> str:
    """Field ``index`` of one raw CSV record, as :mod:`csv` reads it. A record without a
    quote is split on its commas (what the reader does then, without its cost: a cached
    run checks every record it reuses); any other goes to the reader."""
    if '"' not in record:
        return record.rstrip("\r\n").split(",", index + 1)[index]
    return next(csv.reader(io.StringIO(record)))[index]


def _take(records: Iterator[str], layout: Sequence[tuple[str, int]], index: int | None,
          where: str) -> dict[str, list[str]]:
    """One unit's records from ``records``: ``n`` of each method of ``layout`` in turn, each
    checked to name its method in column ``index`` (None: a table owned by one entrant)."""
    unit: dict[str, list[str]] = {}
    for method, n in layout:
        got = unit.setdefault(method, [])
        for _ in range(n):
            record = next(records, None)
            if record is None:
                raise ValueError(f"{where}: fewer rows than its layout says")
            if index is not None and _field(record, index) != method:
                raise ValueError(f"{where}: a row of another method where {method}'s was due")
            got.append(record)
    return unit


class _Staged:
    """The rows a run reuses from a finished run of the same base: ``parts/reused.<table>.csv``
    (only the reused methods, unit by unit, in the study's method order) and
    ``parts/reused.json`` (the methods, their keys and rows per unit, each file's rows and
    SHA-256). Written before the finished tables are replaced, so a kill at any later point
    finds them."""

    def __init__(self, parts: _Parts) -> None:
        self.parts = parts
        self.record_path = parts.dir / "reused.json"
        self.record: dict = {}

    def path(self, table: str) -> Path:
        return self.parts.dir / f"reused.{table}.csv"

    @property
    def methods(self) -> list[str]:
        return list(self.record.get("methods", []))

    @property
    def units(self) -> int:
        return int(self.record.get("units", 0))

    def layout(self, table: str, unit: int) -> list[tuple[str, int]]:
        per = self.record["rows_per_unit"]
        return [(m, _count(per[m][table], unit)) for m in self.methods]

    def load(self, study: Study, keys: Mapping[str, str]) -> bool:
        """Take an intact ``reused.json`` of this study whose keys still hold; False (and
        the files removed) otherwise."""
        try:
            record = json.loads(self.record_path.read_text())
            ok = (record["fingerprint"] == study.fingerprint()
                  and all(keys[m]["key"] == record["keys"][m] for m in record["methods"])
                  and all(file_sha256(self.path(t)) == record["tables"][t]["sha256"]
                          for t in study.tables))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            ok = False
        if ok:
            self.record = record
            return True
        if self.record_path.exists():
            _warn(f"{self.record_path}: reused rows damaged or stale; they are taken from the "
                  "finished run again or recomputed")
        self.drop()
        return False

    def drop(self) -> None:
        self.record = {}
        self.record_path.unlink(missing_ok=True)
        for path in self.parts.dir.glob("reused.*.csv"):
            path.unlink(missing_ok=True)

    def extract(self, study: Study, source: _Source, methods: Sequence[str]) -> bool:
        """Copy ``methods``' rows out of the finished tables of ``source``; False (nothing
        staged, with a warning) if those tables do not hold what their record says."""
        order = [m for m in study.entrants() if m in methods]
        column = study.method_column
        tables = {}
        try:
            for table, (file, _) in study.tables.items():
                per = [source.methods[m]["rows_per_unit"][table] for m in source.order]
                dest = self.path(table)
                with atomic_path(dest) as tmp, open(tmp, "w", newline="") as out, \
                        open(source.folder / file, newline="") as old:
                    header = old.readline()
                    out.write(header)
                    index = _column_index(header, column, table in study.table_owner)
                    records = _records(old)
                    n = 0
                    for u in range(source.units):
                        layout = [(m, _count(v, u)) for m, v in zip(source.order, per,
                                                                    strict=True)]
                        unit = _take(records, layout, index, old.name)
                        for method in order:
                            out.writelines(unit[method])
                            n += len(unit[method])
                    if next(records, None) is not None:
                        raise ValueError(f"{old.name}: more rows than its record says")
                tables[table] = {"rows": n, "sha256": file_sha256(dest)}
        except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
            _warn(f"{source.folder}: the finished run's rows cannot be reused ({exc}); every "
                  "method is recomputed")
            self.drop()
            return False
        self.record = {"fingerprint": study.fingerprint(), "methods": order,
                       "keys": {m: source.methods[m]["key"] for m in order},
                       "rows_per_unit": {m: source.methods[m]["rows_per_unit"] for m in order},
                       "units": source.units, "tables": tables,
                       "source_fingerprint": source.fingerprint}
        write_text_atomic(json.dumps(self.record), self.record_path)
        return True


@dataclasses.dataclass
class _Source:
    """A finished run whose rows may be reused: its folder, method order and per-method
    records (``key``, ``rows_per_unit``) from its ``run.json``."""

    folder: Path
    order: list[str]
    methods: dict[str, dict]
    units: int
    fingerprint: str = ""


def _method_keys(study: Study) -> dict[str, dict] | None:
    """Each selected method's key (:meth:`Study.method_key` and its hash under ``key``), or
    None for a study without ``algorithms``."""
    if not isinstance(getattr(study, "algorithms", None), Sequence):
        return None
    out = {}
    for name in study.entrants():
        parts = study.method_key(name)
        out[name] = {**parts, "key": settings_hash(parts)}
    return out


def _finished_source(study: Study, out_dir: Path, n_units: int) -> _Source | None:
    """The finished run in ``out_dir`` if its rows can be reused by ``study``: same base, a
    per-method record, tables intact (checksums in run.json); None otherwise."""
    try:
        record = json.loads((out_dir / "run.json").read_text())
        methods = record["methods"]
        ok = (record.get("base") == study.base_fingerprint()
              and record.get("units") == n_units and isinstance(methods, dict)
              and all(isinstance(v.get("rows_per_unit"), dict) for v in methods.values()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not ok:
        return None
    files = {table: out_dir / file for table, (file, _) in study.tables.items()}
    if _changed_tables(files, record.get("tables") or {}) or not record.get("tables"):
        return None
    return _Source(out_dir, list(record.get("method_order") or methods), methods, n_units,
                   str(record.get("fingerprint", "")))


def _recorded(out_dir: Path) -> dict:
    """``run.json`` of ``out_dir`` ({} when it cannot be read)."""
    try:
        record = json.loads((out_dir / "run.json").read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def _unchanged(study: Study, out_dir: Path, keys: Mapping[str, dict] | None,
               trust_older: bool) -> bool:
    """True if the finished run in ``out_dir`` (of this fingerprint) has the study's base
    (settings and study code) and every method's key (options and code) as they are now.
    A run.json without them (an older magbench) counts as unchanged only if
    ``trust_older``."""
    record = _recorded(out_dir)
    methods = record.get("methods")
    if "base" not in record or not isinstance(methods, dict):
        return trust_older
    if record["base"] != study.base_fingerprint():
        return False
    return keys is None or all((methods.get(m) or {}).get("key") == k["key"]
                               for m, k in keys.items())


def _same_methods(study: Study, out_dir: Path, keys: Mapping[str, dict] | None) -> bool:
    """True if the finished run in ``out_dir`` has the study's base and exactly its methods,
    in its order, with their keys: it differs at most in the plugins loaded, which determine
    no row of a method it ran (the plugins' own methods have keys of their own)."""
    record = _recorded(out_dir)
    return (keys is not None and record.get("method_order") == list(keys)
            and _unchanged(study, out_dir, keys, trust_older=False)
            and _changed_tables({t: out_dir / f for t, (f, _) in study.tables.items()},
                                record.get("tables") or {}) == [])


def _method_record(study: Study, keys: Mapping[str, dict], staged: _Staged,
                   computed: Sequence[Mapping[str, list]] | None) -> dict:
    """run.json's per-method part: the base, the entrant order, each entrant's key, options
    and code hashes and rows per unit of each table (one number, or one per unit when they
    differ; absent when not known: not reusable later), and which this run reused and
    computed. ``computed``: each unit's layout (:meth:`_Parts.layout`)."""
    methods = {}
    entrants = study.entrants()
    for name in entrants:
        entry = {k: keys[name][k] for k in ("key", "options", "code")}
        if name in staged.methods:
            entry["rows_per_unit"] = staged.record["rows_per_unit"][name]
        elif computed is not None:
            entry["rows_per_unit"] = {
                t: _compact([dict(map(tuple, unit.get(t, []))).get(name, 0)
                             for unit in computed]) for t in study.tables}
        methods[name] = entry
    return {"base": study.base_fingerprint(), "method_order": entrants,
            "methods": methods, "methods_reused": staged.methods,
            "reused_from": staged.record.get("source_fingerprint", "") if staged.methods else "",
            "methods_computed": [m for m in entrants if m not in staged.methods]}


def _plan_message(out_dir: Path, reused: Sequence[str], compute: Mapping[str, str]) -> str:
    """The line that says what a cached run reuses and what it computes."""
    parts = []
    if reused:
        parts.append(f"reusing the rows of {', '.join(reused)} (unchanged)")
    if compute:
        why: dict[str, list[str]] = {}
        for name, reason in compute.items():
            why.setdefault(reason, []).append(name)
        parts.append("computing " + "; ".join(f"{', '.join(v)} ({k})" for k, v in why.items()))
    return f"{out_dir}: {'; '.join(parts) or 'nothing to compute'}"


#: Bytes of one value in a CSV row (a float in full precision and its separator), and in
#: memory when the finished table is summarised (a float64 column, the frame and one copy).
CSV_BYTES_PER_VALUE = 20
MEMORY_BYTES_PER_VALUE = 24


def _free_bytes(folder: Path) -> tuple[int, int | None]:
    """Free disk space where ``folder`` is (or would be) and the memory available (None where
    the system does not say)."""
    existing = next(p for p in [folder, *folder.parents] if p.exists())
    disk = shutil.disk_usage(existing).free
    try:
        with open("/proc/meminfo") as handle:
            info = dict(line.split(":", 1) for line in handle)
        memory = int(info["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        memory = None
    return disk, memory


def check_capacity(study: Study, units: Sequence, out_dir: Path) -> None:
    """Refuse, before any work, a run whose output would not fit on disk or in memory.

    The estimate counts the main table: its rows (:meth:`Study.estimated_rows`) times its
    columns, at :data:`CSV_BYTES_PER_VALUE` on disk twice over (the part files and the merged
    table exist together for a moment), and its rows times the columns the statistics read
    (the study's ``summary_columns`` if it names them, else all) at
    :data:`MEMORY_BYTES_PER_VALUE` in memory.

    Raises
    ------
    TooLarge
        Naming the estimate, what is free, and how to make the run smaller.
    """
    rows = study.estimated_rows(units)
    columns = next(iter(study.tables.values()))[1]
    read = getattr(study, "summary_columns", None) or columns
    disk_need = 2 * CSV_BYTES_PER_VALUE * rows * len(columns)
    memory_need = MEMORY_BYTES_PER_VALUE * rows * len(read)
    disk, memory = _free_bytes(out_dir)
    short = []
    if disk_need > disk:
        short.append(f"{_gb(disk_need)} of disk ({_gb(disk)} free at {out_dir})")
    if memory is not None and memory_need > memory:
        short.append(f"{_gb(memory_need)} of memory ({_gb(memory)} available)")
    if short:
        raise TooLarge(f"this run would write about {rows:,} rows and "
                       f"need {' and '.join(short)}; lower trials, the points or the "
                       "algorithms, or choose another results_dir")


def _gb(n: float) -> str:
    return f"{n / 1e9:.3g} GB"


def _warn(message: str) -> None:
    warnings.warn(message, RuntimeWarning, stacklevel=3)


def finished_run(study: Study, out_dir: Path | str) -> str | None:
    """What ``out_dir`` holds of a run of ``study``'s kind.

    Returns
    -------
    str or None
        None when no table of the study is there, or when the folder holds an unfinished run
        of this configuration (its ``parts/``, perhaps with tables merged just before a kill)
        to resume; ``"same"`` when its ``run.json`` records the study's fingerprint and every
        table matches the checksum and row count recorded there; ``"changed: ..."`` naming
        the tables that do not; otherwise a short description of the other run (its
        fingerprint, or why it cannot be identified).
    """
    out_dir = Path(out_dir)
    files = {table: out_dir / file for table, (file, _) in study.tables.items()}
    try:
        record = json.loads((out_dir / "run.json").read_text())
        found = record.get("fingerprint")
    except (OSError, ValueError, AttributeError):
        record, found = {}, None
    if found != study.fingerprint() and _parts_of(study, out_dir):
        return None
    if not any(f.exists() for f in files.values()):
        return None
    if found is None:
        return "a run with no readable run.json"
    if found != study.fingerprint():
        return f"a run of another configuration (fingerprint {found})"
    changed = _changed_tables(files, record.get("tables") or {})
    return f"changed: {', '.join(changed)}" if changed else "same"


def _parts_of(study: Study, out_dir: Path) -> bool:
    """True if ``out_dir/parts`` holds an unfinished run of this configuration."""
    try:
        manifest = json.loads((out_dir / "parts" / "manifest.json").read_text())
        return manifest.get("fingerprint") == study.fingerprint()
    except (OSError, ValueError, AttributeError):
        return False


def _changed_tables(files: Mapping[str, Path], recorded: Mapping[str, dict]) -> list[str]:
    """The tables that are missing or differ from the checksum and row count in run.json
    (a run.json without them, from an older magbench, is trusted as it was)."""
    changed = []
    for table, path in files.items():
        if not path.exists():
            changed.append(f"{path.name} (missing)")
        elif table in recorded and file_sha256(path) != recorded[table].get("sha256"):
            changed.append(f"{path.name} (checksum differs from run.json)")
    return changed


def _table_record(files: Mapping[str, Path], counts: Mapping[str, int]) -> dict[str, dict]:
    """For run.json: each table's file, row count and SHA-256."""
    return {table: {"file": path.name, "rows": counts[table], "sha256": file_sha256(path)}
            for table, path in files.items()}


def _run_todo(study: Study, units: list, todo: list[tuple[int, int]], parts: _Parts,
              done: Callable[[int, int, dict | None], None], n_jobs: int, backend: str,
              scheduler_address: str | None) -> None:
    """Run the unfinished chunks; a worker's death costs a rerun of the chunks under way.

    ``n_jobs=1`` runs them in one supervised child process (:func:`run_isolated`), so that a
    method that ends its process cannot end the run. With workers, a death (loky's
    ``TerminatedWorkerError``, Dask's ``KilledWorker``, anything a task raises) stops the
    pool: the chunks that were under way (their start markers) are rerun one unit at a time in
    a supervised child, which finds the call that kills and makes it a row, and the rest go
    back to the workers.
    """
    if n_jobs == 1 and backend == "loky":
        run_isolated(study, units, todo, done)
        return
    while todo:
        try:
            _run_parallel(study, units, todo, parts, done, n_jobs, backend, scheduler_address)
            return
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # a worker died or a task failed: find which, in a child
            todo = [c for c in todo if not parts.has_record(*c)]
            suspects = [c for c in todo if parts.started(*c)] or todo
            _warn(f"a worker of {study.name} stopped ({type(exc).__name__}); {len(suspects)} "
                  "chunk(s) under way are rerun one unit at a time in a supervised process")
            run_isolated(study, units, suspects, done)
            todo = [c for c in todo if c not in suspects]
            parts.clear_markers()


def _run_parallel(study: Study, units: list, todo: list[tuple[int, int]], parts: _Parts,
                  done: Callable[[int, int, dict | None], None], n_jobs: int, backend: str,
                  scheduler_address: str | None) -> None:
    """The chunks on joblib's workers or a Dask cluster, each written as it finishes."""
    from joblib import Parallel, delayed

    stops = dict(todo)
    with parallel_backend(backend, n_jobs, scheduler_address) as engine:
        if backend == "dask":
            _run_on_dask(engine["client"], study, units, todo, parts, done)
            return
        with contextlib.ExitStack() as stack:
            with _interrupt_blocked():  # the workers, their manager and tracker start here
                parallel = stack.enter_context(Parallel(
                    n_jobs=engine["n_jobs"], backend=engine["backend"],
                    return_as="generator_unordered"))
                # each worker writes the chunk it computed: the rows never cross to this
                # process, which only follows the records
                writer = parts.writer
                results = parallel(delayed(_run_chunk)(study, units[a:b], a, os.getpid(),
                                                       str(parts.marker(a, b)), writer)
                                   for a, b in todo)
            try:
                for start, rows in results:
                    done(start, stops[start], rows)
            finally:
                _close_quietly(results)


#: joblib's warning when a results generator is closed before its end (a Ctrl-C, a failed
#: write): the tasks it names are cancelled on purpose, and the run says what happened.
_CANCELLED_WARNING = r"\d+ tasks (have been successfully executed|which were still being)"


def _close_quietly(results: Iterator) -> None:
    """Close joblib's results generator here, without its warning about cancelled tasks
    (otherwise it is closed when collected, and warns after the run's one line)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_CANCELLED_WARNING, category=UserWarning)
        results.close()


def _run_on_dask(client: object, study: Study, units: list, todo: list[tuple[int, int]],
                 parts: _Parts, done: Callable[[int, int, dict | None], None]) -> None:
    """The chunks as Dask futures: a task that failed, or whose workers died (``KilledWorker``),
    raises here at once, and the tasks still pending are cancelled."""
    from distributed import as_completed

    futures = [client.submit(_run_chunk, study, units[a:b], a, None, str(parts.marker(a, b)),
                             pure=False) for a, b in todo]
    stops = dict(todo)
    try:
        for future in as_completed(futures):
            start, rows = future.result()
            done(start, stops[start], rows)
    finally:
        client.cancel(futures)


def run_study(study: Study, out_dir: Path | str, *, n_jobs: int = 1, chunk_size: int = 25,
              backend: str = "loky", scheduler_address: str | None = None,
              progress: bool = True, config: Mapping | None = None,
              overwrite: bool = False) -> dict[str, Path]:
    """Run (or finish) ``study`` and write its tables, and ``run.json``, under ``out_dir``.

    Parameters
    ----------
    study : Study
        What to run.
    out_dir : path
        The study's result folder; holds ``parts/`` while the run is unfinished.
    n_jobs : int
        joblib workers (1 runs in this process; -1 uses every core).
    chunk_size : int
        Units per task: large enough that worker start-up and data transfer are small next to
        the work, small enough that a kill loses little.
    backend, scheduler_address : str, str or None
        ``"loky"`` (processes here) or ``"dask"`` (see :func:`parallel_backend`).
    progress : bool
        Show a progress bar (stderr) with the time left.
    config : mapping, optional
        The user's configuration, recorded in ``run.json``.
    overwrite : bool
        Recompute and replace a finished run in ``out_dir`` (of this or another configuration).

    Returns
    -------
    dict
        Table name -> path of its CSV file.

    Raises
    ------
    FolderBusy
        Another run holds ``out_dir``.
    ResultsExist
        ``out_dir`` holds a finished run of another configuration and ``overwrite`` is False.
    TooLarge
        The estimated output exceeds the free disk space or memory (:func:`check_capacity`).
    """
    from tqdm import tqdm

    out_dir = Path(out_dir)
    started, clock = datetime.now(UTC), time.perf_counter()
    load_plugins(study.plugins)
    units = study.units()
    if study.ragged and study.method_column is not None:
        chunk_size = 1
    chunks = [(s, min(s + chunk_size, len(units))) for s in range(0, len(units), chunk_size)]
    written = {table: out_dir / file for table, (file, _) in study.tables.items()}
    # Only a run with trials to compute needs the room: a finished one that lacks its figures
    # or timing pass is completed whatever the disk holds (a look before the lock, so that a
    # refused run leaves nothing behind; the lock's holder looks again).
    if overwrite or finished_run(study, out_dir) != "same":
        check_capacity(study, units, out_dir)
    with _lock_for_run(out_dir):
        before = finished_run(study, out_dir)
        keys = _method_keys(study)
        if before == "same" and _unchanged(study, out_dir, keys, trust_older=not overwrite):
            print(f"{out_dir}: already holds this run (fingerprint {study.fingerprint()}, same "
                  "settings and code); its tables are reused (another results_dir= recomputes "
                  "them)", file=sys.stderr)
            return written
        if (before is not None and before.startswith("a run of another configuration")
                and study.method_column is None and _same_methods(study, out_dir, keys)):
            print(f"{out_dir}: already holds this run (the same settings, methods and code; "
                  "only the plugins loaded differ); its tables are reused", file=sys.stderr)
            return written
        if before is not None and before.startswith("changed: ") and not overwrite:
            raise ResultsExist(f"{out_dir}: {before[9:]}: the finished run's tables were "
                               "changed after it ended; pass overwrite=true to recompute them")
        cached = keys is not None and study.method_column is not None
        source = _finished_source(study, out_dir, len(units)) if cached else None
        if source is not None and before is not None and not overwrite:
            dropped = [m for m in source.order if m not in keys]
            if dropped:
                raise ResultsExist(
                    f"{out_dir} holds a run with {', '.join(dropped)}, which this run does not "
                    "select; select them too to reuse every method's rows, or choose another "
                    "results_dir= or pass overwrite=true to replace it")
        if before == "same" and source is None:
            # The same settings, but code that computes the rows changed since: stale rows
            # are recomputed, never reused, and not refused either.
            print(f"{out_dir}: the code that computes this run changed since it finished; "
                  "every row is recomputed", file=sys.stderr)
        elif before is not None and source is None and not overwrite:
            raise ResultsExist(f"{out_dir} holds {before}; choose another results_dir= or "
                               "pass overwrite=true to replace it")
        parts = _Parts(out_dir, study)
        staged = _Staged(parts)
        reasons: dict[str, str] = {}
        if cached:
            if not staged.load(study, keys) and source is not None:
                same = [m for m in study.entrants()
                        if source.methods.get(m, {}).get("key") == keys[m]["key"]]
                if same:
                    staged.extract(study, source, same)
            for name in study.entrants():
                if name in staged.methods:
                    continue
                old = (source.methods.get(name) if source else None) or {}
                reasons[name] = ("new" if not old else "code changed"
                                 if old.get("code") != keys[name]["code"] else
                                 "options changed" if old.get("options") != keys[name]["options"]
                                 else "not reusable")
        reused = staged.methods
        compute = [m for m in study.entrants() if m not in reused] if reused else None
        work = study if compute is None else study.with_methods(compute)
        if reused and compute:
            work = work.given_reused({t: staged.path(t) for t in study.tables})
        parts.fingerprint = work.fingerprint()
        if source is not None or reused:
            print(_plan_message(out_dir, reused, reasons), file=sys.stderr)
        run_chunks = chunks if compute is None or compute else []
        parts.drop_other_chunking(chunks)
        todo = [c for c in run_chunks if not parts.done(*c)]
        resumed = len(units) - sum(stop - start for start, stop in todo)
        if todo:        # before the sweep's bar: a cold numba cache says so there
            warm_methods(getattr(work, "algorithms", None) or (), progress=progress)
        weights = [study.unit_weight(u) for u in units]
        total = sum(sum(weights[a:b]) for a, b in run_chunks)
        with tqdm(total=total, desc=f"{study.name}", unit="trial", file=sys.stderr,
                  disable=not progress or not run_chunks, smoothing=0.1) as bar:
            bar.update(total - sum(sum(weights[a:b]) for a, b in todo))
            def done(start: int, stop: int, rows: dict[str, list[dict]]) -> None:
                if rows is not None:        # else the worker wrote the chunk
                    parts.write(start, stop, rows)
                bar.update(sum(weights[start:stop]))

            _run_todo(work, units, todo, parts, done, n_jobs, backend, scheduler_address)
        computed = parts.layout(run_chunks) if cached and run_chunks else []
        if reused:
            if computed is None:
                raise RuntimeError(f"{study.name}: the new methods' rows do not come one "
                                   "method after another per unit; they cannot be merged "
                                   "with the reused rows (overwrite=true recomputes all)")
            counts = {table: parts.merge_with(run_chunks, table, written[table], staged,
                                              computed, study.entrants())
                      for table in study.tables}
        else:
            counts = {table: parts.merge(chunks, table, written[table])
                      for table in study.tables}
        finished = datetime.now(UTC)
        extra = {} if keys is None else _method_record(study, keys, staged, computed)
        write_run_record(out_dir, study=study.name, fingerprint=study.fingerprint(),
                         settings=study.describe(), config=dict(config or {}),
                         n_jobs=n_jobs, backend=backend, chunk_size=chunk_size,
                         started=started.isoformat(timespec="seconds"),
                         finished=finished.isoformat(timespec="seconds"),
                         wall_s=round(time.perf_counter() - clock, 3),
                         units=len(units), units_resumed=resumed, rows=counts,
                         tables=_table_record(written, counts), **extra)
        shutil.rmtree(parts.dir)
    return written

