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
