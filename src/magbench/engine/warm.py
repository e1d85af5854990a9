"""Compile the methods' numba loops before a sweep, saying so when it takes a while.

numba compiles a method's loops at their first call and caches the machine code on disk
(:mod:`magbench.methods.algorithms._jit`), so only a first run pays. That first run used to sit
silently at 0 % of the sweep's progress bar for a minute or more. :func:`warm_methods` calls
each selected compiled method once on a small synthetic dataset in the sweep's own process,
before its workers start (they then load the cached code): with a warm cache it takes well
under a second and shows nothing; with a cold one, a line and a progress bar appear after
:data:`QUIET_S` seconds, before the sweep's own bar.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Sequence

__all__ = ["COMPILE_S", "QUIET_S", "compiled_methods", "warm_methods"]

#: A warm-up shorter than this shows nothing (loading a warm cache takes about half of it).
QUIET_S = 1.0
#: Rough seconds to compile each method's loops on one core of a 2-core Xeon (cold cache, see
#: docs/decisions.md); others count :data:`DEFAULT_COMPILE_S`. Used only for the "~N s" shown.
COMPILE_S = {"dorveaux": 11.0, "wu_shi": 8.0, "magical": 4.0, "ali": 3.0, "crassidis": 2.5,
             "vasconcelos": 2.5}
DEFAULT_COMPILE_S = 1.5


def compiled_methods(names: Sequence[str]) -> list[str]:
    """Those of ``names`` whose module, or a module of the methods' package it imports, holds
    a compiled loop (magnetometer-only methods: the warm-up has no gyro or accelerometer data
    to give the others)."""
    from magbench.engine.record import fit_module, method_modules
    from magbench.methods.registry import find_method

    out = []
    for name in names:
        spec = find_method(name)
        if spec is None or not spec.magnetometer_only:
            continue
        modules = [sys.modules.get(m) for m in method_modules(fit_module(spec.fit))]
        if any(_is_loop(v) for m in modules if m is not None for v in vars(m).values()):
            out.append(name)
    return out


def _is_loop(value: object) -> bool:
    """A compiled loop: the lazy placeholder, or the numba dispatcher that replaced it."""
    from magbench.methods.algorithms._jit import LazyLoop

    return isinstance(value, LazyLoop) or (hasattr(value, "py_func")
                                           and hasattr(value, "signatures"))


def _calls(name: str) -> list[dict]:
    """The options of the warm-up calls of ``name``: none, and a noise level if it takes one."""
    from magbench.methods.registry import get_method

    return [{}, *([{"sigma": 0.005}] if "sigma" in get_method(name).option_names() else [])]


def warm_methods(names: Sequence[str], *, progress: bool = True,
                 quiet_s: float = QUIET_S) -> float:
    """Call each compiled method of ``names`` once on a small dataset, so that its loops are
    compiled (or loaded from numba's cache) in this process; returns the seconds spent.

    A method that takes a noise level ``sigma`` is called with one too (the review's sweeps
    pass it, and numba compiles the loops again for a number where None was). A method's
    failure on the dataset is ignored (the sweep reports it). With ``progress``,
    a warm-up that lasts longer than ``quiet_s`` shows one line, "compiling the numba
    kernels, first run only, ~N s", and a progress bar, on stderr.
    """
    from tqdm import tqdm

    from magbench.core.seeding import rng
    from magbench.methods.api import calibrate
    from magbench.sources.synthetic import Point, make_dataset

    todo = compiled_methods(names)
    if not todo:
        return 0.0
    start = time.perf_counter()
    y = make_dataset(rng(0, "warm-up"), Point(K=60)).y
    expected = sum(COMPILE_S.get(n, DEFAULT_COMPILE_S) for n in todo)
    with tqdm(total=len(todo), unit="method", file=sys.stderr, disable=not progress,
              delay=quiet_s, leave=False,
              desc=f"compiling the numba kernels, first run only, ~{expected:.0f} s") as bar:
        for name in todo:
            bar.set_postfix_str(name, refresh=False)
            for options in _calls(name):
                with contextlib.suppress(Exception):
                    calibrate(y, name, raw=True, **options)
            bar.update()
    return time.perf_counter() - start
