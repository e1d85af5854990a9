"""What ``calibrate``'s steps fill in for one recording: :class:`CalibrationResult`.

A module of its own so that each step's module (:mod:`magbench.pipeline.calibration` lists them)
can take and return it without importing the orchestration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from magbench.core.robust import Screen
from magbench.core.uncertainty import Intervals
from magbench.pipeline.choice import Choice
from magbench.sources.recordings import Recording

__all__ = ["CalibrationResult"]


@dataclass
class CalibrationResult:
    """What :func:`magbench.pipeline.calibration.calibrate_recording` found (its notes).

    ``rec`` is the whole recording; ``screen`` its thinning and outlier masks over every
    sample; ``work`` the samples the candidates were fitted on (kept, inliers, strided).
    """

    rec: Recording
    screen: Screen
    stride: int
    work: Recording
    coverage: dict
    trials: list[dict]
    choice: Choice
    directions: int = 0
    band_deg: float = 90.0
    verdict: dict | None = None
    intervals: Intervals | None = None
    bootstrap: dict | None = None
    fitness: dict | None = None
    warnings: list[str] = field(default_factory=list)
    #: Candidates left unfitted (second round not needed, or gyro-aided after thinning).
    not_fitted: list[str] = field(default_factory=list)
    second_round: str = ""
    #: Samples set aside by the first screen and, in addition, around the chosen fit.
    screened: int = 0
    #: The field strength the candidates agree on
    #: (:func:`~magbench.pipeline.rounds.agreed_field`), NaN before a choice.
    field_strength: float = math.nan

    @property
    def inliers(self) -> np.ndarray:
        return self.screen.inliers

    @property
    def outliers(self) -> int:
        return int((~self.screen.inliers).sum())

    @property
    def trimmed(self) -> int:
        return self.outliers - self.screened

    @property
    def thinned(self) -> int:
        return self.screen.thinned

    @property
    def ranked(self) -> list[dict]:
        return self.choice.ranked

    @property
    def chosen(self) -> dict | None:
        return self.choice.chosen

    @property
    def tie(self) -> list[str]:
        return self.choice.tie

    @property
    def how(self) -> str:
        return self.choice.how
