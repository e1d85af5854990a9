"""Cross-method comparisons on matched datasets.

Two methods' accuracies, each over its own meaningful runs, compare different datasets: a
method that fails the hard ones is scored on the easy ones. Every comparison here is over the
runs meaningful for both methods (the same datasets), as a ratio of mean costs with its paired
bootstrap interval and the number of shared runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from magbench.report.format import format_number
from magbench.report.kept import bootstrap_paired_ratio

__all__ = ["Paired", "paired", "point_trials"]


@dataclass(frozen=True)
class Paired:
    """``mean(value of a) / mean(value of b)`` over the ``n`` runs meaningful for both."""

    ratio: float
    low: float
    high: float
    n: int

    @property
    def different(self) -> bool:
        """The 95 % paired interval excludes 1."""
        return bool(np.isfinite(self.low) and (self.high < 1 or self.low > 1))

    def text(self, digits: int = 3) -> str:
        """``0.896 [0.87, 0.92], n = 107``."""
        interval = (f" [{format_number(self.low, 2)}, {format_number(self.high, 2)}]"
                    if np.isfinite(self.low) else "")
        return f"{format_number(self.ratio, digits)}{interval}, n = {self.n}"


def point_trials(trials: pd.DataFrame, column: str, value: object) -> pd.DataFrame:
    """The rows of one sweep point (``column == value``)."""
    return trials[trials[column] == value]


def paired(trials: pd.DataFrame, a: str, b: str, value: str = "J",
           key: tuple = ()) -> Paired:
    """Method ``a`` against ``b`` on the runs of ``trials`` (one sweep point) meaningful for
    both: the ratio of their mean ``value``, its 95 % paired bootstrap interval (stream named
    by ``key``, ``a`` and ``b``) and the number of shared runs."""
    shared = _shared_runs(trials, a, b, value)
    if shared is not None:
        x, y = shared
        if len(x) == 0:
            return Paired(np.nan, np.nan, np.nan, 0)
        low, high = bootstrap_paired_ratio(x, y, *map(str, key), a, b)
        return Paired(float(x.mean() / y.mean()), low, high, len(x))
    return _paired_by_pivot(trials, a, b, value, key)


def _shared_runs(trials: pd.DataFrame, a: str, b: str, value: str
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """``a``'s and ``b``'s ``value`` on the trials meaningful for both, in trial order: the
    arrays :func:`_paired_by_pivot` takes from its pivot tables, without building them (the
    report asks for hundreds of pairs). None where the pivot's rules are not these plain
    ones (a trial twice for a method, trials that are not integers, ``a == b``)."""
    if a == b or trials["trial"].dtype.kind not in "iu":
        return None
    algorithm = trials["algorithm"].to_numpy()
    trial = trials["trial"].to_numpy()
    ok = trials["meaningful"].astype(bool).to_numpy()
    values = trials[value].to_numpy(float)
    picked = []
    for name in (a, b):
        mine = algorithm == name
        t = trial[mine]
        if len(np.unique(t)) != len(t):
            return None                 # the pivot refuses duplicates: let it say so
        picked.append((t[ok[mine]], values[mine][ok[mine]]))
    (ta, xa), (tb, xb) = picked
    common = np.intersect1d(ta, tb)
    x = xa[np.argsort(ta, kind="stable")][np.searchsorted(np.sort(ta), common)]
    y = xb[np.argsort(tb, kind="stable")][np.searchsorted(np.sort(tb), common)]
    return x, y


def _paired_by_pivot(trials: pd.DataFrame, a: str, b: str, value: str, key: tuple) -> Paired:
    """:func:`paired` by pivot tables of the two methods' rows (the rules' reference)."""
    rows = trials[trials["algorithm"].isin([a, b])]
    ok = rows.assign(meaningful=rows["meaningful"].astype(bool)).pivot(
        index="trial", columns="algorithm", values="meaningful")
    both = ok.reindex(columns=[a, b]).eq(True).all(axis=1)
    values = rows.pivot(index="trial", columns="algorithm", values=value).loc[both[both].index]
    n = int(both.sum())
    if n == 0:
        return Paired(np.nan, np.nan, np.nan, 0)
    x, y = values[a].to_numpy(float), values[b].to_numpy(float)
    low, high = bootstrap_paired_ratio(x, y, *map(str, key), a, b)
    return Paired(float(x.mean() / y.mean()), low, high, n)
