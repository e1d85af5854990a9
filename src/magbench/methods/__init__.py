"""Calibration methods: the registry, the :func:`calibrate` entry point and the algorithms."""

import sys
from importlib import import_module
from types import ModuleType

from magbench.methods.registry import Method, get_method, methods, register, unregister

__all__ = ["Method", "calibrate", "get_method", "methods", "register", "unit_scale",
           "unregister"]


def __getattr__(name: str) -> object:
    # calibrate and unit_scale load on first use: the API module brings pandas, which
    # ``python -m magbench`` should not wait for before it starts calibrate's picture process.
    if name in ("calibrate", "unit_scale"):
        value = getattr(import_module("magbench.methods.api"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'magbench.methods' has no attribute {name!r}")


class _CallablePackage(ModuleType):
    """This package, callable as :func:`~magbench.methods.registry.methods`.

    ``magbench.methods()`` is the public list of names, and ``magbench.methods`` is also this
    subpackage: with a plain function bound to that name, ``import
    magbench.methods.algorithms.wu_shi as w`` failed ("'function' object has no attribute
    'algorithms'"). A callable package serves both.
    """

    def __call__(self) -> list[str]:
        return methods()


sys.modules[__name__].__class__ = _CallablePackage
