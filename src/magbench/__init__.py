"""magbench: a Monte Carlo benchmarking harness for three-axis magnetometer calibration.

Reproduces Papafotis, Nikitas and Sotiriadis, "Magnetic Field Sensors' Calibration: Algorithms'
Overview and Comparison", Sensors 2021, 21, 5288, and goes beyond it.

>>> import magbench
>>> cal = magbench.calibrate(samples, "magical")   # doctest: +SKIP
>>> field = cal.apply(samples)                      # doctest: +SKIP
>>> field = magbench.MagCalibrator("fang").fit(samples).transform(samples)  # doctest: +SKIP
"""

from importlib import import_module

# ``methods`` is the subpackage, which is callable: ``magbench.methods()`` lists the names.
from magbench import methods
from magbench.methods.registry import get_method, register

__all__ = ["Calibration", "CalibrationFailed", "MagCalibrator", "calibrate", "get_method",
           "methods", "register"]
__version__ = "0.1.0"

#: Where the other public names live. They are imported on first use (PEP 562), so that
#: ``python -m magbench`` can start calibrate's picture process before pandas loads.
_PUBLIC = {"Calibration": "magbench.core.model", "CalibrationFailed": "magbench.core.model",
           "calibrate": "magbench.methods.api", "MagCalibrator": "magbench.methods.estimator"}


def __getattr__(name: str) -> object:
    if name in _PUBLIC:
        value = getattr(import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'magbench' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])
