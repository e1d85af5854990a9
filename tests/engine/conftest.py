"""Shared by the engine tests: the fault-injecting methods of ``tests/plugins/faulty.py``."""

from __future__ import annotations

import sys

import pytest

from magbench.methods.registry import _REGISTRY, unregister

#: The plugin module, as passed to ``plugins=[...]``.
FAULTY = "tests.plugins.faulty"


@pytest.fixture
def faulty():
    """Register the fault-injecting methods for one test, and remove them afterwards."""
    import tests.plugins.faulty  # noqa: F401

    yield
    for name in [n for n in _REGISTRY if n.startswith("faulty_")]:
        unregister(name)
    sys.modules.pop(FAULTY, None)

