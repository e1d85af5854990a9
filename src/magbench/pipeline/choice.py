"""calibrate's choice among fitted candidates: eligibility, ranking, the tie, the pick.

Each step is a small function of the candidates' table (one record per method, from
:func:`magbench.pipeline.holdout.fold_summary`), so each can be tested and another score can
join the choice:

1. :func:`annotate` adds the model, whether the method needs the gyroscope, and the held-out
   field errors (95th percentile and worst) from the folds.
2. :func:`eligibility` writes why a method cannot be ranked (no out-of-sample score, not
   meaningful, a model the coverage does not support: :func:`allowed`, a fitted field
   strength the gate would refuse: J_r is blind to a scale the data do not fix).
3. :func:`gyro_rule`: a gyro-aided method stays eligible only when it beats the best
   magnetometer-only method out of sample on the held-out J_r scores and ties it on any other
   (it needs more of the data to be right: the gyroscope's bias and alignment, the time base).
4. :func:`rank`: by the mean held-out J_r over the folds. (``sphere_out``, the fold fits'
   predicted error over the whole sphere, is computed and shown beside it; ranked by it, the
   generalisation study lost more band cases, not fewer: docs/decisions.md.)
5. :func:`find_tie`: the methods that tie the best on *every* score in ``scores`` (by default
   the mean and the worst fold's held-out J_r, :data:`SCORES`): each within
   :data:`TIE_RTOL` of the best's. Another per-candidate score (lower is better) joins by
   adding its column to the table and its name to ``scores``.
6. :func:`beyond_raw`: how much more spread than the raw data each eligible fit could leave
   the field's magnitude on the whole sphere, if any other eligible fit were the sensor's
   true model (directions never recorded included: a band, a cap).
7. :func:`pick`: the simplest of the tie (fewest model parameters, then the best mean
   held-out J_r: a closed form is no simpler where it extrapolates), skipping refused fits
   (:func:`magbench.core.robust.refusal_reason`) and passing over those that
   :func:`beyond_raw` finds could be worse than no correction while another could not; if
   all of the tie is set aside, the next in the ranking. Fit times are never used, so the
   same file gives the same choice.

A simpler model therefore wins only when it is as good out of sample on average *and* on the
worst fold; on a band or a cap, where the full models extrapolate badly, the sphere and
offset-only models compete and win when they are better there.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from magbench.core.crb import MODEL_PARAMETERS
from magbench.core.geometry import fibonacci_sphere
from magbench.core.verdict import MAX_GAP_DEG, field_error_pct
from magbench.methods.registry import get_method
from magbench.pipeline.holdout import estimate

__all__ = ["ROBUST_ON_CAPS", "SCORES", "THIN_GAP_DEG", "TIE_RTOL", "WHOLE_SPHERE", "Choice",
           "allowed", "annotate", "beyond_raw", "choose", "could_be_worse_than_raw",
           "eligibility", "find_tie", "gyro_rule", "passed_over", "pick", "rank",
           "ranking_frame"]

#: A candidate's row: a plain record (column -> value), so that ``calibrate`` needs no pandas.
Row = dict

#: Largest uncovered cap (deg) up to which a full model may be chosen (only the ones robust on
#: caps, :data:`ROBUST_ON_CAPS`, beyond :data:`~magbench.core.verdict.MAX_GAP_DEG`).
THIN_GAP_DEG = 135.0
#: Full-model methods with RB >= 90 % on 60 deg caps in results/coverage/summary.csv.
ROBUST_ON_CAPS = ("magical", "fang")
#: Scores (lower is better) on which a simpler model must tie the best to be chosen; the
#: first ranks.
SCORES = ("J_r_out", "J_r_worst")
#: Two methods tie on a score when the larger is at most this much above the smaller.
TIE_RTOL = 0.05
#: Field directions over the whole sphere on which :func:`beyond_raw` compares a correction
#: with the raw data.
WHOLE_SPHERE = 600
#: Points of spread below which :func:`beyond_raw`'s differences are round-off, not a
#: correction worse than none (a calibrated sensor's noise-free samples).
ROUND_OFF_PCT = 1e-9
#: How a candidate's note starts when :func:`pick` passed over it (:func:`beyond_raw`).
PASSED_OVER = "passed over"


def allowed(name: str, gap_deg: float) -> bool:
    """Whether ``name`` may be chosen when the largest uncovered cap is ``gap_deg``.

    Any method up to :data:`~magbench.core.verdict.MAX_GAP_DEG`; beyond, the full-model
    methods robust on 60 deg caps and the sphere and offset-only models up to
    :data:`THIN_GAP_DEG`; beyond that only the sphere and offset-only models.
    """
    model = get_method(name).model
    if gap_deg <= MAX_GAP_DEG or model in ("sphere", "bias"):
        return True
    return gap_deg <= THIN_GAP_DEG and name in ROBUST_ON_CAPS


def annotate(summary: Sequence[Mapping], corrected: Mapping[str, np.ndarray | None]
             ) -> list[Row]:
    """``summary`` with ``model``, ``gyro``, ``p95_out_pct`` and ``worst_out_pct`` (held-out
    field errors of :func:`magbench.pipeline.holdout.held_out_corrected`, NaN without)."""
    out = []
    for row in summary:
        name = row["algorithm"]
        e = field_error_pct(corrected[name]) if corrected.get(name) is not None else None
        out.append({**row, "model": get_method(name).model, "gyro": get_method(name).needs_gyro,
                    "p95_out_pct": np.percentile(e, 95) if e is not None else np.nan,
                    "worst_out_pct": e.max() if e is not None else np.nan})
    return out


def _why_not(r: Mapping) -> str:
    if isinstance(r["error"], str) and r["error"]:
        return r["error"]
    if not r["coverage"] >= 0.5 * r["coverage_sphere"]:
        return (f"degenerate: calibrated directions cover {r['coverage']:.2f} of the sphere, "
                f"the sphere fit's {r['coverage_sphere']:.2f}")
    return f"J_r above twice the sphere fit's ({r['J_r_sphere_in']:.3g})"


def eligibility(table: Sequence[Mapping], gap_deg: float, scores: Sequence[str] = SCORES,
                max_field_pct: float = math.inf) -> list[Row]:
    """``table`` with ``scored``, ``eligible`` and ``note`` (why not); ``scored``: every score
    finite and the fit meaningful. A fit whose field strength (``field_pct``, when the table
    has it) lies more than ``max_field_pct`` % from the data's field (the field strength the
    fits agree on) is not eligible: J_r
    (81) is blind to scale, and the gate would refuse it (a collapsed fit or a wrong unit)."""
    out = []
    for r in table:
        has = all(math.isfinite(float(r[s])) for s in scores)
        note = ""
        field = float(r.get("field_pct", np.nan))
        off_scale = bool(r["meaningful"]) and has and field > max_field_pct
        if not r["meaningful"]:
            note = _why_not(r)
        elif not has and r.get("veto"):
            note = f"set aside: {r['veto']}"
        elif not has:
            note = "no out-of-sample score (a fold's fit failed or was degenerate)"
        elif off_scale:
            note = (f"not chosen: fitted field {field:.0f} % from the data's field (the gate "
                    f"fails above {max_field_pct:g} %)")
        elif not allowed(r["algorithm"], gap_deg):
            note = (f"not chosen: a {r['model']} model is not trusted with a {gap_deg:.0f} deg "
                    "gap in coverage")
        out.append({**r, "scored": has and bool(r["meaningful"]), "eligible": not note,
                    "note": note, "off_scale": off_scale})
    return out


def _beats(a: Mapping, b: Mapping, scores: Sequence[str]) -> bool:
    """``a`` better than ``b`` beyond the tie on every held-out J_r score (:data:`SCORES`),
    and within the tie on any other (an extra score may be a pass mark that two candidates
    share, which neither can beat)."""
    return all(a[s] * (1 + TIE_RTOL) < b[s] if s in SCORES else a[s] <= (1 + TIE_RTOL) * b[s]
               for s in scores)


def gyro_rule(table: Sequence[Mapping], scores: Sequence[str] = SCORES) -> list[Row]:
    """Gyro-aided methods stay eligible only when they beat the best magnetometer-only one."""
    out = [dict(r) for r in table]
    mag = [r for r in out if r["eligible"] and not r["gyro"]]
    if not mag:
        return out
    best = min(mag, key=lambda r: r[scores[0]])         # the first of equals, as a stable sort
    for r in out:
        if r["eligible"] and r["gyro"] and not _beats(r, best, scores):
            r["eligible"] = False
            r["note"] = (f"not chosen: a gyro-aided fit must beat the best "
                         f"magnetometer-only fit ({best['algorithm']}) out of sample")
    return out


def _group(r: Mapping) -> int:
    """Eligible, scored, meaningful, converged, the rest: 0 to 4."""
    for g, key in enumerate(("eligible", "scored", "meaningful", "ok")):
        if r[key]:
            return g
    return 4


def rank(table: Sequence[Mapping], scores: Sequence[str] = SCORES) -> list[Row]:
    """Eligible first by ``scores[0]``, then scored, then meaningful, then the rest; ``rank``
    numbers the eligible ones (None for the others)."""
    def key(r: Mapping) -> tuple[int, float]:
        x = float(r[scores[0]])
        return _group(r), math.inf if math.isnan(x) else x

    ordered = sorted(table, key=key)                    # stable: ties keep the table's order
    n = sum(1 for r in ordered if r["eligible"])
    return [{"rank": i + 1 if i < n else None, **r} for i, r in enumerate(ordered)]


def find_tie(ranked: Sequence[Mapping], scores: Sequence[str] = SCORES) -> list[Row]:
    """``ranked`` with ``tie``: eligible methods within :data:`TIE_RTOL` of the best (the
    first eligible row) on every score."""
    out = [{**r, "tie": False} for r in ranked]
    eligible = [r for r in out if r["eligible"]]
    for r in eligible:
        r["tie"] = all(r[s] <= (1 + TIE_RTOL) * eligible[0][s] for s in scores)
    return out


def beyond_raw(ranked: Sequence[Mapping]) -> list[Row]:
    """``ranked`` with ``beyond_raw_pct`` and ``beyond_raw_if``: for each eligible fit ``j``,
    the most its correction could leave the field's magnitude more spread than the raw data
    over the whole sphere, in points of the field, and under which model.

    Each eligible fit ``k`` is taken in turn as the sensor's true model: the samples it
    predicts on :data:`WHOLE_SPHERE` field directions ``u`` are ``y = T_k u + h_k``, whose
    raw spread is ``100 std|y| / |det T_k|^(1/3)`` (a share of the field, as the raw data
    are scored); ``j``'s correction of them spreads ``100 std|c| / mean|c|`` with ``c =
    T_j^-1 (y - h_j)``. ``beyond_raw_pct`` is the largest difference over ``k`` (NaN for a fit
    that is not eligible or has no invertible ``T``). Where the data cover the sphere the
    eligible fits agree, and every correction beats raw data that need one; on a band or a
    cap they agree only where the data are, and a positive value says this correction could
    be worse than none on the directions not recorded if ``beyond_raw_if``'s model is the
    right one."""
    out = [{**r, "beyond_raw_pct": math.nan, "beyond_raw_if": ""} for r in ranked]
    models = [(r, *estimate(r)) for r in out if r["eligible"] and "T_00" in r]
    models = [(r, T, h) for r, T, h in models
              if np.isfinite(T).all() and np.isfinite(h).all() and np.linalg.det(T) != 0]
    if not models:
        return out
    u = fibonacci_sphere(WHOLE_SPHERE)
    # Every model's predicted samples stacked, one row of directions per model.
    y = np.stack([u @ T.T + h for _, T, h in models])
    fields = np.array([np.cbrt(abs(np.linalg.det(T))) for _, T, _ in models])
    norms = np.linalg.norm(y, axis=2)
    raw = 100 * norms.std(axis=1) / fields
    names = [str(r["algorithm"]) for r, _, _ in models]
    for r, T, h in models:
        c = np.linalg.norm((y - h) @ np.linalg.inv(T).T, axis=2)
        excess = 100 * c.std(axis=1) / c.mean(axis=1) - raw
        k = int(np.argmax(excess))
        r["beyond_raw_pct"], r["beyond_raw_if"] = float(excess[k]), names[k]
    return out


def could_be_worse_than_raw(row: Mapping) -> bool:
    """Whether :func:`beyond_raw` found that ``row``'s correction could leave the field more
    spread than no correction on the whole sphere (by more than round-off)."""
    return float(row.get("beyond_raw_pct", math.nan)) > ROUND_OFF_PCT


def passed_over(ranked: Sequence[Mapping]) -> list[str]:
    """The candidates :func:`pick` passed over as possibly worse than no correction."""
    return [str(r["algorithm"]) for r in ranked
            if str(r.get("note") or "").startswith(PASSED_OVER)]


def pick(ranked: Sequence[Mapping], refuse: Callable[[Row], str] | None = None
         ) -> tuple[list[Row], Row | None]:
    """The simplest of the tie not refused, else the next eligible one (module notes, 7); of
    those, the first that :func:`beyond_raw` does not find could be worse than the raw data
    (:func:`could_be_worse_than_raw`), when there is one; the chosen row is a copy."""
    out = [dict(r) for r in ranked]
    tie = sorted((r for r in out if r["tie"]),
                 key=lambda r: (MODEL_PARAMETERS[r["model"]], float(r[SCORES[0]])))
    rest = [r for r in out if r["eligible"] and not r["tie"]]
    usable = []
    for r in tie + rest:
        reason = refuse(dict(r)) if refuse else ""
        if reason:
            r["note"] = f"refused: {reason}"
        else:
            usable.append(r)
    safe = [r for r in usable if not could_be_worse_than_raw(r)]
    if not usable:
        return out, None
    chosen = safe[0] if safe else usable[0]
    for r in usable[:usable.index(chosen)]:
        r["note"] = (f"{PASSED_OVER}: off the recorded directions it could leave the field "
                     f"{r['beyond_raw_pct']:.2f} points more spread than no correction (if "
                     f"{r['beyond_raw_if']}'s model is the sensor's)")
    return out, dict(chosen)


class Choice:
    """What :func:`choose` decided: the ranked rows, the tie, the chosen row and how."""

    def __init__(self, ranked: list[Row], chosen: Row | None, how: str):
        self.ranked, self.chosen, self.how = ranked, chosen, how

    @property
    def tie(self) -> list[str]:
        return [r["algorithm"] for r in self.ranked if r["tie"]]


def ranking_frame(ranked: Sequence[Mapping]) -> object:
    """The ranked rows as a pandas DataFrame (``rank`` a nullable integer), for a program
    that wants the table; ``calibrate`` itself writes them without pandas."""
    import pandas as pd

    frame = pd.DataFrame(list(ranked))
    return frame.astype({"rank": "Int64"}) if "rank" in frame else frame


def _how(ranked: Sequence[Mapping], chosen: Mapping | None) -> str:
    if chosen is None:
        return "no method has an out-of-sample score" if not any(r["eligible"] for r in ranked) \
            else "every eligible method was refused"
    tie = [r["algorithm"] for r in ranked if r["tie"]]
    best = next(r for r in ranked if r["eligible"])["algorithm"]
    passed = passed_over(ranked)
    if passed:
        return (f"{', '.join(passed)} could leave the field more spread than no correction "
                f"off the recorded directions; chosen {chosen['algorithm']}, the first that "
                "could not")
    if chosen["algorithm"] not in tie:
        return f"every method of the tie was refused; chosen {chosen['algorithm']}, the next"
    if len(tie) == 1:
        return f"{best} is best held out (mean and worst fold), alone beyond {TIE_RTOL:.0%}"
    return (f"{len(tie)} tie with {best} held out (mean and worst fold within "
            f"{TIE_RTOL:.0%}); chosen {chosen['algorithm']}, the simplest")


def choose(summary: Sequence[Mapping], corrected: Mapping[str, np.ndarray | None],
           gap_deg: float, *, refuse: Callable[[Row], str] | None = None,
           scores: Sequence[str] = SCORES, max_field_pct: float = math.inf) -> Choice:
    """Annotate, judge eligibility, apply the gyro rule, rank, tie and pick (module notes).

    Parameters
    ----------
    summary : sequence of dict
        :func:`magbench.pipeline.holdout.fold_summary` (plus any extra score columns).
    corrected : mapping
        Each method's held-out corrected samples (None without).
    gap_deg : float
        Largest uncovered cap, for :func:`allowed`.
    refuse : callable, optional
        ``refuse(row) -> str``: a non-empty reason keeps the row from being chosen.
    scores : sequence of str
        Columns (lower is better) a simpler model must tie on; the first ranks.
    max_field_pct : float
        Largest distance (%) of a fit's field strength from the samples' radius
        (:func:`eligibility`).
    """
    table = gyro_rule(eligibility(annotate(summary, corrected), gap_deg, scores,
                                  max_field_pct), scores)
    ranked, chosen = pick(beyond_raw(find_tie(rank(table, scores), scores)), refuse)
    if chosen is None:
        # Nothing else can be chosen: the best fit off the data's scale is judged, and the
        # gate FAILs it with the reason, rather than no answer at all.
        off = [r for r in ranked if r.get("off_scale")]
        if off:
            chosen = dict(min(off, key=lambda r: float(r[scores[0]])))
            return Choice(ranked, chosen, f"only {chosen['algorithm']} has an out-of-sample "
                          "score, and its field is off the data's scale")
    return Choice(ranked, chosen, _how(ranked, chosen))
