"""Units run in a supervised child process: a method that kills its process becomes a row.

A method may end the process it runs in (``os._exit``, a segmentation fault in compiled code,
the kernel's out-of-memory killer) or hold the interpreter in one compiled call long past its
time limit, where no Python-level timer can stop it. The process that runs the sweep must
survive both and record them as data. :func:`run_isolated` runs chunks of units in one child
process that tells its parent, over a pipe, which unit starts and which method is called; the
parent waits with a deadline of the call's time limit plus a grace. When the child dies (or
the deadline passes and the parent ends it), the call that was running is known: the unit is
run again in a fresh child with that call skipped (its row says why), and the run goes on.

The child is forked where the system allows it (it starts in milliseconds with everything the
parent imported); elsewhere it is spawned and imports the study's plugins itself.

:func:`map_supervised` is the same mechanism for work that is not a sweep's trials (the timing
pass, ``bench``, ``calibrate``'s candidates): any function of a unit whose method calls go
through :func:`magbench.engine.trial.run_method`.
"""

from __future__ import annotations

import contextlib
import ctypes
import faulthandler
import multiprocessing
import os
import signal
import sys
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from magbench.engine.plugins import load_plugins
from magbench.engine.trial import is_supervised, supervise_calls

__all__ = ["WorkerDied", "die_with_parent", "map_supervised", "run_isolated", "watch_calls"]

#: Seconds a call may run past its own time limit (and at least as long again) before its
#: process is ended: a loaded machine may delay the limit's own timer, never by this much.
GRACE_S = 5.0


def hard_limit(limit: float) -> float:
    """When a call with time limit ``limit`` has its process ended."""
    return limit + max(GRACE_S, limit)


class WorkerDied(RuntimeError):
    """A unit ended its process outside any method call (the study itself failed there)."""


@dataclass(frozen=True)
class _Death:
    index: int
    method: str | None
    reason: str


def die_with_parent() -> None:
    """Ask the kernel to end this process when its parent dies (Linux's parent-death signal).

    Unlike a thread that polls the parent, this needs no interpreter lock, so it also ends a
    worker stuck in one long compiled call. Elsewhere it does nothing.
    """
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)          # PR_SET_PDEATHSIG = 1


_DEVNULL: list = []


def watch_calls() -> None:
    """In a worker of a pool: end the process if one call holds it past :func:`hard_limit`
    (a compiled call that never returns to Python, where the limit's own timer
    cannot act). The watchdog is faulthandler's thread, which needs no interpreter lock; the
    run sees a dead worker and finds the call again in a supervised child."""
    if not _DEVNULL:
        _DEVNULL.append(open(os.devnull, "w"))      # open for the process's life

    def arm(name: str, limit: float | None) -> None:
        if limit:
            faulthandler.dump_traceback_later(hard_limit(limit), exit=True, file=_DEVNULL[0])

    supervise_calls(arm, after_call=faulthandler.cancel_dump_traceback_later)


def _context() -> multiprocessing.context.BaseContext:
    """Fork on Linux (fast, inherits the parent's imports); spawn elsewhere."""
    method = "fork" if sys.platform.startswith("linux") else "spawn"
    return multiprocessing.get_context(method)


