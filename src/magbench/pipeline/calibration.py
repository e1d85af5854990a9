"""Calibrating one recording for a user: thinned, screened, an out-of-sample choice, a gate.

This is the screen, fit, choose and gate of ``python -m magbench calibrate`` (the package notes,
:mod:`magbench.pipeline`, list every step; the command reads, prints and writes).
:func:`calibrate_recording` runs these steps, each a small function in the module of its step:

1. :func:`~magbench.pipeline.screening.prepare` (:mod:`magbench.pipeline.screening`) -
   *thinning and the outlier screen* (:func:`magbench.core.robust.screen`):
   a centre that a still stretch cannot pull, samples thinned by direction (a still or slow
   stretch counts as one direction, not half the data), outliers set aside by the norm
   residual, never the samples that carry most of the directions; then an even stride down to
   ``max_samples``. Coverage is measured on the directions seen from that centre, which do not
   depend on any candidate's fit (:func:`magbench.core.verdict.coverage_report`).
2. :func:`~magbench.pipeline.rounds.fit_round` (:mod:`magbench.pipeline.rounds`) -
   *candidates held out*: every candidate fitted on all the kept samples
   and on each fold of interleaved time blocks, scored on the held-out blocks
   (:mod:`magbench.pipeline.holdout`). With a ``second_round`` (``calibrate``'s default), the
   closed forms and Wu-Shi NM (:data:`~magbench.pipeline.rounds.FIRST_ROUND`) are fitted first
   and the others only when :func:`~magbench.pipeline.rounds.second_round_reason` finds that
   they could change the choice: Wu-Shi NM minimises
   the NM objective (11), ``K`` times J_r (81), so no method fits the data better, and another
   can only do better out of sample (a short recording), or be needed on a cap.
   Gyro-aided candidates need an unbroken time base: they are left out when thinning removed
   samples.
3. *The choice* (:func:`magbench.pipeline.choice.choose`, called by
   :mod:`magbench.pipeline.rounds`): ranked by the mean held-out J_r over
   the folds; a simpler model wins only when it ties the best on the mean and on the worst
   fold; a gyro-aided method only when it beats the best magnetometer-only one out of sample;
   the coverage limits which models may be chosen (:func:`magbench.pipeline.choice.allowed`,
   from the coverage sweep's findings).
4. :func:`~magbench.pipeline.screening.retrim` (:mod:`magbench.pipeline.screening`) -
   *trimming around the chosen fit*: the chosen method's own norm residuals on
   every sample are screened like the sphere fit's; if that changes the inliers, steps 2-4 run
   again (at most ``rounds`` times).
5. :func:`~magbench.pipeline.gate.judge` (:mod:`magbench.pipeline.gate`) -
   *verdict, intervals and fitness*: the held-out field error of the chosen
   method (every kept sample corrected by the fold fit it was held out of), model-based 95 %
   intervals (:func:`magbench.core.uncertainty.fisher_intervals`), and PASS / WARN / FAIL from
   the thresholds of :class:`magbench.core.verdict.Gate`.
6. :func:`~magbench.pipeline.bootstrap.bootstrap_check` (:mod:`magbench.pipeline.bootstrap`) -
   *intervals that cover*: ``bootstrap`` refits on circular block
   resamples of the kept samples in time order (blocks five times the residuals'
   integrated correlation time), so time-correlated error widens the intervals; the wider of the two
   intervals is reported, and which it is.

What they fill in is a :class:`~magbench.pipeline.result.CalibrationResult`
(:mod:`magbench.pipeline.result`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from magbench.core.geometry import band_half_width, direction_cells
from magbench.core.robust import screen
from magbench.core.verdict import Gate, coverage_report
from magbench.methods.registry import get_method
from magbench.pipeline.bootstrap import bootstrap_check
from magbench.pipeline.choice import could_be_worse_than_raw
from magbench.pipeline.gate import _coverage_warnings, _halves_reason, _next_that_passes, judge
from magbench.pipeline.result import CalibrationResult
from magbench.pipeline.rounds import ExtraScore, _fit_and_choose, agreed_field
from magbench.pipeline.screening import prepare, retrim
from magbench.sources.recordings import Recording

__all__ = ["calibrate_recording"]


def calibrate_recording(rec: Recording, candidates: Sequence[str], *,
                        preprocess: str = "centre", options: dict | None = None,
                        seed: int = 0, call_timeout_s: float | None = None,
                        bootstrap: int = 50, rounds: int = 3,
                        second_round: Sequence[str] = (), max_samples: int | None = None,
                        gate: Gate | None = None,
                        expected_field: float | tuple[float, float] | None = None,
                        extra: ExtraScore | None = None) -> CalibrationResult:
    """Thin, screen, fit, choose, trim and judge (module notes).

    Parameters
    ----------
    rec : Recording
        The whole recording, in time order.
    candidates : sequence of str
        Methods to fit; with one, it is the choice unless it is refused or not meaningful.
    preprocess, options, seed, call_timeout_s
        As in :func:`magbench.pipeline.fitting.evaluate_recording`.
    bootstrap : int
        Block-bootstrap refits of the chosen method (0: none;
        :func:`~magbench.pipeline.bootstrap.bootstrap_check`).
    rounds : int
        Largest number of fit-and-trim rounds.
    second_round : sequence of str
        Methods fitted only when :func:`~magbench.pipeline.rounds.second_round_reason` says
        they could change the choice; their names end in ``result.not_fitted`` otherwise.
    max_samples : int, optional
        Fit at most about this many samples (an even stride after thinning).
    gate : Gate, optional
        Fitness thresholds (default :class:`~magbench.core.verdict.Gate`).
    expected_field : float or (low, high), optional
        The field strength expected, in the recording's units.
    extra : callable, optional
        Another score for the choice: ``extra(summary, trials, work) -> (column, values)``
        (a summary row's ``choosable``: eligible on every other ground),
        one value per row of ``summary`` (lower is better); a simpler model must tie on it too
        (:func:`magbench.pipeline.choice.choose`'s ``scores``). When it has a ``scores``
        mapping (method -> held-out heading RMS, deg, as
        :class:`magbench.pipeline.alignment.DirectionVeto`), the choice's entry goes to the
        gate.
    """
    options = options or {}
    current = screen(rec.y)
    screened = int((~current.inliers).sum())
    named = len(candidates) == 1 and not second_round
    names, later, escalated = list(candidates), list(second_round), ""
    skipped: list[str] = []
    if current.thinned:
        skipped = [n for n in names + later if get_method(n).needs_gyro]
        names = [n for n in names if n not in skipped]
        later = [n for n in later if n not in skipped]
    fit = dict(preprocess=preprocess, options=options, seed=seed, call_timeout_s=call_timeout_s)
    for _ in range(rounds):
        work, stride = prepare(rec, current, max_samples)
        cover = coverage_report(work.y - current.centre)
        trials, choice, reason = _fit_and_choose(
            work, current.centre, names, later, cover["largest_gap_deg"], named, fit, extra,
            current.radius, (gate or Gate()).fail_field_pct)
        if reason:
            names, later, escalated = names + later, [], reason
        if choice.chosen is None:
            break
        new = retrim(rec, current, choice.chosen)
        if np.array_equal(new.inliers, current.inliers) or new.work.sum() < 0.5 * \
                current.work.sum():
            break
        current = new
    result = CalibrationResult(
        rec, current, stride, work, cover, trials, choice,
        directions=int(np.unique(direction_cells(work.y - current.centre)).size),
        band_deg=band_half_width(work.y - current.centre), not_fitted=later + skipped,
        second_round=escalated, screened=screened,
        field_strength=agreed_field(choice.ranked, current.radius))
    if not current.applied:
        result.warnings.append("the outlier screen would have removed most directions: "
                               "not applied")
    if skipped:
        result.warnings.append(f"gyro-aided methods not fitted ({', '.join(skipped)}): "
                               f"{current.thinned} samples were thinned by direction, which "
                               "breaks their time base")
    result.warnings += _coverage_warnings(result, named)
    if result.chosen is None:
        return result
    scores = getattr(extra, "scores", {})
    judge(result, gate or Gate(), expected_field, scores.get(str(result.chosen["algorithm"])))
    if result.fitness["status"] == "FAIL" and not named:
        _next_that_passes(result, gate or Gate(), expected_field, scores)
    _halves_reason(result, gate or Gate())
    if result.fitness["status"] != "FAIL" and could_be_worse_than_raw(result.chosen):
        chosen = result.chosen
        result.warnings.append(
            f"{chosen['algorithm']} could leave the field {chosen['beyond_raw_pct']:.2f} points "
            f"more spread than no correction on the directions not recorded (if "
            f"{chosen['beyond_raw_if']}'s model is the sensor's), as could every other fit "
            "that could be written; record every direction for a correction that cannot")
    result.bootstrap = bootstrap_check(result, bootstrap, preprocess=preprocess,
                                       options=options, seed=seed)
    return result
