"""``python -m magbench warmup``: compile the methods' numba loops ahead of a first run.

A fresh install compiles each method's loops at its first call (about half a minute for all of
them on two cores); a sweep does that itself with a line and a progress bar
(:mod:`magbench.engine.warm`). This command does it beforehand, for whoever wants the first
sweep to start at once; a second ``warmup`` only loads the cached code.
"""

from __future__ import annotations

import sys

from omegaconf import DictConfig

__all__ = ["run_warmup"]


def run_warmup(cfg: DictConfig) -> int:
    """Compile (or load from numba's cache) the loops of the selected methods (``algorithms``,
    every method by default, plugins' included); prints what it did and how long it took."""
    from magbench.cli.config import check_common, selected_algorithms
    from magbench.engine.warm import compiled_methods, warm_methods

    common = check_common(cfg)
    names = compiled_methods(selected_algorithms(cfg))
    spent = warm_methods(names, progress=common["progress"], quiet_s=0.0)
    print(f"numba kernels ready for {len(names)} method(s) ({', '.join(names) or 'none'}) in "
          f"{spent:.1f} s; later runs load them from numba's cache", file=sys.stderr)
    return 0
