"""What ``calibrate`` decides for one recording, without reading or writing a file.

:func:`decide` is the part of ``python -m magbench calibrate`` between reading the file and
writing the answer: the magnetometer lag removed against the inertial streams, a hard-iron
offset that changes within the recording cut (:func:`magbench.pipeline.alignment.offset_check`),
the candidates fitted, held out and chosen
(:func:`magbench.pipeline.calibration.calibrate_recording`, with the direction veto when there
is a reference attitude), and the verdict, with the field strength checked against the
Earth's in the declared unit. The command prints and writes what it returns; the
generalisation study (:mod:`magbench.studies.generalisation`) scores it, so the study measures
the command's own choice, exit status included.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from magbench.core.exports import field_strength
from magbench.core.model import Calibration, CalibrationFailed
from magbench.core.units import UNKNOWN, UnitCheck, Units, unit_check
from magbench.core.verdict import Gate, with_reason
from magbench.pipeline.alignment import (
    DirectionVeto,
    OffsetCheck,
    align_chosen,
    inertial_source,
    lag_corrected,
    offset_check,
)
from magbench.pipeline.calibration import calibrate_recording
from magbench.pipeline.flight import usable_regressors
from magbench.pipeline.holdout import estimate
from magbench.pipeline.result import CalibrationResult
from magbench.sources.recordings import Recording

__all__ = ["EXIT_FAIL", "EXIT_NONE", "Decision", "decide", "written_correction"]

#: Exit status of a FAIL (only the reasons are written).
EXIT_FAIL = 3
#: Exit status when no method produced a calibration (a usage error: nothing written).
EXIT_NONE = 2


@dataclass
class Decision:
    """What :func:`decide` found.

    Attributes
    ----------
    rec : Recording
        The recording as fitted (lag removed, the rows of one offset kept).
    result : CalibrationResult
        The pipeline's answer (``result.chosen`` None when nothing could be chosen).
    lag_s : float
        The magnetometer lag removed, s.
    offsets : OffsetCheck or None
        The offset cut, when the offset changed within the recording.
    veto : DirectionVeto
        The held-out heading scores and vetoes (empty without an attitude).
    units : UnitCheck or None
        The chosen fit's field strength against the Earth's in the declared (or inferred)
        unit (None without a choice).
    """

    rec: Recording
    result: CalibrationResult
    lag_s: float
    offsets: OffsetCheck | None
    veto: DirectionVeto
    units: UnitCheck | None = None

    @property
    def status(self) -> str:
        """``PASS``, ``WARN``, ``FAIL``, or ``NONE`` when no method could be chosen."""
        if self.result.chosen is None or self.result.fitness is None:
            return "NONE"
        return str(self.result.fitness["status"])

    @property
    def exit_code(self) -> int:
        return {"NONE": EXIT_NONE, "FAIL": EXIT_FAIL}.get(self.status, 0)

    @property
    def written(self) -> bool:
        """Whether the command writes a correction a device may use."""
        return self.exit_code == 0


def decide(rec: Recording, candidates: Sequence[str], *, second_round: Sequence[str] = (),
           preprocess: str = "centre", options: dict | None = None, seed: int = 0,
           call_timeout_s: float | None = None, max_samples: int | None = None,
           gate: Gate | None = None, expected_field: float | None = None,
           compensate: list[str] | None = None, units: Units = UNKNOWN,
           consume: bool = False) -> Decision:
    """``calibrate``'s decision on ``rec`` (module notes); the block bootstrap is left to the
    caller (:func:`magbench.pipeline.bootstrap.bootstrap_check`). ``units``: the declared
    unit of the samples (a field strength the Earth cannot give in it is a FAIL).
    ``consume``: the caller keeps only the decision's ``rec``, so the lag's shift may be
    written over ``rec``'s samples (one copy of a long log's samples, not two)."""
    has_inertial = inertial_source(rec) != "none"
    rec, lag = lag_corrected(rec, in_place=consume) if has_inertial else (rec, 0.0)
    # An offset that follows the current, throttle or temperature is what the time-varying
    # terms fit: only without such a regressor is a changed offset a cut.
    offsets = (offset_check(rec)
               if has_inertial and not usable_regressors(rec, compensate) else None)
    if offsets is not None and not offsets.changed:
        offsets = None
    if offsets is not None:
        rec = rec.rows(np.flatnonzero(offsets.keep))
    veto = DirectionVeto()
    result = calibrate_recording(rec, candidates, preprocess=preprocess, options=options,
                                 seed=seed, call_timeout_s=call_timeout_s, bootstrap=0,
                                 second_round=second_round, max_samples=max_samples,
                                 gate=gate, expected_field=expected_field, extra=veto)
    if result.fitness is None:
        return Decision(rec, result, lag, offsets, veto)
    if offsets is not None:
        # A calibration of a minority of the recording describes a state the vehicle
        # mostly was not in: it is not written.
        result.fitness = with_reason(result.fitness, offsets.warning(),
                                     fail=offsets.kept_share < 0.5)
    check = unit_check(field_strength(Calibration(*estimate(result.chosen))), units)
    if check.fail:
        result.fitness = with_reason(result.fitness, check.fail, fail=True)
    return Decision(rec, result, lag, offsets, veto, check)


def written_correction(decision: Decision) -> Calibration | None:
    """The correction the command writes (heading-true when the inertial columns fix its
    rotation, else the safe gauge); None when it writes none."""
    if not decision.written:
        return None
    cal = Calibration(*estimate(decision.result.chosen))
    if inertial_source(decision.rec) != "none":
        try:
            cal, _ = align_chosen(cal, decision.rec, decision.result.inliers)
        except CalibrationFailed:
            pass                        # the command writes the safe gauge then, and says so
    return cal
