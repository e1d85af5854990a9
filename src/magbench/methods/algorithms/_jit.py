"""The methods' compiled loops, with numba imported on their first call, not on import.

A module declares a loop with ``@njit`` from here exactly as with numba's decorator, and every
loop is compiled with the same options, ``cache=True, error_model="numpy"``: the machine code is
cached on disk next to the source, so a process compiles, or loads, each loop once, and a
division by zero gives inf or NaN as in NumPy (the methods' failure checks expect that) instead
of raising ZeroDivisionError.

Importing numba costs about 0.1 s, which registering the methods (``magbench.methods.methods()``,
``magbench --help``, a figure or report run) need not pay. So until a compiled loop is first
called, the decorator returns a :class:`LazyLoop` placeholder. The first call of any of them
imports numba, creates the real dispatchers of all loops declared so far and rebinds every
placeholder in the globals of the modules that declared loops to its dispatcher, before anything
is compiled: a compiled loop calling another one (``_common.fit_affine`` from the Dorveaux and
MAG.I.C.AL loops) then finds a numba Dispatcher as the global, as numba requires. Loops declared
after that are compiled directly.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["OPTIONS", "LazyLoop", "load", "load_for", "njit"]

#: The one set of options every compiled loop uses.
OPTIONS: dict[str, Any] = {"cache": True, "error_model": "numpy"}

_pending: list[LazyLoop] = []
_namespaces: list[dict[str, Any]] = []
_numba_jit: Callable[..., Any] | None = None
#: True once every placeholder is rebound; set last, under the lock, so that no thread calls a
#: dispatcher whose callees are still placeholders in a module's globals.
_ready = False
_lock = threading.Lock()


class LazyLoop:
    """A compiled loop before numba is imported: calling it compiles (or loads) it and runs it.

    ``py_func`` is the plain Python function, as on a numba dispatcher.
    """

    def __init__(self, py_func: Callable[..., Any]) -> None:
        self.py_func = py_func
        self.dispatcher: Any = None
        functools.update_wrapper(self, py_func)

    def __call__(self, *args: Any) -> Any:
        if not _ready:
            load()
        return self.dispatcher(*args)

    def __repr__(self) -> str:
        return f"<LazyLoop {self.py_func.__module__}.{self.py_func.__qualname__}>"


def load() -> None:
    """Import numba, create every pending loop's dispatcher and rebind the placeholders (once;
    safe from several threads)."""
    with _lock:
        if not _ready:
            _materialise()


def load_for(fit: Callable[..., Any]) -> None:
    """:func:`load`, if the module of ``fit`` (a method's fit function, or a partial of one)
    refers to a compiled loop: what its first call would do, done beforehand."""
    while isinstance(fit, functools.partial):
        fit = fit.func
    if not _ready and any(isinstance(value, LazyLoop)
                          for value in getattr(fit, "__globals__", {}).values()):
        load()


def _materialise() -> None:
    global _numba_jit, _ready
    if _numba_jit is None:
        _numba_jit = _import_njit()(**OPTIONS)
    for loop in _pending:
        loop.dispatcher = _numba_jit(loop.py_func)
    _pending.clear()
    for namespace in _namespaces:
        for name, value in list(namespace.items()):
            if isinstance(value, LazyLoop) and value.dispatcher is not None:
                namespace[name] = value.dispatcher
    _ready = True


def _import_njit() -> Callable[..., Any]:
    """``numba.njit``, imported so that a folder named ``coverage`` in the working directory
    (``results/`` has one) is not taken for coverage.py: numba uses coverage.py if it can
    import it, and a folder without ``__init__.py`` imports as an empty namespace package,
    on which numba's import fails."""
    module = sys.modules.get("coverage")
    spec = (getattr(module, "__spec__", None) if module is not None
            else importlib.util.find_spec("coverage"))
    folder = (spec is not None and spec.submodule_search_locations is not None
              and spec.origin in (None, "namespace"))
    if not folder:
        from numba import njit as numba_njit

        return numba_njit
    sys.modules["coverage"] = None      # an import of it raises ImportError for numba
    try:
        from numba import njit as numba_njit
    finally:
        if module is None:
            del sys.modules["coverage"]
        else:
            sys.modules["coverage"] = module
    return numba_njit


def njit(py_func: Callable[..., Any]) -> Any:
    """Declare a compiled loop (decorator): ``numba.njit(cache=True, error_model="numpy")``,
    applied when a compiled loop is first called (see the module notes)."""
    namespace = py_func.__globals__
    if not any(namespace is seen for seen in _namespaces):
        _namespaces.append(namespace)
    if _numba_jit is not None:
        return _numba_jit(py_func)
    loop = LazyLoop(py_func)
    _pending.append(loop)
    return loop
