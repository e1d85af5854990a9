"""magbench: a Monte Carlo benchmarking harness for three-axis magnetometer calibration.

Reproduces Papafotis, Nikitas and Sotiriadis, "Magnetic Field Sensors' Calibration: Algorithms'
Overview and Comparison", Sensors 2021, 21, 5288, and goes beyond it.

>>> import magbench
>>> cal = magbench.calibrate(samples, "magical")   # doctest: +SKIP
>>> field = cal.apply(samples)                      # doctest: +SKIP
>>> field = magbench.MagCalibrator("fang").fit(samples).transform(samples)  # doctest: +SKIP
"""

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.api import calibrate
from magbench.methods.estimator import MagCalibrator
from magbench.methods.registry import get_method, methods, register

__all__ = ["Calibration", "CalibrationFailed", "MagCalibrator", "calibrate", "get_method",
           "methods", "register"]
__version__ = "0.1.0"
