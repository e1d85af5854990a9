"""magbench: a Monte Carlo benchmarking harness for three-axis magnetometer calibration.

Reproduces Papafotis, Nikitas and Sotiriadis, "Magnetic Field Sensors' Calibration: Algorithms'
Overview and Comparison", Sensors 2021, 21, 5288, and goes beyond it.

>>> import magbench
>>> cal = magbench.calibrate(samples, "magical")   # doctest: +SKIP
>>> field = cal.apply(samples)                      # doctest: +SKIP
"""

from magbench.api import calibrate, get_method, methods, register
from magbench.model import Calibration, CalibrationFailed

__all__ = ["Calibration", "CalibrationFailed", "calibrate", "get_method", "methods", "register"]
__version__ = "0.1.0"
