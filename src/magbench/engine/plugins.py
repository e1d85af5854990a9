"""Plugin modules: user code that registers extra methods, imported in every process."""

from __future__ import annotations

import importlib
from collections.abc import Iterable

__all__ = ["load_plugins"]


def load_plugins(modules: Iterable[str]) -> None:
    """Import modules that register extra methods (a user's own, or the tests' faulty ones).

    Raises
    ------
    ValueError
        If a module cannot be imported (its name and the import error).
    """
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise ValueError(f"cannot import plugin module {name!r}: {exc}") from None
