"""Methods that count their calls, registered only by the tests.

Loaded with ``plugins=[tests.plugins.counting]``. Each call appends the method's name as one
line to the file named by the environment variable ``MAGBENCH_COUNT_CALLS`` (when it is set),
from whatever process runs it, so a test can tell exactly which methods a run computed and
which it reused.
"""

import os

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.registry import register

#: The environment variable naming the file the calls are appended to.
CALLS_FILE = "MAGBENCH_COUNT_CALLS"


def _count(name: str) -> None:
    path = os.environ.get(CALLS_FILE)
    if path:
        with open(path, "a") as handle:
            handle.write(name + "\n")


def _fit(name: str, samples: np.ndarray, shift: float) -> Calibration:
    """The sphere's trivial fit (centre = mean, radius = RMS distance), moved by ``shift``."""
    _count(name)
    h = samples.mean(axis=0) + shift
    r = float(np.sqrt(((samples - h) ** 2).sum(axis=1).mean()))
    return Calibration(r * np.eye(3), h)


@register("counting_a", label="counting A", min_samples=5, family="extra", model="sphere")
def counting_a(samples: np.ndarray, *, shift: float = 0.0) -> Calibration:
    return _fit("counting_a", samples, shift)


@register("counting_b", label="counting B", min_samples=5, family="extra", model="sphere")
def counting_b(samples: np.ndarray, *, shift: float = 0.0) -> Calibration:
    return _fit("counting_b", samples, shift)
