"""Fault-injecting methods, registered only by the tests (``plugins=[tests.plugins.faulty]``).

Each one misbehaves in one way a real method might, so the tests can prove that the harness
turns every kind of failure into a row and carries on.
"""

import time

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.registry import register


@register("faulty_raises", label="raises", min_samples=4, family="extra")
def raises(samples: np.ndarray) -> Calibration:
    raise RuntimeError("deliberate failure")


@register("faulty_nan", label="returns NaN", min_samples=4, family="extra")
def returns_nan(samples: np.ndarray) -> Calibration:
    return Calibration(np.full((3, 3), np.nan), np.zeros(3))


@register("faulty_hangs", label="hangs", min_samples=4, family="extra")
def hangs(samples: np.ndarray) -> Calibration:
    while True:
        time.sleep(1.0)


@register("faulty_slow", label="slow", min_samples=4, family="extra")
def slow(samples: np.ndarray, *, delay: float = 0.05) -> Calibration:
    """The trivial answer (I, 0), after a delay: long enough to interrupt a sweep."""
    time.sleep(delay)
    return Calibration(np.eye(3), np.zeros(3))


@register("faulty_keyerror", label="raises KeyError", min_samples=4, family="extra")
def raises_key_error(samples: np.ndarray) -> Calibration:
    """An unusual exception type: containment must not depend on the type."""
    raise KeyError("deliberate missing key")


# Methods that end or seize the process they run in, on about half of the datasets (the
# "marked" ones) and return the trivial answer (I, 0) on the others. ``faulty_marked`` fails
# in the ordinary way on exactly the same datasets: the tests compare against it.

def marked(samples: np.ndarray) -> bool:
    """True on about half of the datasets, the same for every method given the same samples."""
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(samples).tobytes()).digest()[0] % 2 == 0


def _trivial() -> Calibration:
    return Calibration(np.eye(3), np.zeros(3))


@register("faulty_marked", label="raises when marked", min_samples=4, family="extra")
def raises_when_marked(samples: np.ndarray) -> Calibration:
    if marked(samples):
        raise RuntimeError("marked dataset")
    return _trivial()


@register("faulty_exit", label="os._exit", min_samples=4, family="extra")
def exits(samples: np.ndarray) -> Calibration:
    """Ends its process at once, as a crashing extension or a stray ``os._exit`` would."""
    import os

    if marked(samples):
        os._exit(3)
    return _trivial()


@register("faulty_segfault", label="segfault", min_samples=4, family="extra")
def segfaults(samples: np.ndarray) -> Calibration:
    """Reads address 0: a segmentation fault (signal 11) in compiled code."""
    import ctypes

    if marked(samples):
        ctypes.string_at(0)
    return _trivial()


@register("faulty_memory", label="exceeds a memory limit", min_samples=4, family="extra")
def exceeds_memory(samples: np.ndarray) -> Calibration:
    """Sets a memory limit 64 MB above what the process uses and allocates 2 GB past it (what
    the kernel's out-of-memory killer would stop, without taking this machine's memory)."""
    import resource

    if marked(samples):
        size = int(open("/proc/self/statm").read().split()[0]) * resource.getpagesize()
        hard = resource.getrlimit(resource.RLIMIT_AS)[1]
        resource.setrlimit(resource.RLIMIT_AS, (size + 64 * 2**20, hard))
        np.ones(2**28)
    return _trivial()


@register("faulty_exit_exception", label="raises SystemExit", min_samples=4, family="extra")
def raises_system_exit(samples: np.ndarray) -> Calibration:
    if marked(samples):
        raise SystemExit(5)
    return _trivial()


@register("faulty_gil", label="holds the GIL", min_samples=4, family="extra")
def holds_the_interpreter(samples: np.ndarray, *, seconds: int = 30) -> Calibration:
    """One compiled call that keeps the interpreter lock and lets no signal through (libc's
    ``sleep`` through ``PyDLL``, with the timer's signal blocked): no Python-level time limit
    can stop it."""
    import ctypes
    import signal

    if marked(samples):
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
        ctypes.PyDLL(None).sleep(seconds)
    return _trivial()


@register("faulty_sigkill", label="SIGKILL", min_samples=4, family="extra")
def kills_itself(samples: np.ndarray) -> Calibration:
    """Sends its own process SIGKILL, as the kernel's out-of-memory killer would."""
    import os
    import signal

    if marked(samples):
        os.kill(os.getpid(), signal.SIGKILL)
    return _trivial()


@register("faulty_interrupt", label="raises KeyboardInterrupt", min_samples=4, family="extra")
def raises_keyboard_interrupt(samples: np.ndarray) -> Calibration:
    """Raises the exception a Ctrl-C raises, though nobody pressed one."""
    if marked(samples):
        raise KeyboardInterrupt
    return _trivial()
