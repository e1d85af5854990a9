"""Calibrating one recording for a user: thinned, screened, an out-of-sample choice, a gate.

This is the screen, fit, choose and gate of ``python -m magbench calibrate`` (the package notes,
:mod:`magbench.pipeline`, list every step; the command reads, prints and writes).
:func:`calibrate_recording` runs these steps, each a small function:

1. :func:`prepare` - *thinning and the outlier screen* (:func:`magbench.core.robust.screen`):
   a centre that a still stretch cannot pull, samples thinned by direction (a still or slow
   stretch counts as one direction, not half the data), outliers set aside by the norm
   residual, never the samples that carry most of the directions; then an even stride down to
   ``max_samples``. Coverage is measured on the directions seen from that centre, which do not
   depend on any candidate's fit (:func:`magbench.core.verdict.coverage_report`).
2. :func:`fit_round` - *candidates held out*: every candidate fitted on all the kept samples
   and on each fold of interleaved time blocks, scored on the held-out blocks
   (:mod:`magbench.pipeline.holdout`). With a ``second_round`` (``calibrate``'s default), the
   closed forms and Wu-Shi NM (:data:`FIRST_ROUND`) are fitted first and the others only when
   :func:`second_round_reason` finds that they could change the choice: Wu-Shi NM minimises
   the NM objective (11), ``K`` times J_r (81), so no method fits the data better, and another
   can only do better out of sample (a short recording), or be needed on a cap.
   Gyro-aided candidates need an unbroken time base: they are left out when thinning removed
   samples.
3. *The choice* (:func:`magbench.pipeline.choice.choose`): ranked by the mean held-out J_r over
   the folds; a simpler model wins only when it ties the best on the mean and on the worst
   fold; a gyro-aided method only when it beats the best magnetometer-only one out of sample;
   the coverage limits which models may be chosen (:func:`magbench.pipeline.choice.allowed`,
   from the coverage sweep's findings).
4. :func:`retrim` - *trimming around the chosen fit*: the chosen method's own norm residuals on
   every sample are screened like the sphere fit's; if that changes the inliers, steps 2-4 run
   again (at most ``rounds`` times).
5. :func:`judge` - *verdict, intervals and fitness*: the held-out field error of the chosen
   method (every kept sample corrected by the fold fit it was held out of), model-based 95 %
   intervals (:func:`magbench.core.uncertainty.fisher_intervals`), and PASS / WARN / FAIL from
   the thresholds of :class:`magbench.core.verdict.Gate`.
6. :func:`bootstrap_check` - *intervals that cover*: ``bootstrap`` refits on circular block
   resamples of the kept samples in time order (blocks five times the residuals'
   integrated correlation time), so time-correlated error widens the intervals; the wider of the two
   intervals is reported, and which it is.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from magbench.core.gauge import safe_gauge
from magbench.core.geometry import band_half_width, direction_cells, row_norms
from magbench.core.robust import (
    Screen,
    corrected_norms,
    norm_residuals,
    refusal_reason,
    screen,
    trimmed,
)
from magbench.core.seeding import rng
from magbench.core.uncertainty import (
    Intervals,
    block_length,
    block_resample,
    correlation_length,
    fisher_intervals,
    student_t95,
)
from magbench.core.verdict import (
    CENTRAL_SHARE,
    MAX_GAP_DEG,
    Gate,
    central_spread_of_norms,
    coverage_report,
    fitness,
    magnitude_verdict,
    noise_p95_pct,
    with_reason,
)
from magbench.engine.isolation import map_supervised
from magbench.engine.plugins import plugin_modules
from magbench.engine.trial import run_method
from magbench.methods.registry import get_method
from magbench.pipeline.choice import (
    ROBUST_ON_CAPS,
    SCORES,
    THIN_GAP_DEG,
    Choice,
    allowed,
    choose,
)
from magbench.pipeline.fitting import fit_recording
from magbench.pipeline.holdout import (
    estimate,
    evaluate_folds,
    fold_summary,
    held_out_corrected,
    sphere_spread,
)
from magbench.sources.recordings import Recording

__all__ = ["AGREEING_FITS", "FIRST_ROUND", "ROBUST_ON_CAPS", "THIN_GAP_DEG",
           "CalibrationResult", "agreed_field", "allowed", "bootstrap_check",
           "calibrate_recording", "estimate", "fit_round", "judge", "prepare", "retrim",
           "second_round_reason"]

#: The first round of ``calibrate``'s default candidates (module notes, step 2): the closed
#: forms of every model and the minimiser of J_r (81), Wu-Shi NM.
FIRST_ROUND = ("sphere", "twostep_hi", "diagonal", "ellipsoid", "fang", "twostep", "wu_shi_nm")
#: The method whose objective (Wu and Shi's (11)) is K times J_r (81).
J_R_MINIMISER = "wu_shi_nm"
#: ``extra(summary, trials, work) -> (column, values)``: a further score for the choice
#: (``summary`` and ``trials`` are lists of records, :mod:`magbench.pipeline.holdout`).
ExtraScore = Callable[[list[dict], list[dict], Recording], tuple[str, Sequence[float]]]


@dataclass
class CalibrationResult:
    """What :func:`calibrate_recording` found (see the module notes).

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
    #: The field strength the candidates agree on (:func:`agreed_field`), NaN before a choice.
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


