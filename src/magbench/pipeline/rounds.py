"""The fit step of ``calibrate``: candidates fitted in rounds, held out, and each round's choice.

Steps 2 and 3 of :mod:`magbench.pipeline.calibration`, whose notes describe them:
:func:`fit_round` fits every candidate on all samples and on the folds
(:mod:`magbench.pipeline.holdout`), :func:`second_round_reason` says when the second round is
needed, and the ranking goes to :func:`magbench.pipeline.choice.choose` with the field the fits
agree on (:func:`agreed_field`) and each fit's predicted error over the sphere
(:func:`sphere_scores`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from magbench.core.robust import refusal_reason
from magbench.core.verdict import MAX_GAP_DEG
from magbench.pipeline.choice import ROBUST_ON_CAPS, SCORES, Choice, annotate, choose, eligibility
from magbench.pipeline.holdout import (
    estimate,
    evaluate_folds,
    fold_summary,
    held_out_corrected,
    sphere_spread,
)
from magbench.sources.recordings import Recording

__all__ = ["AGREEING_FITS", "FIRST_ROUND", "J_R_MINIMISER", "ExtraScore", "agreed_field",
           "fit_round", "second_round_reason", "sphere_scores"]


#: The first round of ``calibrate``'s default candidates
#: (:mod:`~magbench.pipeline.calibration`, step 2): the closed forms of every model and the
#: minimiser of J_r (81), Wu-Shi NM.
FIRST_ROUND = ("sphere", "twostep_hi", "diagonal", "ellipsoid", "fang", "twostep", "wu_shi_nm")
#: The method whose objective (Wu and Shi's (11)) is K times J_r (81).
J_R_MINIMISER = "wu_shi_nm"
#: ``extra(summary, trials, work) -> (column, values)``: a further score for the choice
#: (``summary`` and ``trials`` are lists of records, :mod:`magbench.pipeline.holdout`; a
#: summary row's ``choosable``: whether the candidate is eligible on every other ground).
ExtraScore = Callable[[list[dict], list[dict], Recording], tuple[str, Sequence[float]]]


def fit_round(work: Recording, names: Sequence[str], *, preprocess: str, options: dict,
              seed: int, call_timeout_s: float | None) -> list[dict]:
    """Every method of ``names`` on all of ``work`` and on each fold
    (:mod:`~magbench.pipeline.calibration`, step 2)."""
    return evaluate_folds(work, list(names), preprocess, options=options, seed=seed,
                          call_timeout_s=call_timeout_s)


def second_round_reason(tie: Sequence[str], chosen: Mapping | None, gap_deg: float,
                        first: Sequence[str]) -> str:
    """Why the second round of candidates must be fitted, or ""
    (:mod:`~magbench.pipeline.calibration`, step 2)."""
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
    corrected = {r["algorithm"]: held_out_corrected(trials, work, r["algorithm"])
                 for r in summary}
    if extra is not None:
        # The extra score may compare each candidate with those the choice could take on
        # every other ground (``choosable``).
        choosable = [bool(r["eligible"]) for r in eligibility(
            annotate(summary, corrected), gap_deg, SCORES, max_field_pct)]
        column, values = extra([{**r, "choosable": c} for r, c in
                                zip(summary, choosable, strict=True)], trials, work)
        # Why a score is missing, when the extra score says (a direction veto's reason).
        why = getattr(extra, "vetoes", {})
        summary = [{**r, column: v, "veto": why.get(str(r["algorithm"]), "")}
                   for r, v in zip(summary, values, strict=True)]
        scores = (*SCORES, column)
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
    """One round of fitting and choosing (:mod:`~magbench.pipeline.calibration`, steps
    2-3): the first round's candidates, then the second round's when
    :func:`second_round_reason` gives a reason (also returned, "" otherwise)."""
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
