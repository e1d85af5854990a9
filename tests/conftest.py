"""Shared fixtures: small seeded datasets."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.sources.synthetic import Dataset, Point, make_dataset


def dataset(seed: int = 0, **point: float) -> Dataset:
    """A dataset of Algorithm 8 at the nominal point, with overrides."""
    return make_dataset(np.random.default_rng(seed), Point(**point))


@pytest.fixture
def noise_free() -> Dataset:
    return dataset(seed=1, sigma=0.0)


@pytest.fixture
def nominal() -> Dataset:
    return dataset(seed=2)


@pytest.fixture
def blank_figures(monkeypatch):
    """Figures are written as empty files: these tests check rows, and rendering a PNG costs
    more than a tiny sweep (the figures have their own tests in tests/figures)."""
    from pathlib import Path

    from matplotlib.figure import Figure

    monkeypatch.setattr(Figure, "savefig", lambda self, fname, *a, **k: Path(fname).touch())


@pytest.fixture(scope="session", autouse=True)
def numba_loops_compiled_once():
    """Compile (or load from numba's cache) every method's loops once, before any test: on a
    fresh clone the suite pays the compilation here, once, and the processes the tests start
    load the cached code instead of compiling it again side by side."""
    from magbench.engine.warm import compiled_methods, warm_methods
    from magbench.methods.registry import methods

    warm_methods(compiled_methods(methods()), progress=False)
