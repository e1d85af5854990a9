"""Real recordings, review section 10.2 (Figure 6): every method on every recording.

Without a ground truth, a calibration is judged by J_r of eq. (81), the mean of
``(||m_k||^2 - 1)^2`` with ``m_k = T^-1 (y_k - h)`` (82). Loading is
:mod:`magbench.sources.recordings`; coverage and thickness are :mod:`magbench.core.geometry`.

*Preprocessing* and *fitting* are :mod:`magbench.pipeline.fitting`, which ``calibrate`` shares
(:func:`~magbench.pipeline.fitting.fit_recording`: ``scale`` divides by the mean sample norm,
the review's "remove gross scaling errors", section 10.1; ``centre`` also removes the sphere-fit
centre and radius; ``none`` passes the recording as it is).

*The sweep* (:class:`RealStudy`, ``python -m magbench sweep=real``; one work unit per
recording). Every selected method on every recording and preprocessing, three fits each: on
all samples (J_r in sample), on the
first half in time and on the second half in time, each evaluated on the other half (J_r out of
sample; time halves, not even/odd samples, because neighbouring samples of a slow hand rotation
are nearly equal and an even/odd split would test on the training data). A fit on all of one
qmc5883l recording is also evaluated on the other recording of the same sensor (cross).
Recordings longer than ``max_samples`` are thinned deterministically to every ``s``-th sample,
``s = ceil(n / max_samples)`` (a uniform stride keeps the time base uniform for the gyro methods).

*Robustness on real data* (:func:`magbench.pipeline.fitting.is_meaningful`, whose notes say
why). A fit counts as meaningful when the method ended normally, its J_r on its fit data is at
most ``sphere_factor`` (2) times the sphere fit's, and its calibrated directions keep at least
``coverage_ratio`` (0.5) of the sphere fit's coverage (J_r has a degenerate minimiser). RB % is
the share of meaningful fits among the applicable (not skipped) ones (eq. 77 in spirit);
skipped rows count neither for nor against robustness.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from magbench.core.files import file_sha256, write_csv_atomic
from magbench.engine.sweep import Study
from magbench.methods.registry import method_label
from magbench.pipeline.fitting import (
    DEFAULT_MAX_SAMPLES,
    REAL_ROW_COLUMNS,
    evaluate_recording,
    summary_records,
)
from magbench.sources.recordings import load_recording
from magbench.studies.times import split_times, with_times

if TYPE_CHECKING:     # the sweep's summaries only: importing this module needs no pandas
    import pandas as pd

__all__ = ["PARTNERS", "RealStudy", "method_summary", "recording_summary"]

#: Recordings of the same sensor: a fit on one is also evaluated on the other.
PARTNERS = {"qmc5883l_filtered": "qmc5883l_noisy", "qmc5883l_noisy": "qmc5883l_filtered"}


@dataclass(frozen=True)
class RealStudy(Study):
    """What the real-data sweep runs (see the module notes); one work unit per recording."""

    root: str
    datasets: Sequence[str]
    algorithms: Sequence[str]
    preprocess: Sequence[str] = ("scale", "centre")
    max_samples: int = DEFAULT_MAX_SAMPLES
    options: dict | None = None
    seed: int = 0
    call_timeout_s: float | None = None
    coverage_ratio: float = 0.5
    sphere_factor: float = 2.0
    plugins: Sequence[str] = ()
    name: str = "real"

    tables: ClassVar[dict] = {"trials": ("real_trials.csv", REAL_ROW_COLUMNS),
                              "times": ("real_trials_times.csv",
                                        ["dataset", "algorithm", "time_s"])}
    #: Rows cached per method: a recording's rows come method by method (each method's
    #: preprocessings and fits together); :meth:`summarize` reads them preprocessing first.
    method_column: ClassVar[str] = "algorithm"

    def units(self) -> list[str]:
        return list(self.datasets)

    def unit_weight(self, unit: str) -> int:
        return 1

    def describe(self) -> dict:
        """The settings and the SHA-256 of every recording's file: a recording edited between
        a killed run and its rerun makes another fingerprint, so no stale row is reused."""
        out = super().describe()
        out["recording_sha256"] = {name: _recording_sha256(Path(self.root) / name / "data.csv")
                                   for name in self.datasets}
        return out

    def run_unit(self, name: str) -> dict[str, list[dict]]:
        rec = load_recording(self.root, name, check=False).thinned(self.max_samples)
        partner = None
        if name in PARTNERS and PARTNERS[name] in self.datasets:
            partner = load_recording(self.root, PARTNERS[name],
                                     check=False).thinned(self.max_samples)
        rows = evaluate_recording(
            rec, self.algorithms, self.preprocess, options=self.options, seed=self.seed,
            partner=partner, call_timeout_s=self.call_timeout_s,
            coverage_ratio=self.coverage_ratio, sphere_factor=self.sphere_factor)
        order = {name: i for i, name in enumerate(self.algorithms)}
        rows, times = split_times(sorted(rows, key=lambda r: order[r["algorithm"]]), "dataset")
        return {"trials": rows, "times": times}

    def summarize(self, out_dir: Path | str) -> tuple[pd.DataFrame, pd.DataFrame]:
        """Write ``real_summary.csv`` (per recording) and ``fig6_real.csv`` (per method)."""
        import pandas as pd

        out_dir = Path(out_dir)
        trials = pd.read_csv(out_dir / "real_trials.csv", dtype={"error": str, "test_on": str},
                             keep_default_na=True)
        trials["error"] = trials["error"].fillna("")
        trials["test_on"] = trials["test_on"].fillna("")
        trials = with_times(trials, out_dir / "real_trials.csv", "dataset")
        # Preprocessing first within a recording, methods in their order (the summaries'
        # order), whatever the order of the rows in the file.
        first = {name: i for i, name in enumerate(dict.fromkeys(trials["dataset"]))}
        how = {name: i for i, name in enumerate(self.preprocess)}
        trials = trials.iloc[np.lexsort((trials["preprocess"].map(how).to_numpy(),
                                         trials["dataset"].map(first).to_numpy()))]
        trials = trials.reset_index(drop=True)
        per_recording = recording_summary(trials)
        per_method = method_summary(per_recording)
        write_csv_atomic(per_recording, out_dir / "real_summary.csv")
        write_csv_atomic(per_method, out_dir / "fig6_real.csv")
        return per_recording, per_method


def _recording_sha256(path: Path) -> str:
    """SHA-256 of a recording's file ('missing' if it is not there), read once per version of
    the file (its size and modification time) in this process."""
    try:
        stat = path.stat()
    except OSError:
        return "missing"
    return _sha256_of(str(path), stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=256)
def _sha256_of(path: str, size: int, mtime_ns: int) -> str:
    return file_sha256(path)


def recording_summary(trials: pd.DataFrame) -> pd.DataFrame:
    """One row per (recording, preprocessing, method): :func:`summary_records` as a table."""
    import pandas as pd

    return pd.DataFrame(summary_records(trials.to_dict("records")))


def method_summary(per_recording: pd.DataFrame) -> pd.DataFrame:
    """Figure 6's numbers: one row per (preprocessing, method).

    ``RB_pct`` is the share of meaningful all-samples fits among the applicable recordings;
    ``rho_in`` the mean J_r in sample over the meaningful ones (the review's "mean value of the
    cost function (81) across all the recorded datasets", restricted to meaningful fits as in
    eq. 78) and ``accuracy_in = 1 / rho_in``; ``rho_out`` and ``accuracy_out`` the same for the
    held-out J_r over the meaningful recordings that have one; ``median_ratio_in`` and
    ``median_ratio_out`` the medians over the same recordings of J_r over the sphere fit's J_r
    on the same data (scale-free: the means are dominated by the noisiest recordings).
    """
    import pandas as pd

    rows = []
    for (how, name), g in per_recording.groupby(["preprocess", "algorithm"], sort=False):
        applicable = g[~g["skipped"].astype(bool)]
        good = applicable[applicable["meaningful"].astype(bool)]
        out = good[np.isfinite(good["J_r_out"])]
        rho_in = float(good["J_r_in"].mean()) if len(good) else np.nan
        rho_out = float(out["J_r_out"].mean()) if len(out) else np.nan
        rows.append({
            "preprocess": how, "algorithm": name, "label": method_label(name),
            "n_recordings": len(g), "n_applicable": len(applicable),
            "n_meaningful": len(good), "n_out": len(out),
            "RB_pct": 100.0 * len(good) / len(applicable) if len(applicable) else np.nan,
            "rho_in": rho_in, "accuracy_in": 1.0 / rho_in if len(good) else np.nan,
            "rho_out": rho_out, "accuracy_out": 1.0 / rho_out if len(out) else np.nan,
            "median_ratio_in": float((good["J_r_in"] / good["J_r_sphere_in"]).median())
            if len(good) else np.nan,
            "median_ratio_out": float((out["J_r_out"] / out["J_r_sphere_out"]).median())
            if len(out) else np.nan,
            "tau_s": float(good["time_s"].mean()) if len(good) else np.nan,
        })
    return pd.DataFrame(rows)


#: The methods whose accuracy on a method's kept recordings is its selection's yardstick.
SELECTION_REFERENCE = ("twostep", "crassidis", "dorveaux", "vasconcelos", "ali", "wu_shi",
                       "magical")
#: A kept subset whose recordings are this much easier for the reference methods sets the bar.
SELECTION_FACTOR = 2.0


def selection_inflation(per_recording: pd.DataFrame,
                        reference: Sequence[str] = SELECTION_REFERENCE) -> pd.DataFrame:
    """How much of a method's in-sample accuracy comes from which recordings it kept.

    A method meaningful on only some recordings is scored on those (eq. 78): if they are the
    easy ones its 1/mean J_r is high whatever it does. For every (preprocessing, method) that
    kept a strict subset, the other reference methods' accuracy on that subset is set beside
    their accuracy on all the recordings they solved; ``inflation`` is the median ratio over
    them (1 = a representative subset) and ``others_on_kept`` their median accuracy on the
    subset. ``set_by_selection`` flags an inflation of at least :data:`SELECTION_FACTOR`.

    Returns
    -------
    DataFrame
        ``preprocess``, ``algorithm``, ``n_kept``, ``others_on_kept``, ``inflation``,
        ``set_by_selection``; only the methods that kept a strict, non-empty subset.
    """
    import pandas as pd

    rows = []
    usable = per_recording[~per_recording["skipped"].astype(bool)]
    for (how, name), g in usable.groupby(["preprocess", "algorithm"], sort=False):
        kept = set(g.loc[g["meaningful"].astype(bool), "dataset"])
        if not kept or len(kept) == len(g):
            continue
        same = usable[(usable["preprocess"] == how) & usable["algorithm"].isin(reference)
                      & (usable["algorithm"] != name) & usable["meaningful"].astype(bool)]
        on_kept, ratio = [], []
        for _, o in same.groupby("algorithm"):
            sub = o[o["dataset"].isin(kept)]
            if len(sub):
                on_kept.append(1.0 / sub["J_r_in"].mean())
                ratio.append(on_kept[-1] * o["J_r_in"].mean())
        inflation = float(np.median(ratio)) if ratio else np.nan
        rows.append({"preprocess": how, "algorithm": name, "n_kept": len(kept),
                     "others_on_kept": float(np.median(on_kept)) if on_kept else np.nan,
                     "inflation": inflation,
                     "set_by_selection": bool(inflation >= SELECTION_FACTOR)})
    return pd.DataFrame(rows, columns=["preprocess", "algorithm", "n_kept", "others_on_kept",
                                       "inflation", "set_by_selection"])