def _child_main(study: object, units: Sequence, conn: object, parent: int) -> None:
    """The child: run the units the parent asks for, reporting each unit and call."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # the parent handles Ctrl-C
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    faulthandler.disable()          # a death is reported as a row, not as a traceback dump
    die_with_parent()
    if os.getppid() != parent:
        os._exit(1)
    load_plugins(study.plugins)

    def before(name: str, limit: float | None) -> None:
        conn.send(("call", name, limit))

    def after() -> None:
        conn.send(("called", None, None))

    while True:
        request = conn.recv()
        if request is None:
            return
        for index, skip in request:
            conn.send(("unit", index, None))
            supervise_calls(before, skip, after_call=after)
            try:
                rows = study.run_unit(units[index])
            except BaseException as exc:  # the parent raises it (the study's own failure)
                conn.send(("error", index, _picklable(exc)))
                return
            conn.send(("rows", index, rows))


def _picklable(exc: BaseException) -> BaseException:
    import pickle

    try:
        pickle.dumps(exc)
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


class _Child:
    """One supervised child process and the pipe to it."""

    def __init__(self, study: object, units: Sequence) -> None:
        context = _context()
        self.conn, child_conn = context.Pipe()
        self.proc = context.Process(target=_child_main, daemon=True,
                                    args=(study, units, child_conn, os.getpid()))
        self.proc.start()
        child_conn.close()

    def run(self, requests: list[tuple[int, dict]]) -> Iterator[tuple[int, dict]]:
        """Rows of each requested unit, in order; raises :class:`_DeathSignal` on a death."""
        self.conn.send(requests)
        unit, method, deadline, limit = None, None, None, None
        remaining = len(requests)
        while remaining:
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            if not self.conn.poll(wait):
                self.stop()
                raise _DeathSignal(_Death(unit, method, _timeout_reason(limit)))
            try:
                event, index, payload = self.conn.recv()
            except (EOFError, OSError):
                raise _DeathSignal(_Death(unit, method, self._exit_reason())) from None
            if event in ("unit", "called"):
                unit = index if event == "unit" else unit
                method, deadline = None, None
            elif event == "call":
                method, limit = index, payload
                deadline = None if not limit else time.monotonic() + hard_limit(limit)
            elif event == "rows":
                remaining -= 1
                method, deadline = None, None
                yield index, payload
            else:
                self.stop()
                raise _UnitFailed(index, payload)

    def _exit_reason(self) -> str:
        self.proc.join(timeout=10)
        code = self.proc.exitcode
        if code is not None and code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = "unknown"
            return f"worker died: signal {-code} ({name})"
        return f"worker died: exit code {code}"

    def stop(self) -> None:
        """End the child now (it may be stuck in a call that ignores everything else)."""
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(timeout=10)
        self.conn.close()

    def close(self) -> None:
        """Let the child finish normally."""
        with contextlib.suppress(OSError, BrokenPipeError):
            self.conn.send(None)
        self.proc.join(timeout=10)
        self.stop()


class _UnitFailed(Exception):
    """The study (not a method) raised in the child on unit ``index``."""

    def __init__(self, index: int, error: BaseException) -> None:
        super().__init__(f"{type(error).__name__}: {error}")
        self.index, self.error = index, error


class _DeathSignal(Exception):
    def __init__(self, death: _Death) -> None:
        super().__init__(death.reason)
        self.death = death


def _timeout_reason(limit: float | None) -> str:
    return (f"CallTimeout: call exceeded call_timeout_s = {limit:g} s inside one compiled "
            "call; its worker process was ended")


def run_isolated(study: object, units: Sequence, chunks: Sequence[tuple[int, int]],
                 done: Callable[[int, int, dict[str, list[dict]]], None]) -> int:
    """Run ``chunks`` of ``units`` in a supervised child; ``done(start, stop, rows)`` per chunk.

    A call that ends the child is not made again on that unit: the unit is rerun in a fresh
    child with that method's row saying why (``worker died: signal 11 (SIGSEGV)``, or the
    time limit for a call that held the child past it), and the chunk goes on.

    Returns
    -------
    int
        How many times a child died (0 on a clean run).

    Raises
    ------
    WorkerDied
        A unit ended its process outside any method call.
    """
    child, deaths = None, 0
    skip: dict[int, dict[str, str]] = {}
    finished = False
    try:
        for start, stop in chunks:
            rows: dict[int, dict] = {}
            while len(rows) < stop - start:
                child = child or _Child(study, units)
                todo = [(i, skip.get(i, {})) for i in range(start, stop) if i not in rows]
                try:
                    for index, unit_rows in child.run(todo):
                        rows[index] = unit_rows
                except _UnitFailed as failed:
                    child = None
                    rows[failed.index] = _run_here(study, units, failed, skip)
                except _DeathSignal as signal_:
                    child, deaths = None, deaths + 1
                    death = signal_.death
                    if death.method is None:
                        raise WorkerDied(f"unit {death.index} of {study.name} ended its process "
                                         f"outside any method call ({death.reason})") from None
                    skip.setdefault(death.index, {})[death.method] = death.reason
            done(start, stop, _concat(study, [rows[i] for i in range(start, stop)]))
        finished = True
    finally:
        if child is not None:
            # After an interruption the child may be inside a long call: end it now rather
            # than wait for it.
            child.close() if finished else child.stop()
    return deaths


def _run_here(study: object, units: Sequence, failed: _UnitFailed,
              skip: dict[int, dict[str, str]]) -> dict[str, list[dict]]:
    """A unit that raised in the child, run again in this process: an interruption or an
    error that recurs here is the study's own and propagates; one that does not (a child's
    state the parent does not share) is warned of, and this run's rows are kept."""
    if isinstance(failed.error, KeyboardInterrupt):
        raise failed.error
    if isinstance(failed.error, SystemExit):
        raise WorkerDied(f"unit {failed.index} of {study.name} called exit"
                         f"({failed.error.code})") from None
    supervise_calls(skip=skip.get(failed.index, {}), worker=False)
    try:
        rows = study.run_unit(units[failed.index])
    finally:
        supervise_calls(worker=False)
    warnings.warn(f"unit {failed.index} of {study.name} failed in its supervised process "
                  f"({failed}) and ran here", RuntimeWarning, stacklevel=3)
    return rows


