"""Calibration methods, one module each; importing this package registers them all.

Every module registers its ``fit`` function with
:func:`magbench.methods.registry.register`. Modules are discovered rather than listed so that
adding a method is adding one file.
"""

import importlib
import pkgutil

for _info in pkgutil.iter_modules(__path__):
    if not _info.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_info.name}")
