"""The picture step of ``calibrate``: what ``calibration.png`` shows, as a job for the drawing
process (:mod:`magbench.cli.picture`, which runs :func:`magbench.figures.calibration.\
calibration_picture`): the data before and after, kept, thinned and outlying samples apart, and
the field directions covered. Building the job needs only the result and the payload, so the
drawing can start while the bootstrap refits run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from magbench.pipeline.result import CalibrationResult
from magbench.sources.recordings import Recording

__all__ = ["PICTURE_COMPRESSION", "PICTURE_DPI", "PICTURE_SAMPLES", "picture_arguments",
           "picture_job"]

#: Samples drawn in the picture: enough to show the shape, few enough to draw fast.
PICTURE_SAMPLES = 1500
#: Resolution of the picture (the sweeps' figures use 110; PNG encoding grows with its square).
PICTURE_DPI = 90
#: zlib level of the picture's PNG: 1 encodes in a third of the default's 55 ms, 18 % larger.
PICTURE_COMPRESSION = 1


def picture_job(result: CalibrationResult, payload: dict, folder: Path) -> dict:
    """:func:`~magbench.cli.picture.draw_picture`'s job for ``folder/calibration.png``."""
    return {"path": folder / "calibration.png", "dpi": PICTURE_DPI,
            "compress_level": PICTURE_COMPRESSION,
            "kwargs": picture_arguments(result, payload)}


def picture_arguments(result: CalibrationResult, payload: dict) -> dict:
    """Keyword arguments of :func:`magbench.figures.calibration.calibration_picture`: kept,
    thinned and outlying samples apart; on a FAIL the rejected correction and the first
    reason in the title. When the offset is larger than the field, the "before" row is drawn
    about the fitted centre (else the data are a small blob far from the unit circle), and its
    title says so."""
    fail = payload["status"] == "FAIL"
    fit = payload["rejected"] if fail else payload
    A = np.array(fit["A"])
    b = np.array(fit["b"])
    rec: Recording = result.rec
    step = max(1, rec.K // PICTURE_SAMPLES)
    y = rec.y[::step]
    strength = float(payload["field_strength"])
    offset = float(np.linalg.norm(b))
    if offset > strength:
        before = (y - b) / strength
        before_title = (f"before, drawn about the fitted offset (|b| = {offset / strength:.1f} "
                        "x the field), scaled to the field")
    else:
        before = y / float(np.mean(np.linalg.norm(y, axis=1)))
        before_title = None
    after = (y - b) @ A.T
    where = Path(payload["file"])
    title = f"{where.parent.name}/{where.name}: {payload['label']} ({payload['model']} model)"
    if fail:
        reason = payload["fitness"]["reasons"][0] if payload["fitness"]["reasons"] else ""
        title = f"FAIL: {reason[:110]}" + ("..." if len(reason) > 110 else "") + f"\n{title}"
    return {"before": before, "after": after, "title": title,
            "inliers": result.screen.inliers[::step], "thinned": ~result.screen.kept[::step],
            "before_title": before_title, "directions": (result.work.y - b) @ A.T,
            "gap_centre": np.array(result.coverage["gap_centre"]),
            "gap_deg": result.coverage["largest_gap_deg"]}
