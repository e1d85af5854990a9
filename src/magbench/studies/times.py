"""Wall times kept beside the trials, not in them.

A trials file holds only what the seed determines, so the same code and seed give the same
bytes and a regenerated ``results/`` changes in git only where results change. The time of
each calibration call, which differs from run to run, goes to a sidecar table in the same row
order (``<stem>_times.csv``: the row's trial or run, its method, ``time_s``), and
:func:`with_times` puts it back when a summary needs tau.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from magbench.core.files import read_csv_columns

if TYPE_CHECKING:     # with_times only: calibrate imports this module and needs no pandas
    import pandas as pd

__all__ = ["split_times", "times_path", "with_times"]


def times_path(trials_path: Path | str) -> Path:
    """The sidecar of ``trials_path``: ``trials.csv`` -> ``trials_times.csv``."""
    path = Path(trials_path)
    return path.with_name(f"{path.name.removesuffix('.gz').removesuffix('.csv')}_times.csv")


def split_times(rows: Sequence[dict], key: str) -> tuple[list[dict], list[dict]]:
    """``rows`` without ``time_s``, and the times rows (``key``, ``algorithm``, ``time_s``)."""
    kept, times = [], []
    for row in rows:
        row = dict(row)
        times.append({key: row[key], "algorithm": row["algorithm"],
                      "time_s": row.pop("time_s")})
        kept.append(row)
    return kept, times


def with_times(trials: pd.DataFrame, trials_path: Path | str, key: str) -> pd.DataFrame:
    """``trials`` with the ``time_s`` column of its sidecar (NaN when there is none).

    Raises
    ------
    ValueError
        The sidecar does not list the same rows (another run's times).
    """
    path = times_path(trials_path)
    if "time_s" in trials or not path.exists():
        return trials if "time_s" in trials else trials.assign(time_s=float("nan"))
    times = read_csv_columns(path, [key, "algorithm", "time_s"])      # chunked: any length
    same = (len(times) == len(trials) and
            (times[key].to_numpy() == trials[key].to_numpy()).all() and
            (times["algorithm"].astype(str).to_numpy()
             == trials["algorithm"].astype(str).to_numpy()).all())
    if not same:
        raise ValueError(f"{path} does not list the rows of {trials_path}; rerun the sweep")
    return trials.assign(time_s=times["time_s"].to_numpy())