def prepare(rec: Recording, current: Screen, max_samples: int | None) -> tuple[Recording, int]:
    """The samples to fit (module notes, step 1): kept by thinning, not outliers, then every
    ``s``-th of them so that at most ``max_samples`` remain; and ``s``."""
    index = np.flatnonzero(current.work)
    stride = int(np.ceil(index.size / max_samples)) if max_samples else 1
    stride = max(1, stride)
    return rec.rows(index[::stride]), stride


def fit_round(work: Recording, names: Sequence[str], *, preprocess: str, options: dict,
              seed: int, call_timeout_s: float | None) -> list[dict]:
    """Every method of ``names`` on all of ``work`` and on each fold (module notes, step 2)."""
    return evaluate_folds(work, list(names), preprocess, options=options, seed=seed,
                          call_timeout_s=call_timeout_s)


def second_round_reason(tie: Sequence[str], chosen: Mapping | None, gap_deg: float,
                        first: Sequence[str]) -> str:
    """Why the second round of candidates must be fitted, or "" (module notes, step 2)."""
    if chosen is None:
        return "no method of the first round can be chosen"
    if gap_deg > MAX_GAP_DEG:
        return (f"a {gap_deg:.0f} deg gap in coverage: the methods robust on caps "
                f"({', '.join(ROBUST_ON_CAPS)}) are needed")
    if J_R_MINIMISER in first and J_R_MINIMISER not in tie:
        return (f"{J_R_MINIMISER}, which minimises J_r (81) itself, does not tie the best out "
                "of sample (a short recording, where a regularised fit may do better)")
    return ""


def _rank_trials(trials: list[dict], work: Recording, gap_deg: float, centre: np.ndarray,
                 extra: ExtraScore | None = None, radius: float = 0.0,
                 max_field_pct: float = math.inf) -> Choice:
    summary = fold_summary(trials)
    agreed = agreed_field(summary, radius)
    summary = [{**r, **sphere_scores(trials, r, agreed)} for r in summary]
    scores = SCORES
    if extra is not None:
        column, values = extra(summary, trials, work)
        summary = [{**r, column: v} for r, v in zip(summary, values, strict=True)]
        scores = (*SCORES, column)
    corrected = {r["algorithm"]: held_out_corrected(trials, work, r["algorithm"])
                 for r in summary}
    return choose(summary, corrected, gap_deg, scores=scores, max_field_pct=max_field_pct,
                  refuse=lambda row: refusal_reason(*estimate(row), work.y, centre))


#: Fewest candidates with an out-of-sample score whose median field strength is trusted
#: over the samples' sphere radius (:func:`agreed_field`).
AGREEING_FITS = 3


def agreed_field(summary: Sequence[Mapping], radius: float) -> float:
    """The field strength (samples' units) that the candidates agree on: the median of
    ``|det T|^(1/3)`` over the meaningful fits with an out-of-sample score (``J_r_out``),
    when there are at least :data:`AGREEING_FITS`; else the samples' sphere radius
    ``radius``. On partial coverage a sphere fit's radius is biased (a phone in a pocket:
    27 uT where the models that also fit a shape say 37-43), and one fit that lost the scale
    (a collapsed fit, a wrong unit) is outvoted by the others."""
    fields = [float(np.cbrt(abs(np.linalg.det(estimate(r)[0])))) for r in summary
              if r.get("meaningful", True) and np.isfinite(float(r["J_r_out"]))
              and np.isfinite(float(r["T_00"]))]
    fields = [f for f in fields if np.isfinite(f) and f > 0]
    return float(np.median(fields)) if len(fields) >= AGREEING_FITS else float(radius)


