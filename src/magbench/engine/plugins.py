"""Plugin modules: user code that registers extra methods, imported in every process."""

from __future__ import annotations

import importlib
from collections.abc import Iterable

__all__ = ["load_plugins", "plugin_modules"]


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


def plugin_modules(names: Iterable[str]) -> tuple[str, ...]:
    """The modules outside magbench that registered the methods ``names`` (what a spawned
    process must import to call them); unknown names are left out."""
    from magbench.methods.registry import get_method, methods

    known = set(methods())
    modules = {getattr(get_method(n).fit, "__module__", "") for n in names if n in known}
    return tuple(sorted(m for m in modules if m and m.split(".")[0] != "magbench"))
