"""Bootstrap intervals a report drew before, kept beside it (``report_intervals.json``).

A method added to a finished run leaves every other method's rows, and so their intervals,
as they were; drawing them again was a third to a half of the report's text. The report's
intervals go through the functions here: the same as :mod:`magbench.core.intervals`', and
within :func:`kept_intervals` taken from the store when everything they depend on is the
same (a digest of the values, the stream keys, the options, the code and NumPy's version).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from magbench.core import intervals as _core
from magbench.core.files import write_text_atomic

__all__ = ["bootstrap_inverse_mean", "bootstrap_mean", "bootstrap_paired_ratio",
           "kept_intervals"]


#: The intervals store of :func:`kept_intervals` while one is open (else None).
_STORE: list = [None]


class _IntervalStore:
    """Intervals computed by an earlier report, by a digest of everything that determines
    them: the function, its values, stream keys, seed, resamples and level, this module's
    code, core.intervals' and NumPy's version. ``used`` is what this report asked for, and
    what it saves."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            found = json.loads(path.read_text())
        except (OSError, ValueError):
            found = {}
        self.found = found if isinstance(found, dict) else {}
        self.used: dict[str, list[float]] = {}

    def save(self) -> None:
        write_text_atomic(json.dumps(dict(sorted(self.used.items())), indent=0), self.path)


@functools.cache
def _code_digest() -> str:
    return hashlib.sha256(Path(__file__).read_bytes() + Path(_core.__file__).read_bytes()
                          + np.__version__.encode()).hexdigest()


def _interval_key(name: str, arrays: Sequence[np.ndarray], options: tuple) -> str:
    digest = hashlib.sha256(repr((_code_digest(), name, options)).encode())
    for x in arrays:
        x = np.ascontiguousarray(x, dtype=float)
        digest.update(repr(x.shape).encode())
        digest.update(x.tobytes())
    return digest.hexdigest()


def _kept(arrays: int) -> Callable:
    """Decorator: the interval function's result from the open store (:func:`kept_intervals`)
    when its inputs (the first ``arrays`` arguments, the stream keys and the keyword options)
    were asked before, else computed and stored."""
    def wrap(func: Callable) -> Callable:
        @functools.wraps(func)
        def kept(*args: object, **kwargs: object) -> tuple[float, float]:
            store = _STORE[0]
            if store is None or not set(kwargs) <= {"seed", "resamples", "level"}:
                return func(*args, **kwargs)
            key = _interval_key(func.__name__, [np.asarray(a, dtype=float)
                                                for a in args[:arrays]],
                                (tuple(map(repr, args[arrays:])), sorted(kwargs.items())))
            if key in store.found:
                value = store.found[key]
                result = (float(value[0]), float(value[1]))
            else:
                result = func(*args, **kwargs)
            store.used[key] = [float(result[0]), float(result[1])]
            return result
        return kept
    return wrap


@contextlib.contextmanager
def kept_intervals(path: Path | str) -> Iterator[None]:
    """Within the block, the bootstrap intervals (:func:`bootstrap_inverse_mean`,
    :func:`bootstrap_mean`, :func:`bootstrap_paired_ratio`) an earlier block saved in
    ``path`` are taken from it instead of drawn again, and at its end ``path`` holds those
    the block asked for (sorted: the same inputs give the same file). Each is keyed by a
    digest of all it depends on, so an interval of rows that did not change (a method's,
    when another is added) is kept and any other is computed."""
    store = _IntervalStore(Path(path))
    previous, _STORE[0] = _STORE[0], store
    try:
        yield
    finally:
        _STORE[0] = previous
    store.save()


bootstrap_inverse_mean = _kept(arrays=1)(_core.bootstrap_inverse_mean)
bootstrap_mean = _kept(arrays=1)(_core.bootstrap_mean)
bootstrap_paired_ratio = _kept(arrays=2)(_core.bootstrap_paired_ratio)