def sphere_scores(trials: Sequence[Mapping], row: Mapping, radius: float) -> dict:
    """``sphere_out``, the predicted RMS error (share of the field) of ``row``'s correction
    over the whole sphere: the held-out error on the recorded directions (``J_r_out / 4``,
    as J_r (81) is about four times the mean squared magnitude error) plus the fold fits'
    disagreement on every direction (:func:`magbench.pipeline.holdout.sphere_spread`); and
    ``field_pct``, how far (%) the fitted field strength ``|det T|^(1/3)`` lies from
    ``radius``, the field the fits agree on (:func:`agreed_field`; NaN without one)."""
    name = str(row["algorithm"])
    spread = sphere_spread(trials, name)
    out = float(np.sqrt(row["J_r_out"] / 4 + spread)) if np.isfinite(row["J_r_out"]) \
        else np.nan
    field = np.nan
    if radius > 0 and np.isfinite(row["T_00"]):
        field = 100 * abs(float(np.cbrt(abs(np.linalg.det(estimate(row)[0])))) / radius - 1)
    return {"sphere_out": out, "field_pct": field}


def _named_choice(choice: Choice, work: Recording, centre: np.ndarray) -> Choice:
    """One named method: its fit on all samples when it has no held-out score."""
    if choice.chosen is not None:
        return Choice(choice.ranked, choice.chosen, f"named: {choice.chosen['algorithm']}")
    row = choice.ranked[0]
    reason = refusal_reason(*estimate(row), work.y, centre) if np.isfinite(row["T_00"]) else \
        "no estimate"
    if bool(row["meaningful"]) and not reason:
        return Choice(choice.ranked, dict(row),
                      f"named: {row['algorithm']} (no out-of-sample score)")
    return choice


def _fit_and_choose(work: Recording, centre: np.ndarray, names: list[str], later: list[str],
                    gap: float, named: bool, fit: dict, extra: ExtraScore | None = None,
                    radius: float = 0.0, max_field_pct: float = math.inf
                    ) -> tuple[list[dict], Choice, str]:
    """One round of fitting and choosing (module notes, steps 2-3): the first round's
    candidates, then the second round's when :func:`second_round_reason` gives a reason (also
    returned, "" otherwise)."""
    limit = 0.0 if named else gap
    rank = dict(extra=extra, radius=radius, max_field_pct=math.inf if named else max_field_pct)
    trials = fit_round(work, names, **fit)
    choice = _rank_trials(trials, work, limit, centre, **rank)
    reason = second_round_reason(choice.tie, choice.chosen, gap, names) if later else ""
    if reason:
        trials = trials + fit_round(work, later, **fit)
        choice = _rank_trials(trials, work, limit, centre, **rank)
    if named:
        choice = _named_choice(choice, work, centre)
    return trials, choice, reason


def retrim(rec: Recording, current: Screen, chosen: Mapping) -> Screen:
    """The screen redone on the chosen fit's norm residuals (module notes, step 4)."""
    T, h = estimate(chosen)
    return trimmed(current, norm_residuals(T, h, rec.y), rec.y, centre=current.centre)


