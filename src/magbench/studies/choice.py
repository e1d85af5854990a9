"""calibrate's choice among fitted candidates: eligibility, ranking, the tie, the pick.

Each step is a small function of the candidates' table (one row per method, from
:func:`magbench.studies.holdout.fold_summary`), so each can be tested and another score can
join the choice:

1. :func:`annotate` adds the model, whether the method needs the gyroscope, and the held-out
   field errors (95th percentile and worst) from the folds.
2. :func:`eligibility` writes why a method cannot be ranked (no out-of-sample score, not
   meaningful, a model the coverage does not support: :func:`allowed`).
3. :func:`gyro_rule`: a gyro-aided method stays eligible only when it beats the best
   magnetometer-only method out of sample on every score (it needs more of the data to be right:
   the gyroscope's bias and alignment, the time base).
4. :func:`rank`: by the mean held-out J_r over the folds.
5. :func:`find_tie`: the methods that tie the best on *every* score in ``scores`` (by default
   the mean and the worst fold's held-out J_r, :data:`SCORES`): each within :data:`TIE_RTOL`
   of the best's. Another per-candidate score (lower is better) joins by adding its column to
   the table and its name to ``scores``.
6. :func:`pick`: the simplest of the tie (fewest model parameters, then closed form, then the
   best mean held-out J_r), skipping refused fits (:func:`magbench.core.robust.refusal_reason`);
   if all of the tie is refused, the next in the ranking. Fit times are never used, so the same
   file gives the same choice.

A simpler model therefore wins only when it is as good out of sample on average *and* on the
worst fold; on a band or a cap, where the full models extrapolate badly, the sphere and
offset-only models compete and win when they are better there.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from magbench.core.crb import MODEL_PARAMETERS
from magbench.core.verdict import MAX_GAP_DEG, field_error_pct
from magbench.methods.registry import get_method

__all__ = ["ROBUST_ON_CAPS", "SCORES", "THIN_GAP_DEG", "TIE_RTOL", "Choice", "allowed",
           "annotate", "choose", "eligibility", "find_tie", "gyro_rule", "pick", "rank"]

#: Largest uncovered cap (deg) up to which a full model may be chosen (only the ones robust on
#: caps, :data:`ROBUST_ON_CAPS`, beyond :data:`~magbench.core.verdict.MAX_GAP_DEG`).
THIN_GAP_DEG = 135.0
#: Full-model methods with RB >= 90 % on 60 deg caps in results/coverage/summary.csv.
ROBUST_ON_CAPS = ("magical", "fang")
#: Scores (lower is better) on which a simpler model must tie the best to be chosen.
SCORES = ("J_r_out", "J_r_worst")
#: Two methods tie on a score when the larger is at most this much above the smaller.
TIE_RTOL = 0.05


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


def annotate(summary: pd.DataFrame, corrected: Mapping[str, np.ndarray | None]
             ) -> pd.DataFrame:
    """``summary`` with ``model``, ``gyro``, ``p95_out_pct`` and ``worst_out_pct`` (held-out
    field errors of :func:`magbench.studies.holdout.held_out_corrected`, NaN without)."""
    out = summary.copy()
    out["model"] = [get_method(a).model for a in out["algorithm"]]
    out["gyro"] = [get_method(a).needs_gyro for a in out["algorithm"]]
    errors = [field_error_pct(corrected[a]) if corrected.get(a) is not None else None
              for a in out["algorithm"]]
    out["p95_out_pct"] = [np.percentile(e, 95) if e is not None else np.nan for e in errors]
    out["worst_out_pct"] = [e.max() if e is not None else np.nan for e in errors]
    return out


def _why_not(r) -> str:
    if isinstance(r.error, str) and r.error:
        return r.error
    if not r.coverage >= 0.5 * r.coverage_sphere:
        return (f"degenerate: calibrated directions cover {r.coverage:.2f} of the sphere, the "
                f"sphere fit's {r.coverage_sphere:.2f}")
    return f"J_r above twice the sphere fit's ({r.J_r_sphere_in:.3g})"


def eligibility(table: pd.DataFrame, gap_deg: float, scores: Sequence[str] = SCORES
                ) -> pd.DataFrame:
    """``table`` with ``eligible`` and ``note`` (why not); ``scored``: every score finite."""
    out = table.copy()
    scored = np.all([np.isfinite(out[s].astype(float)) for s in scores], axis=0)
    notes, eligible = [], []
    for r, has in zip(out.itertuples(index=False), scored, strict=True):
        note = ""
        if not r.meaningful:
            note = _why_not(r)
        elif not has:
            note = "no out-of-sample score (a fold's fit failed or was degenerate)"
        elif not allowed(r.algorithm, gap_deg):
            note = (f"not chosen: a {r.model} model is not trusted with a {gap_deg:.0f} deg "
                    "gap in coverage")
        notes.append(note)
        eligible.append(not note)
    return out.assign(scored=scored & out["meaningful"].astype(bool), eligible=eligible,
                      note=notes)


def _beats(a: pd.Series, b: pd.Series, scores: Sequence[str]) -> bool:
    """``a`` better than ``b`` beyond the tie on every score."""
    return all(a[s] * (1 + TIE_RTOL) < b[s] for s in scores)


def gyro_rule(table: pd.DataFrame, scores: Sequence[str] = SCORES) -> pd.DataFrame:
    """Gyro-aided methods stay eligible only when they beat the best magnetometer-only one."""
    out = table.copy()
    mag = out[out["eligible"] & ~out["gyro"].astype(bool)]
    if mag.empty:
        return out
    best = mag.sort_values(scores[0], kind="stable").iloc[0]
    for i in out.index[out["eligible"] & out["gyro"].astype(bool)]:
        if not _beats(out.loc[i], best, scores):
            out.loc[i, "eligible"] = False
            out.loc[i, "note"] = (f"not chosen: a gyro-aided fit must beat the best "
                                  f"magnetometer-only fit ({best['algorithm']}) out of sample")
    return out


def rank(table: pd.DataFrame, scores: Sequence[str] = SCORES) -> pd.DataFrame:
    """Eligible first by ``scores[0]``, then scored, then meaningful, then the rest; ``rank``
    numbers the eligible ones."""
    group = np.where(table["eligible"], 0, np.where(table["scored"], 1, np.where(
        table["meaningful"].astype(bool), 2, np.where(table["ok"].astype(bool), 3, 4))))
    out = (table.assign(_g=group, _k=table[scores[0]].astype(float).fillna(np.inf))
           .sort_values(["_g", "_k"], kind="stable").reset_index(drop=True))
    n = int((out["_g"] == 0).sum())
    out.insert(0, "rank", pd.array([i + 1 if i < n else pd.NA for i in range(len(out))],
                                   dtype="Int64"))
    return out.drop(columns=["_g", "_k"])


def find_tie(ranked: pd.DataFrame, scores: Sequence[str] = SCORES) -> pd.DataFrame:
    """``ranked`` with ``tie``: eligible methods within :data:`TIE_RTOL` of the best (the
    first eligible row) on every score."""
    out = ranked.assign(tie=False)
    eligible = out.index[out["eligible"]]
    if len(eligible) == 0:
        return out
    best = out.loc[eligible[0]]
    for i in eligible:
        out.loc[i, "tie"] = all(out.loc[i, s] <= (1 + TIE_RTOL) * best[s] for s in scores)
    return out


def pick(ranked: pd.DataFrame, refuse: Callable[[pd.Series], str] | None = None
         ) -> tuple[pd.DataFrame, pd.Series | None]:
    """The simplest of the tie not refused, else the next eligible one (module notes, 6)."""
    out = ranked.copy()
    tie = out[out["tie"]].assign(_p=lambda d: [MODEL_PARAMETERS[m] for m in d["model"]],
                                 _it=lambda d: d["n_iter"] > 0)
    order = tie.sort_values(["_p", "_it"], kind="stable").drop(columns=["_p", "_it"])
    rest = out[out["eligible"] & ~out["tie"]]
    for i, r in pd.concat([order, rest]).iterrows():
        reason = refuse(r) if refuse else ""
        if not reason:
            return out, r
        out.loc[i, "note"] = f"refused: {reason}"
    return out, None


class Choice:
    """What :func:`choose` decided: the ranked table, the tie, the chosen row and how."""

    def __init__(self, ranked: pd.DataFrame, chosen: pd.Series | None, how: str):
        self.ranked, self.chosen, self.how = ranked, chosen, how

    @property
    def tie(self) -> list[str]:
        return self.ranked.loc[self.ranked["tie"], "algorithm"].tolist()


def _how(ranked: pd.DataFrame, chosen: pd.Series | None) -> str:
    if chosen is None:
        return "no method has an out-of-sample score" if not ranked["eligible"].any() else \
            "every eligible method was refused"
    tie = ranked.loc[ranked["tie"], "algorithm"].tolist()
    best = ranked[ranked["eligible"]].iloc[0]["algorithm"]
    if chosen["algorithm"] not in tie:
        return f"every method of the tie was refused; chosen {chosen['algorithm']}, the next"
    if len(tie) == 1:
        return f"{best} is best held out (mean and worst fold), alone beyond {TIE_RTOL:.0%}"
    return (f"{len(tie)} tie with {best} held out (mean and worst fold within "
            f"{TIE_RTOL:.0%}); chosen {chosen['algorithm']}, the simplest")


def choose(summary: pd.DataFrame, corrected: Mapping[str, np.ndarray | None], gap_deg: float,
           *, refuse: Callable[[pd.Series], str] | None = None,
           scores: Sequence[str] = SCORES) -> Choice:
    """Annotate, judge eligibility, apply the gyro rule, rank, tie and pick (module notes).

    Parameters
    ----------
    summary : DataFrame
        :func:`magbench.studies.holdout.fold_summary` (plus any extra score columns).
    corrected : mapping
        Each method's held-out corrected samples (None without).
    gap_deg : float
        Largest uncovered cap, for :func:`allowed`.
    refuse : callable, optional
        ``refuse(row) -> str``: a non-empty reason keeps the row from being chosen.
    scores : sequence of str
        Columns (lower is better) a simpler model must tie on; the first ranks.
    """
    table = gyro_rule(eligibility(annotate(summary, corrected), gap_deg, scores), scores)
    ranked, chosen = pick(find_tie(rank(table, scores), scores), refuse)
    return Choice(ranked, chosen, _how(ranked, chosen))
