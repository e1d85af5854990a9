"""Calibration methods: the registry, the :func:`calibrate` entry point and the algorithms."""

from magbench.methods.api import calibrate, unit_scale
from magbench.methods.registry import Method, get_method, methods, register, unregister

__all__ = ["Method", "calibrate", "get_method", "methods", "register", "unit_scale",
           "unregister"]