def _concat(study: object, per_unit: list[dict[str, list[dict]]]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {name: [] for name in study.tables}
    for unit_rows in per_unit:
        for name, table_rows in unit_rows.items():
            out[name].extend(table_rows)
    return out


@dataclass(frozen=True)
class _Mapped:
    """:func:`map_supervised`'s work seen as a study with one table of one row per unit."""

    name: str
    fn: Callable[[object], object]
    plugins: tuple[str, ...]
    tables: tuple[str, ...] = ("out",)

    def run_unit(self, unit: object) -> dict[str, list]:
        return {"out": [self.fn(unit)]}


def map_supervised(fn: Callable[[object], object], units: Sequence, *, name: str = "calls",
                   plugins: Sequence[str] = ()) -> list:
    """``[fn(unit) for unit in units]`` with every method call supervised as a trial's is.

    ``fn`` runs in a supervised child process (:func:`run_isolated`), one unit after another;
    a method call that ends or seizes the child is not made again on that unit, which is run
    again in a fresh child where that call returns an :class:`~magbench.engine.trial.Outcome`
    with the reason (``skipped``). In a process that is itself supervised (a sweep's worker or
    child) ``fn`` runs here: the calls are already contained.

    Parameters
    ----------
    fn : callable
        A function of one unit whose method calls go through
        :func:`~magbench.engine.trial.run_method`; its result must pickle. A module-level
        function or a :func:`functools.partial` of one where processes are spawned.
    units : sequence
        Its arguments.
    name : str
        What the work is called in a warning or error.
    plugins : sequence of str
        Modules a spawned child imports to register plugin methods
        (:func:`magbench.engine.plugins.plugin_modules`).

    Returns
    -------
    list
        ``fn(unit)`` of each unit, in order.

    Raises
    ------
    WorkerDied
        A unit ended its process outside any method call.
    """
    units = list(units)
    if is_supervised():
        return [fn(unit) for unit in units]
    results: list = [None] * len(units)

    def done(start: int, stop: int, rows: dict[str, list]) -> None:
        results[start:stop] = rows["out"]

    run_isolated(_Mapped(name, fn, tuple(plugins)), units,
                 [(i, i + 1) for i in range(len(units))], done)
    return results
