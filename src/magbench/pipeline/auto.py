"""The automatic choice of ``python -m magbench calibrate``, for a program: :func:`calibrate_auto`.

The command and this function run the same pipeline, :func:`magbench.pipeline.calibration.\
calibrate_recording` (outlier screen, coverage, every candidate fitted and held out, the choice,
the verdict and the intervals), on the same candidates (:func:`candidate_rounds`) and the same
thinning; this function takes arrays instead of a file and returns instead of writing. What it
returns is in the safe gauge (``m = A (y - b)``, ``T = A^-1`` symmetric positive definite).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from magbench.core.geometry import check_geometry
from magbench.core.model import Calibration, as_samples
from magbench.core.uncertainty import Intervals
from magbench.core.verdict import Gate
from magbench.engine.plugins import plugin_modules
from magbench.methods.registry import get_method, methods
from magbench.pipeline.bootstrap import bootstrap_check
from magbench.pipeline.calibration import calibrate_recording
from magbench.pipeline.choice import ranking_frame
from magbench.pipeline.fitting import DEFAULT_MAX_SAMPLES
from magbench.pipeline.holdout import estimate
from magbench.pipeline.reading import MIN_COVERAGE
from magbench.pipeline.result import CalibrationResult
from magbench.pipeline.rounds import FIRST_ROUND
from magbench.sources.recordings import Recording

if TYPE_CHECKING:     # the ranking table only: calibrate imports this module, not pandas
    import pandas as pd

__all__ = ["AutoCalibration", "calibrate_auto", "candidate_rounds"]


def candidate_rounds(has_gyro: bool, chosen: str | Sequence[str] = "auto", *,
                     shipped: bool = False) -> tuple[list[str], list[str]]:
    """The first and second round of candidates (``second_round`` of
    :func:`~magbench.pipeline.calibration.calibrate_recording`).

    ``auto``: every registered method except the review's printed variants (benchmark rows,
    never a user's fit), the alignment methods (they need an accelerometer) and, without gyro
    data, the gyro-aided ones, in two rounds
    (:data:`~magbench.pipeline.rounds.FIRST_ROUND` first); ``all``: the same in one round;
    a list: those methods, in one round. ``shipped``: only the methods magbench itself
    registers (a plugin loaded in this process left out), the choice as shipped.
    """
    if not isinstance(chosen, str):
        return list(chosen), []
    every = [m for m in methods() if get_method(m).family != "variant"
             and (not shipped or not plugin_modules([m]))
             and (get_method(m).magnetometer_only
                  or (has_gyro and not get_method(m).needs_accel))]
    if chosen == "all":
        return every, []
    return ([m for m in every if m in FIRST_ROUND],
            [m for m in every if m not in FIRST_ROUND])


@dataclass(frozen=True)
class AutoCalibration:
    """The answer of :func:`calibrate_auto`.

    Attributes
    ----------
    calibration : Calibration or None
        The chosen calibration in the safe gauge (None when nothing could be chosen).
    method : str or None
        The chosen method.
    status : str
        ``PASS``, ``WARN`` or ``FAIL``.
    reason : str
        Why, in one line (the first warning, or why nothing was chosen; empty for PASS).
    verdict : dict or None
        The held-out field-error and heading-error verdict.
    intervals : Intervals or None
        95 % intervals on ``b`` and ``A``.
    choice : str
        How the method was chosen (ties, coverage limits).
    tie : list of str
        The methods that tie the best out of sample.
    warnings : list of str
        Every warning, in order.
    ranking : DataFrame
        The ranked candidates (the table ``calibrate`` prints; ``result.ranked`` holds the
        same rows as records).
    result : CalibrationResult
        Everything the pipeline found.
    """

    calibration: Calibration | None
    method: str | None
    status: str
    reason: str
    verdict: dict | None
    intervals: Intervals | None
    choice: str
    tie: list[str]
    warnings: list[str]
    ranking: pd.DataFrame
    result: CalibrationResult = field(repr=False)


def _status(result: CalibrationResult) -> tuple[str, str]:
    """The pipeline's fitness (PASS, WARN or FAIL and its first reason); FAIL without a choice."""
    if result.chosen is None or result.fitness is None:
        return "FAIL", "no method produced a calibration that can be written"
    reasons = result.fitness["reasons"]
    return str(result.fitness["status"]), str(reasons[0]) if reasons else ""


def calibrate_auto(samples: object, *, time: object = None, angular_rate: object = None,
                   candidates: str | Sequence[str] = "auto", preprocess: str = "centre",
                   options: dict | None = None, seed: int = 2021,
                   max_samples: int | None = DEFAULT_MAX_SAMPLES, bootstrap: int = 0,
                   call_timeout_s: float | None = None, gate: Gate | None = None,
                   expected_field: float | None = None) -> AutoCalibration:
    """Calibrate samples with ``calibrate``'s automatic choice (module notes).

    Parameters
    ----------
    samples : array_like, shape (K, 3)
        Magnetometer samples in time order, any unit.
    time, angular_rate : array_like, optional
        Sample times (K,) in seconds and gyroscope rates (K, 3) in rad/s; with both, the
        gyro-aided methods are candidates too.
    candidates : ``"auto"``, ``"all"`` or a list of method names
        As the ``candidates`` key of ``calibrate``.
    preprocess, options, seed, call_timeout_s
        As the keys of ``calibrate`` (``options``: method -> keyword options).
    max_samples : int or None
        After thinning by direction, longer recordings are strided to about this many
        samples, as ``calibrate`` does.
    bootstrap : int
        Block-bootstrap refits that widen the intervals where needed (0: none).
    gate : Gate, optional
        PASS / WARN / FAIL thresholds (:class:`magbench.core.verdict.Gate`, the defaults of
        ``calibrate``'s ``gate.*`` keys).
    expected_field : float, optional
        The field strength expected, in the samples' unit.

    Returns
    -------
    AutoCalibration
        The chosen calibration in the safe gauge with its status, verdict, intervals and
        choice.

    Raises
    ------
    ValueError
        Bad samples (shape, non-finite values, too few, coplanar or too little coverage).
    """
    y = as_samples(samples, min_samples=min(get_method(m).min_samples for m in methods()))
    t = None if time is None else np.asarray(time, dtype=float).reshape(-1)
    gyro = None if angular_rate is None else np.asarray(angular_rate, dtype=float)
    if (t is not None and t.shape != (y.shape[0],)) or \
            (gyro is not None and gyro.shape != y.shape):
        raise ValueError(f"time must have shape ({y.shape[0]},) and angular_rate "
                         f"({y.shape[0]}, 3), like the samples")
    check_geometry(y, min_coverage=MIN_COVERAGE, what="the samples")
    rec = Recording("samples", y, t, gyro if t is not None else None, n_rows=y.shape[0])
    first, second = candidate_rounds(rec.has_gyro, candidates)
    result = calibrate_recording(rec, first, preprocess=preprocess, options=options or {},
                                 seed=seed, call_timeout_s=call_timeout_s, bootstrap=0,
                                 second_round=second, max_samples=max_samples, gate=gate,
                                 expected_field=expected_field)
    result.bootstrap = bootstrap_check(result, bootstrap, preprocess=preprocess,
                                       options=options or {}, seed=seed)
    status, reason = _status(result)
    cal = method = None
    if result.chosen is not None:
        cal = Calibration(*estimate(result.chosen)).safe()
        method = str(result.chosen["algorithm"])
    return AutoCalibration(cal, method, status, reason, result.verdict, result.intervals,
                           result.how, list(result.tie), list(result.warnings),
                           ranking_frame(result.ranked), result)
