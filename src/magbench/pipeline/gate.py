"""The gate step of ``calibrate``: the verdict, intervals and PASS / WARN / FAIL of the choice.

Step 5 of :mod:`magbench.pipeline.calibration`, whose notes describe it: :func:`judge`, the
offsets of the recording's two halves (:func:`halves_offsets`), the next candidate that passes
when the chosen one fails, and the coverage warnings.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from magbench.core.geometry import row_norms
from magbench.core.robust import corrected_norms, refusal_reason
from magbench.core.uncertainty import fisher_intervals
from magbench.core.verdict import (
    CENTRAL_SHARE,
    MAX_GAP_DEG,
    Gate,
    central_spread_of_norms,
    fitness,
    magnitude_verdict,
    noise_p95_pct,
    with_reason,
)
from magbench.methods.registry import get_method
from magbench.pipeline.choice import (
    ROBUST_ON_CAPS,
    THIN_GAP_DEG,
    Choice,
    allowed,
    could_be_worse_than_raw,
)
from magbench.pipeline.holdout import estimate, held_out_corrected
from magbench.pipeline.result import CalibrationResult
from magbench.sources.recordings import Recording

__all__ = ["halves_offsets", "judge", "offset_of"]


def judge(result: CalibrationResult, gate: Gate,
          expected_field: float | tuple[float, float] | None = None,
          heading_deg: float | None = None) -> None:
    """Verdict, model-based intervals and fitness of the choice
    (:mod:`~magbench.pipeline.calibration`, step 5); ``heading_deg``: the choice's held-out
    heading RMS against a reference attitude, when measured (recorded in the verdict and
    judged by the gate). The correction must narrow the field magnitude's spread over the
    samples left by thinning, outliers included (a still stretch, one direction, would
    otherwise weigh as much as the turns), below that of the raw samples as a share of their
    radius (:func:`magbench.core.verdict.fitness`)."""
    chosen = result.chosen
    work = result.work
    name = str(chosen["algorithm"])
    T, h = estimate(chosen)
    corrected = held_out_corrected(result.trials, work, name)
    result.verdict = (magnitude_verdict(corrected, held_out=True) if corrected is not None
                      else magnitude_verdict(np.linalg.solve(T, (work.y - h).T).T,
                                             held_out=False))
    if heading_deg is not None and not math.isfinite(heading_deg):
        heading_deg = None
    result.verdict["heading_measured_deg"] = heading_deg
    model = get_method(name).model
    result.intervals = fisher_intervals(work.y, T, h, model)
    spreads = _spreads(result.rec.y, result.screen.kept, T, h, result.screen.radius)
    noise = noise_p95_pct(result.rec.y, result.screen.radius)
    result.verdict["spread_pct"] = None if spreads is None else {
        "corrected": spreads[0], "uncorrected": spreads[1], "kept": CENTRAL_SHARE}
    result.verdict["noise_p95_pct"] = noise
    result.fitness = fitness(
        gate, p95_pct=result.verdict["field_error_pct"]["p95"],
        held_out=result.verdict["held_out"], gap_deg=result.coverage["largest_gap_deg"],
        directions=result.directions, band_deg=result.band_deg,
        field=float(np.cbrt(abs(np.linalg.det(T)))),
        radius=result.field_strength if math.isfinite(result.field_strength)
        else result.screen.radius,
        expected_field=expected_field, heading_deg=heading_deg,
        spread_pct=spreads, noise_p95_pct=noise)


def offset_of(y: np.ndarray, T: np.ndarray, h: np.ndarray, iterations: int = 8) -> np.ndarray:
    """The offset that best fits ``y`` with the shape ``T`` held: Gauss-Newton on the norm
    residuals ``|T^-1 (y - h)| - 1``, from ``h``."""
    Ti = np.linalg.inv(T)
    h = np.array(h, dtype=float)
    for _ in range(iterations):
        m = (y - h) @ Ti.T
        n = np.linalg.norm(m, axis=1)
        J = -(m / n[:, None]) @ Ti          # d(n_k)/dh
        step = np.linalg.lstsq(J, -(n - 1.0), rcond=None)[0]
        h += step
        if np.linalg.norm(Ti @ step) < 1e-9:
            break
    return h


def halves_offsets(work: Recording, T: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    """The offsets (2, 3) of the first and the second half of ``work`` (in time order), the
    shape ``T`` held (:func:`offset_of`); None when a half has fewer than 20 samples."""
    half = work.K // 2
    if half < 20:
        return None
    return np.array([offset_of(work.y[:half], T, h), offset_of(work.y[half:], T, h)])


def _halves_reason(result: CalibrationResult, gate: Gate) -> None:
    """WARN (FAIL above the gate's field-error FAIL threshold) when the second half of the
    recording contradicts the first (:func:`halves_offsets`, apart by a share of the field):
    a correction fitted on both is a compromise that holds neither state."""
    T, h = estimate(result.chosen)
    both = halves_offsets(result.work, T, h)
    change = np.nan if both is None else \
        float(np.linalg.norm(np.linalg.solve(T, both[0] - both[1])))
    result.verdict["halves_offset_change_pct"] = None if np.isnan(change) else 100 * change
    result.verdict["halves_offsets"] = None if both is None else both.tolist()
    if not 100 * change > gate.warn_error_pct:
        return
    t = result.work.t
    when = f" (t = {t[result.work.K // 2]:.1f} s splits them)" if t is not None else ""
    reason = (f"the offset moves by {100 * change:.0f} % of the field between the first and "
              f"the second half of the recording{when}: the hard iron changed, and the "
              "correction is a compromise of both states; record again in one state")
    result.fitness = with_reason(result.fitness, reason,
                                 fail=100 * change > gate.fail_error_pct, quality=True)


def _spreads(y: np.ndarray, rows: np.ndarray, T: np.ndarray, h: np.ndarray, radius: float
             ) -> tuple[float, float]:
    """:func:`~magbench.core.verdict.central_spread_pct` of the ``rows`` (a mask) of ``y``
    corrected, and uncorrected as a share of the samples' radius (the field's strength in
    their units); from the norms, a block of rows at a time, so a long recording is not
    copied."""
    return (central_spread_of_norms(corrected_norms(T, h, y, rows=rows)),
            central_spread_of_norms(row_norms(y)[rows], scale=radius))


def _next_that_passes(result: CalibrationResult, gate: Gate,
                      expected_field: float | tuple[float, float] | None,
                      headings: Mapping[str, float]) -> None:
    """When the chosen fit FAILs the gate, the next eligible candidate in the ranking that
    does not (and is not refused) is chosen instead, and the table says why; unchanged when
    none passes (a reason of the recording's, coverage say, fails them all). When the choice
    could not leave the field more spread than no correction off the recorded directions
    (:func:`~magbench.pipeline.choice.beyond_raw`), neither may the next: the FAIL then
    stands, and the raw data it leaves are better than a correction that could be worse."""
    first = result.chosen
    reason = result.fitness["reasons"][0]
    safe_only = not could_be_worse_than_raw(first)
    for row in result.ranked:
        if not row["eligible"] or row["algorithm"] == first["algorithm"] or \
                (safe_only and could_be_worse_than_raw(row)) or \
                refusal_reason(*estimate(row), result.work.y, result.screen.centre):
            continue
        trial = replace(result, choice=Choice(result.ranked, dict(row), result.how))
        judge(trial, gate, expected_field, headings.get(str(row["algorithm"])))
        if trial.fitness["status"] != "FAIL":
            ranked = [dict(r) for r in result.ranked]
            for r in ranked:
                if r["algorithm"] == first["algorithm"]:
                    r["note"] = f"fails the gate: {reason}"
            how = (f"{first['algorithm']} ranked first but fails the gate ({reason}); "
                   f"{row['algorithm']}, the next eligible one, passes")
            result.choice = Choice(ranked, dict(row), how)
            result.verdict, result.intervals = trial.verdict, trial.intervals
            result.fitness = trial.fitness
            return


def _coverage_warnings(result: CalibrationResult, named: bool) -> list[str]:
    gap = result.coverage["largest_gap_deg"]
    out = [result.coverage["warning"]] if result.coverage["warning"] else []
    if result.chosen is None:
        return out
    name = str(result.chosen["algorithm"])
    model = get_method(name).model
    if not named and gap > MAX_GAP_DEG:
        limited = ("the sphere and offset-only models" if gap > THIN_GAP_DEG else
                   f"{', '.join(ROBUST_ON_CAPS)} and the sphere and offset-only models")
        out.append(f"with a {gap:.0f} deg gap the choice was limited to {limited}; chosen "
                   f"model: {model}; not to be trusted beyond the directions recorded")
    elif named and model == "full" and not allowed(name, gap):
        out.append(f"{name} fits a {model} model, which the coverage sweep found unreliable "
                   f"with a {gap:.0f} deg gap in coverage")
    return out