def judge(result: CalibrationResult, gate: Gate,
          expected_field: float | tuple[float, float] | None = None,
          heading_deg: float | None = None) -> None:
    """Verdict, model-based intervals and fitness of the choice (module notes, step 5);
    ``heading_deg``: the choice's held-out heading RMS against a reference attitude, when
    measured (recorded in the verdict and judged by the gate). The correction must narrow
    the field magnitude's spread over the samples left by thinning, outliers included (a
    still stretch, one direction, would otherwise weigh as much as the turns), below that of
    the raw samples as a share of their radius (:func:`magbench.core.verdict.fitness`)."""
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
    none passes (a reason of the recording's, coverage say, fails them all)."""
    first = result.chosen
    reason = result.fitness["reasons"][0]
    for row in result.ranked:
        if not row["eligible"] or row["algorithm"] == first["algorithm"] or \
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
        Block-bootstrap refits of the chosen method (0: none; :func:`bootstrap_check`).
    rounds : int
        Largest number of fit-and-trim rounds.
    second_round : sequence of str
        Methods fitted only when :func:`second_round_reason` says they could change the
        choice; their names end in ``result.not_fitted`` otherwise.
    max_samples : int, optional
        Fit at most about this many samples (an even stride after thinning).
    gate : Gate, optional
        Fitness thresholds (default :class:`~magbench.core.verdict.Gate`).
    expected_field : float or (low, high), optional
        The field strength expected, in the recording's units.
    extra : callable, optional
        Another score for the choice: ``extra(summary, trials, work) -> (column, values)``,
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
    result.bootstrap = bootstrap_check(result, bootstrap, preprocess=preprocess,
                                       options=options, seed=seed)
    return result


def _refit_gauge(rows: np.ndarray, rec: Recording, method: str, preprocess: str,
                 options: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """``b`` and ``A`` of ``method`` refitted on ``rec``'s ``rows``; None when the refit
    fails (one replicate fewer, not a failed command), whatever the way it fails."""
    out = run_method(method, lambda o: fit_recording(rec.rows(rows), method, preprocess, o),
                     options=options)
    if out.T is None or out.error:
        return None
    try:
        gauge = safe_gauge(out.T, out.h)
    except ValueError:
        return None
    return gauge.b, gauge.A


def bootstrap_check(result: CalibrationResult, B: int, *, preprocess: str = "centre",
                    options: dict | None = None, seed: int = 0) -> dict | None:
    """Block-bootstrap intervals of the choice, beside the model-based ones (module notes, 6).

    ``calibrate_recording(..., bootstrap=B)`` runs it; ``bootstrap=0`` leaves it to the caller,
    which may then do other work first (``calibrate`` draws its picture in a second process
    meanwhile). The same arguments give the same answer either way.

    Returns
    -------
    dict or None
        ``block`` (samples per block) and ``correlation_samples``, ``replicates``, the
        bootstrap half-widths ``h_half_width`` and ``A_half_width`` (1.96 standard deviations
        of the refits), their ratios to the model-based ones, and the reported ``wider``
        half-widths with ``source_h`` and ``source_A`` (``block bootstrap`` or
        ``model-based``, the wider in most entries); None without a choice, without ``B``, or
        when fewer than ``max(10, B // 2)`` refits succeeded.
    """
    if not B or result.chosen is None or result.intervals is None:
        return None
    name = str(result.chosen["algorithm"])
    opts = dict((options or {}).get(name) or {})
    work = result.work
    T, h = estimate(result.chosen)
    residual = np.linalg.norm(np.linalg.solve(T, (work.y - h).T), axis=0) - 1.0
    block = block_length(residual)
    gen = rng(seed, "calibrate", "bootstrap", name)
    resamples = [np.sort(block_resample(work.K, block, gen)) for _ in range(B)]
    # Supervised as the candidates' fits are: a refit that ends its process is one replicate
    # fewer, not the end of calibrate.
    fits = map_supervised(functools.partial(_refit_gauge, rec=work, method=name,
                                            preprocess=preprocess, options=opts), resamples,
                          name=f"bootstrap refits of {name}", plugins=plugin_modules([name]))
    fits = [f for f in fits if f is not None]
    if len(fits) < max(10, B // 2):
        return None
    out = _bootstrap_summary(result.intervals, fits, block, correlation_length(residual),
                             work.K)
    return _with_halves(out, (result.verdict or {}).get("halves_offsets"))


def _with_halves(summary: dict, halves: list | None) -> dict:
    """The reported offset half-widths at least the distance between the offsets of the two
    halves of the recording: an offset that drifts slowly (temperature, a battery) moves less
    within a block than over the recording, which the block bootstrap cannot see."""
    if halves is None:
        return summary
    apart = np.abs(np.subtract(*np.asarray(halves, dtype=float)))
    wider = np.asarray(summary["wider_h"], dtype=float)
    out = {**summary, "halves_apart_h": apart.tolist(),
           "wider_h": np.maximum(wider, apart).tolist()}
    if np.mean(apart > wider) > 0.5:
        out["source_h"] = "time halves"
    return out


def _bootstrap_summary(iv: Intervals, fits: list, block: int, corr: float, K: int) -> dict:
    # Student's quantile with one degree of freedom per block less one: with a dozen blocks
    # the spread of the refits is itself uncertain, and 1.96 would cover too little.
    z = student_t95(int(np.ceil(K / block)) - 1)
    h_half = z * np.std([f[0] for f in fits], axis=0, ddof=1)
    A_half = z * np.std([f[1] for f in fits], axis=0, ddof=1)
    fixed = iv.model == "bias"                      # A is not estimated: no interval at all
    if fixed:
        A_half = np.zeros((3, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        rh = h_half / iv.h_half
        rA = (A_half / iv.A_half)[iv.A_half > 0]
    return {"kind": "circular block bootstrap over time", "block": int(block), "quantile": z,
            "correlation_samples": float(corr), "replicates": len(fits),
            "h_half_width": h_half.tolist(), "A_half_width": A_half.tolist(),
            "ratio_h": rh.tolist(),
            "ratio_A_median": float(np.median(rA)) if rA.size else None,
            "ratio_A_range": [float(rA.min()), float(rA.max())] if rA.size else None,
            "wider_h": np.maximum(h_half, iv.h_half).tolist(),
            "wider_A": np.maximum(A_half, iv.A_half).tolist(),
            "source_h": "block bootstrap" if np.mean(h_half > iv.h_half) > 0.5 else
            "model-based",
            "source_A": "not estimated" if fixed else "block bootstrap"
            if np.mean(A_half > iv.A_half) > 0.5 else "model-based"}
