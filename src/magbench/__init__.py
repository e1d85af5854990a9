"""magbench: a Monte Carlo benchmarking harness for three-axis magnetometer calibration.

Reproduces Papafotis, Nikitas and Sotiriadis, "Magnetic Field Sensors' Calibration: Algorithms'
Overview and Comparison", Sensors 2021, 21, 5288, and goes beyond it.

>>> import magbench
>>> cal = magbench.calibrate(samples, "magical")   # doctest: +SKIP
>>> field = cal.apply(samples)                      # doctest: +SKIP
>>> field = magbench.MagCalibrator("fang").fit(samples).transform(samples)  # doctest: +SKIP
"""

from importlib import import_module

__all__ = ["Calibration", "CalibrationFailed", "MagCalibrator", "calibrate", "get_method",
           "methods", "register"]
__version__ = "0.1.0"

#: Where the public names live. They are imported on first use (PEP 562), so that ``python -m
#: magbench`` starts calibrate's picture process before NumPy, let alone pandas, loads.
#: ``methods`` is the subpackage, which is callable: ``magbench.methods()`` lists the names.
_PUBLIC = {"Calibration": "magbench.core.model", "CalibrationFailed": "magbench.core.model",
           "calibrate": "magbench.methods.api", "MagCalibrator": "magbench.methods.estimator",
           "get_method": "magbench.methods.registry", "register": "magbench.methods.registry",
           "methods": None}


def __getattr__(name: str) -> object:
    if name == "methods":
        return import_module("magbench.methods")
    if name in _PUBLIC:
        value = getattr(import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'magbench' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])
