"""The one trial loop: run a method on one unit's data, contained, timed and seeded.

Every study (review sweeps, coverage, gyro, Wu-Shi, real recordings) calls a method through
:func:`run_method`, so a method behaves the same everywhere: any exception, a non-finite or
singular answer, a call past ``call_timeout_s`` or a stop at the iteration cap becomes an
:class:`Outcome` with a reason in ``error`` (a row with ``ok=False``), and the study goes on.
A method that raises any ``BaseException`` (``SystemExit`` included) gives a row too;
only a ``KeyboardInterrupt`` in the process that runs the sweep (the user's Ctrl-C) stops it.
Only the calibration call is timed. A randomised method gets a Generator keyed by the study's
stream, the method's name and an optional tail (:mod:`magbench.core.seeding`), so its draws do
not depend on which other methods run or on the workers.
"""

from __future__ import annotations

import contextlib
import ctypes
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from magbench.core.model import Calibration
from magbench.core.seeding import rng
from magbench.methods.registry import get_method

__all__ = ["CallTimeout", "Outcome", "estimate_columns", "is_supervised", "run_method",
           "supervise_calls", "time_limit"]

T_COLUMNS = [f"T_{i}{j}" for i in range(3) for j in range(3)]
H_COLUMNS = [f"h_{i}" for i in range(3)]


class CallTimeout(Exception):
    """A calibration call ran past ``call_timeout_s``."""


@dataclass
class _Supervision:
    """What a supervising process asked of this one (:func:`supervise_calls`)."""

    before_call: Callable[[str, float | None], None] | None = None
    after_call: Callable[[], None] | None = None
    skip: Mapping[str, str] = field(default_factory=dict)
    worker: bool = False


_SUPERVISION = _Supervision()


def supervise_calls(before_call: Callable[[str, float | None], None] | None = None,
                    skip: Mapping[str, str] | None = None, worker: bool = True,
                    after_call: Callable[[], None] | None = None) -> None:
    """Set how :func:`run_method` behaves in a worker process of a sweep.

    Parameters
    ----------
    before_call : callable, optional
        Called with the method's name and time limit just before each call, so that the
        process that supervises this one knows which call a death of this process belongs to.
    skip : mapping, optional
        Method name -> reason: calls that killed a worker on the current unit before. They are
        not made again; each gives a row with the reason.
    worker : bool
        This process is a worker: a ``KeyboardInterrupt`` from a method becomes a row here
        (the process that runs the sweep handles the user's Ctrl-C).
    """
    _SUPERVISION.before_call = before_call
    _SUPERVISION.after_call = after_call
    _SUPERVISION.skip = dict(skip or {})
    _SUPERVISION.worker = worker


def is_supervised() -> bool:
    """True in a process whose method calls a supervising process watches (a sweep's worker or
    supervised child): a call that ends this process is already contained."""
    return _SUPERVISION.before_call is not None


@contextlib.contextmanager
def _memory_limits_kept() -> Iterator[None]:
    """Put back the soft memory limits a method lowered (``resource.setrlimit``), so that one
    method's limit does not fail the calls after it in the same process."""
    try:
        import resource
    except ImportError:             # no resource limits on this system
        yield
        return
    kinds = [getattr(resource, k) for k in ("RLIMIT_AS", "RLIMIT_DATA") if hasattr(resource, k)]
    before = [resource.getrlimit(k) for k in kinds]
    try:
        yield
    finally:
        for kind, (soft, hard) in zip(kinds, before, strict=True):
            now_soft, now_hard = resource.getrlimit(kind)
            if now_soft != soft:
                with contextlib.suppress(ValueError, OSError):
                    resource.setrlimit(kind, (soft if now_hard == hard else now_hard, now_hard))


