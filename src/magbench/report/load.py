"""The result files a report section reads: summaries, trials, timing passes, settings."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.engine.trial import H_COLUMNS, T_COLUMNS
from magbench.report.intervals import read_run
from magbench.studies.review import POINT_COLUMNS, TRUTH_COLUMNS

__all__ = ["ESTIMATE_COLUMNS", "TRIAL_COLUMNS", "load_csv", "load_trials", "sweep_delta"]

#: The columns of ``trials.csv`` the report reads (the point, the method, the error metrics);
#: the file holds more (seed, status, times, iterations, estimates), read only where needed.
TRIAL_COLUMNS = [*POINT_COLUMNS, "algorithm", "trial", "J", "J0", "meaningful", "sq_err",
                 "crb", "crb_J", "J_h", "J_T"]
#: The estimate and truth columns of ``trials.csv`` (h, T and their true values).
ESTIMATE_COLUMNS = [*H_COLUMNS, *T_COLUMNS, *TRUTH_COLUMNS]


def load_csv(results_dir: Path, name: str, file: str = "summary.csv") -> pd.DataFrame | None:
    """``<results_dir>/<name>/<file>``, or None when it is absent."""
    path = Path(results_dir) / name / file
    return pd.read_csv(path) if path.exists() else None


def load_trials(folder: Path, estimates: bool = False) -> pd.DataFrame | None:
    """The columns of ``<folder>/trials.csv`` the report needs (None when absent)."""
    path = Path(folder) / "trials.csv"
    if not path.exists():
        return None
    wanted = set(TRIAL_COLUMNS + (ESTIMATE_COLUMNS if estimates else []))
    return pd.read_csv(path, usecols=lambda c: c in wanted)


def sweep_delta(folder: Path, default: float = 0.5) -> float:
    """The robustness threshold delta of eq. (76) a sweep ran with (its ``run.json``)."""
    return (read_run(folder) or {}).get("settings", {}).get("delta", default)
