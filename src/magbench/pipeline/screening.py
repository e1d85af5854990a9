"""The screen step of ``calibrate``: the samples to fit, and the trim around the chosen fit.

Steps 1 (:func:`prepare`) and 4 (:func:`retrim`) of :mod:`magbench.pipeline.calibration`, whose
notes describe them; the screen itself is :func:`magbench.core.robust.screen`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from magbench.core.robust import Screen, norm_residuals, trimmed
from magbench.pipeline.holdout import estimate
from magbench.sources.recordings import Recording

__all__ = ["prepare", "retrim"]


def prepare(rec: Recording, current: Screen, max_samples: int | None) -> tuple[Recording, int]:
    """The samples to fit (:mod:`~magbench.pipeline.calibration`, step 1): kept by
    thinning, not outliers, then every ``s``-th of them so that at most ``max_samples``
    remain; and ``s``."""
    index = np.flatnonzero(current.work)
    stride = int(np.ceil(index.size / max_samples)) if max_samples else 1
    stride = max(1, stride)
    return rec.rows(index[::stride]), stride


def retrim(rec: Recording, current: Screen, chosen: Mapping) -> Screen:
    """The screen redone on the chosen fit's norm residuals
    (:mod:`~magbench.pipeline.calibration`, step 4)."""
    T, h = estimate(chosen)
    return trimmed(current, norm_residuals(T, h, rec.y), rec.y, centre=current.centre)