@contextlib.contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Raise :class:`CallTimeout` in the block once ``seconds`` have passed.

    In the main thread of a process (in-process runs, joblib's process workers) a real-time
    interval timer raises it from its signal handler. In any other thread (a Dask worker runs
    its tasks in threads, where signals cannot go) a timer thread raises it asynchronously in
    the working thread (``PyThreadState_SetAsyncExc``). Either way it arrives between two
    Python bytecodes: a method stuck inside one long compiled call is stopped when that call
    returns.
    """
    if not seconds:
        yield
        return
    message = f"call exceeded call_timeout_s = {seconds:g} s"
    if threading.current_thread() is not threading.main_thread():
        with _thread_time_limit(seconds, message):
            yield
        return

    def expire(signum, frame):
        raise CallTimeout(message)

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def _thread_time_limit(seconds: float, message: str) -> Iterator[None]:
    """:func:`time_limit` for a thread that is not the main one (see there)."""
    target = ctypes.c_ulong(threading.get_ident())
    lock = threading.Lock()
    state = {"active": True, "fired": False}

    def expire() -> None:
        with lock:              # never fire once the block has ended
            if state["active"]:
                state["fired"] = True
                ctypes.pythonapi.PyThreadState_SetAsyncExc(target, ctypes.py_object(CallTimeout))

    timer = threading.Timer(seconds, expire)
    timer.daemon = True
    timer.start()
    try:
        try:
            yield
        finally:
            with lock:
                state["active"] = False
            timer.cancel()
            if state["fired"]:
                # Withdraw the exception if it is still pending (the block ended just after
                # the timer fired), so it cannot surface later in unrelated code.
                ctypes.pythonapi.PyThreadState_SetAsyncExc(target, None)
    except CallTimeout:
        # The asynchronous exception is raised as a bare class: give it its message.
        raise CallTimeout(message) from None


@dataclass(frozen=True)
class Outcome:
    """What one method call gave: the estimate (if any), the reason it is not ok, the time.

    ``error`` is empty when the method ended by its own rule with a finite, invertible
    estimate; otherwise it says why (exception type and message, timeout, iteration cap). A
    capped estimate is kept in ``calibration`` (what a user would get) with ``ok=False``.
    ``time_s`` is the wall time and ``cpu_s`` the process's CPU time of the method's call
    alone (NaN when it was not made); ``skipped`` says the call was not made because it ended
    or seized a supervised process on this unit before (``error`` says how).
    """

    name: str
    calibration: Calibration | None
    error: str
    time_s: float
    cpu_s: float = float("nan")
    skipped: bool = False

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def n_iter(self) -> int:
        return 0 if self.calibration is None else self.calibration.n_iter

    @property
    def T(self) -> np.ndarray | None:
        return None if self.calibration is None else self.calibration.T

    @property
    def h(self) -> np.ndarray | None:
        return None if self.calibration is None else self.calibration.h


def run_method(name: str, fit: Callable[[dict], Calibration], *,
               options: Mapping | None = None, seed: int = 0, stream: tuple = (),
               stream_tail: tuple = (), call_timeout_s: float | None = None) -> Outcome:
    """Call ``fit(options)`` for method ``name``, contained and timed.

    Parameters
    ----------
    name : str
        A registered method (its ``randomized`` flag decides whether it gets an ``rng``).
    fit : callable
        ``fit(options) -> Calibration``: the study's way of calling the method on the unit's
        data (usually ``lambda o: calibrate(y, name, **o)``).
    options : mapping, optional
        The method's keyword options; an ``rng`` here is used as given.
    seed, stream, stream_tail : int, tuple, tuple
        A randomised method draws from ``rng(seed, *stream, name, *stream_tail)``.
    call_timeout_s : float, optional
        Time limit of the call (see :func:`time_limit`).

    Returns
    -------
    Outcome
        Never raises for a failure of the method: anything it raises becomes the reason
        (see :func:`supervise_calls` for ``KeyboardInterrupt`` and calls skipped after a
        worker's death).
    """
    opts = dict(options or {})
    spec = get_method(name)
    if spec.randomized and "rng" not in opts:
        opts["rng"] = rng(seed, *stream, name, *stream_tail)
    spec.prepare()          # numba's import is a worker's start-up, not part of the timed call
    if name in _SUPERVISION.skip:
        return Outcome(name, None, _SUPERVISION.skip[name], float("nan"), skipped=True)
    if _SUPERVISION.before_call is not None:
        _SUPERVISION.before_call(name, call_timeout_s)
    # The supervisor's messages (before_call, after_call) stay outside both clocks.
    start, cpu = time.perf_counter(), time.process_time()
    try:
        with _memory_limits_kept(), time_limit(call_timeout_s):
            cal = fit(opts)
        elapsed, cpu_s = time.perf_counter() - start, time.process_time() - cpu
    except BaseException as exc:  # failures are data: anything a method raises becomes a row
        if isinstance(exc, KeyboardInterrupt) and not _SUPERVISION.worker:
            raise
        return Outcome(name, None, f"{type(exc).__name__}: {exc}",
                       time.perf_counter() - start, time.process_time() - cpu)
    finally:
        if _SUPERVISION.after_call is not None:
            _SUPERVISION.after_call()
    if not (np.isfinite(cal.T).all() and np.isfinite(cal.h).all()):
        return Outcome(name, None, f"CalibrationFailed: {name}: estimate is not finite",
                       elapsed, cpu_s)
    error = "" if cal.converged else (cal.message or f"{name}: stopped at its iteration cap")
    return Outcome(name, cal, error, elapsed, cpu_s)


def estimate_columns(T: np.ndarray | None, h: np.ndarray | None) -> dict:
    """``h_0..h_2`` and ``T_00..T_22`` of an estimate (NaN where there is none)."""
    T = np.full((3, 3), np.nan) if T is None else np.asarray(T)
    h = np.full(3, np.nan) if h is None else np.asarray(h)
    return {**dict(zip(H_COLUMNS, h.tolist(), strict=True)),
            **dict(zip(T_COLUMNS, T.ravel().tolist(), strict=True))}
