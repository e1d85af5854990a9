"""Calibrating one recording for a user: robust, coverage-aware, an honest choice, intervals.

This is the study behind ``python -m magbench calibrate`` (the command only reads, prints and
writes). :func:`calibrate_recording` runs, in order:

1. *Outlier screen.* The robust sphere fit of :mod:`magbench.core.robust` sets aside spikes
   and disturbances (norm residual more than :data:`~magbench.core.robust.CUTOFF` robust
   sigmas from the median).
2. *Coverage and model.* The field directions seen from that centre give the largest
   uncovered cap (:func:`magbench.core.verdict.coverage_report`), which decides which
   candidates may be chosen (:func:`allowed`), from the coverage sweep's own findings
   (``results/coverage/summary.csv``, 250 datasets per point at the review's nominal point):

   * a cap of 90 deg or more (hemisphere) calibrates with every full-model method (RB 100 %
     for all eight at cap 90 and 135), so up to a largest gap of
     :data:`~magbench.core.verdict.MAX_GAP_DEG` (100 deg: samples filling a cap of 80 deg) any
     method may be chosen;
   * at a cap of 60 deg only MAG.I.C.AL (RB 92 %) and Fang (94 %) stay robust (Wu-Shi 75 %,
     Ali 73 %, the ellipsoid fit 38 %, TWOSTEP 4 %, Dorveaux and Vasconcelos 1 %), and they
     still beat the models with fewer parameters there (accuracy 25.6 and 25.1 against the
     sphere fit's 9.6; a run of 40 datasets per cap into /tmp with the offset + diagonal scale
     model gave it a median J of 0.30 at cap 60 and 1.0 at cap 45 against the sphere fit's
     0.15 and 0.17: its extra freedom amplifies the cross-coupling it cannot represent), so
     up to a gap of :data:`THIN_GAP_DEG` (135 deg, a cap of 45 deg) only :data:`ROBUST_ON_CAPS`
     may be chosen, with a warning (on hmc5883l_sphere cut to a 60 deg cap, Fang and
     MAG.I.C.AL fits reach 16 % and 9 % field error on the whole recording, a sphere fit 39 %);
   * below a cap of 45 deg every full-model method fails on 40 % or more of the datasets (cap
     45: MAG.I.C.AL 57 %, Fang 47 %; cap 30: at most 35 %), so only the sphere and offset-only
     models may be chosen (the fallback also when no robust full fit succeeds at larger
     caps), with a warning. Coverage below 0.2 is refused when the file is read.

3. *Candidates, held out.* Every candidate is fitted on the inliers and on each half in time,
   each half-fit scored on the other half (:func:`magbench.studies.real.evaluate_recording`).
   With a ``second_round`` (``calibrate``'s default), the candidates are fitted in two rounds:
   first the closed forms and Wu-Shi NM (:data:`FIRST_ROUND`), then the others only when
   :func:`second_round_reason` finds that they could change the choice. Wu-Shi NM minimises
   the NM objective (11), which is ``K`` times J_r (81) itself, so no method fits the data
   better; another can only do better out of sample, where regularisation beats fitting (a
   short recording). The second round therefore runs when Wu-Shi NM does not tie the best
   of the first round, when coverage has a gap beyond
   :data:`~magbench.core.verdict.MAX_GAP_DEG` (the methods robust on caps are needed), or
   when nothing in the first round can be chosen.
4. *The choice* (:func:`choose`). Only methods with an out-of-sample score are ranked. A method
   whose held-out worst-case field error exceeds :data:`WORST_FACTOR` times the smallest
   (plus :data:`WORST_SLACK_PCT` points) is ranked after the others. The best by held-out
   J_r (eq. 81) is compared with every other: two methods *tie* when the 95 % block-bootstrap
   interval of the difference of their held-out per-sample costs contains 0, or their held-out
   J_r differ by at most :data:`TIE_RTOL` (5 %). The tie is reported ("any of ..."), and the
   chosen one is the simplest of it: fewest model parameters
   (:data:`magbench.core.crb.MODEL_PARAMETERS`), then closed form before iterative, then the
   best held-out J_r. Fit times are not used: they vary from run to run (by more than the
   tenth of a millisecond that separates the closed forms), and the same file must give the
   same choice every time.
5. *Trimming around the chosen fit.* The chosen method's own norm residuals on every sample
   are trimmed like the sphere fit's (a soft-iron sensor's disturbances can hide in the sphere
   fit's wider residuals); if that changes the inliers, steps 3-5 run again (at most
   ``rounds`` times).
6. *Refusal.* A fit that collapses the directions, is nearly singular or is not finite
   (:func:`magbench.core.robust.refusal_reason`) is never chosen; the next in the tie or the
   ranking is.
7. *Verdict and uncertainty*: held-out field error on the inliers
   (:func:`magbench.core.verdict.magnitude_verdict`), model-based 95 % intervals on ``h`` and
   ``A`` (:func:`magbench.core.uncertainty.fisher_intervals`) and, as a check, the spread of
   ``bootstrap`` refits on resampled inliers.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from magbench.core.crb import MODEL_PARAMETERS
from magbench.core.gauge import safe_gauge
from magbench.core.robust import outliers, refusal_reason, robust_sphere_fit
from magbench.core.seeding import rng
from magbench.core.uncertainty import Intervals, fisher_intervals
from magbench.core.verdict import MAX_GAP_DEG, coverage_report, field_error_pct, magnitude_verdict
from magbench.methods.registry import get_method
from magbench.sources.recordings import Recording
from magbench.studies.real import evaluate_recording, fit_recording, recording_summary

__all__ = ["FIRST_ROUND", "ROBUST_ON_CAPS", "THIN_GAP_DEG", "TIE_RTOL", "WORST_FACTOR",
           "CalibrationResult", "allowed", "bootstrap_check", "calibrate_recording", "choose",
           "estimate",
           "held_out_corrected", "held_out_errors", "second_round_reason"]

#: Largest uncovered cap (deg) up to which a full model is fitted by :data:`ROBUST_ON_CAPS`.
THIN_GAP_DEG = 135.0
#: Full-model methods with RB >= 90 % on 60 deg caps in results/coverage/summary.csv.
ROBUST_ON_CAPS = ("magical", "fang")
#: The first round of ``calibrate``'s default candidates (module notes, step 3): the closed
#: forms of every model and the minimiser of J_r (81), Wu-Shi NM.
FIRST_ROUND = ("sphere", "twostep_hi", "diagonal", "ellipsoid", "fang", "twostep", "wu_shi_nm")
#: The method whose objective (Wu and Shi's (11)) is K times J_r (81).
J_R_MINIMISER = "wu_shi_nm"
#: Held-out J_r within this relative distance of the best is a tie whatever the bootstrap says.
TIE_RTOL = 0.05
#: A held-out worst-case field error above WORST_FACTOR x the smallest + WORST_SLACK_PCT.
WORST_FACTOR = 1.5
WORST_SLACK_PCT = 0.5
_BLOCKS = 40
_TIE_RESAMPLES = 1000


@dataclass
class CalibrationResult:
    """What :func:`calibrate_recording` found (see the module notes)."""

    rec: Recording
    inliers: np.ndarray
    screened: int
    trimmed: int
    centre: np.ndarray
    coverage: dict
    ranked: pd.DataFrame
    trials: pd.DataFrame
    tie: list[str]
    chosen: pd.Series | None
    how: str
    verdict: dict | None = None
    intervals: Intervals | None = None
    bootstrap: dict | None = None
    warnings: list[str] = field(default_factory=list)
    #: Candidates of the second round left unfitted, and why the second round ran ("": not).
    not_fitted: list[str] = field(default_factory=list)
    second_round: str = ""
    #: The samples the chosen method was last fitted on (what :func:`bootstrap_check` resamples).
    work: Recording | None = None

    @property
    def outliers(self) -> int:
        return int((~self.inliers).sum())


def estimate(row: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` of a row of the real-data tables."""
    T = np.array([[row[f"T_{i}{j}"] for j in range(3)] for i in range(3)], dtype=float)
    return T, np.array([row[f"h_{i}"] for i in range(3)], dtype=float)


def allowed(name: str, gap_deg: float) -> bool:
    """Whether ``name`` may be chosen when the largest uncovered cap is ``gap_deg`` (module
    notes, step 2)."""
    model = get_method(name).model
    if gap_deg <= MAX_GAP_DEG:
        return True
    if gap_deg <= THIN_GAP_DEG:
        return name in ROBUST_ON_CAPS
    return model in ("sphere", "bias")


def held_out_corrected(trials: pd.DataFrame, rec: Recording, method: str
                       ) -> np.ndarray | None:
    """Each half in time of ``rec`` corrected by ``method``'s fit on the other half, first
    half first; None unless both half-fits are usable."""
    rows = trials[(trials["algorithm"] == method) & (trials["fit_on"] != "all")]
    if len(rows) != 2 or not rows["usable"].astype(bool).all():
        return None
    halves = dict(zip(("first_half", "second_half"), rec.halves(), strict=True))
    out = []
    for test in ("first_half", "second_half"):
        T, h = estimate(rows[rows["test_on"] == test].iloc[0])
        out.append(np.linalg.solve(T, (halves[test].y - h).T).T)
    return np.vstack(out)


def held_out_errors(trials: pd.DataFrame, rec: Recording, method: str
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-sample held-out cost ``(||m||^2 - 1)^2`` (eq. 81's terms) and field error % of
    ``method`` (:func:`held_out_corrected`); None without usable half-fits."""
    m = held_out_corrected(trials, rec, method)
    if m is None:
        return None
    return (np.einsum("ij,ij->i", m, m) - 1.0) ** 2, field_error_pct(m)


def _tie_interval(diff: np.ndarray, gen: np.random.Generator) -> tuple[float, float]:
    """95 % block-bootstrap interval of ``mean(diff)``: contiguous blocks, because neighbouring
    samples of a slow rotation are correlated (an i.i.d. bootstrap would call too little a
    tie)."""
    n_blocks = min(_BLOCKS, len(diff))
    sums = np.array([b.mean() for b in np.array_split(diff, n_blocks)])
    means = sums[gen.integers(0, n_blocks, size=(_TIE_RESAMPLES, n_blocks))].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def choose(summary: pd.DataFrame, trials: pd.DataFrame, rec: Recording, gap_deg: float,
           *, seed: int = 0, refuse=None) -> tuple[pd.DataFrame, list[str], pd.Series | None,
                                                  str]:
    """Rank, find the tie and choose (module notes, step 4).

    Parameters
    ----------
    summary : DataFrame
        :func:`magbench.studies.real.recording_summary` of one preprocessing.
    trials, rec : DataFrame, Recording
        The rows and the recording they were fitted on (for the per-sample held-out errors).
    gap_deg : float
        Largest uncovered cap, for :func:`allowed`.
    refuse : callable, optional
        ``refuse(row) -> str``: a non-empty reason keeps the row from being chosen.

    Returns
    -------
    ranked : DataFrame
        ``summary`` in ranked order with ``rank`` (blank for methods without an
        out-of-sample score or not allowed), ``model``, ``worst_out_pct``, ``p95_out_pct``,
        ``tie`` and ``note`` columns.
    tie : list of str
        The methods tied with the best (the best first).
    chosen : Series or None
    how : str
        How the choice was made, one sentence.
    """
    out = summary.copy()
    out["model"] = [get_method(a).model for a in out["algorithm"]]
    errors = {a: held_out_errors(trials, rec, a) for a in out["algorithm"]}
    out["worst_out_pct"] = [e[1].max() if e is not None else np.nan for e in errors.values()]
    out["p95_out_pct"] = [np.percentile(e[1], 95) if e is not None else np.nan
                          for e in errors.values()]
    has_score = out["meaningful"].astype(bool) & np.isfinite(out["J_r_out"])
    ok_cover = np.array([allowed(a, gap_deg) for a in out["algorithm"]])
    rankable = has_score & ok_cover
    notes = []
    for r, score, cover in zip(out.itertuples(index=False), has_score, ok_cover, strict=True):
        if not r.meaningful:
            notes.append(_why_not(r))
        elif not score:
            notes.append("no out-of-sample score (a half-fit failed or was degenerate)")
        elif not cover:
            notes.append(f"not chosen: a {r.model} model is not trusted with a {gap_deg:.0f} "
                         "deg gap in coverage")
        else:
            notes.append("")
    out["note"] = notes
    best_worst = out.loc[rankable, "worst_out_pct"].min() if rankable.any() else np.nan
    demoted = rankable & (out["worst_out_pct"] > WORST_FACTOR * best_worst + WORST_SLACK_PCT)
    out.loc[demoted, "note"] = [f"held-out worst case {w:.2f} % vs best {best_worst:.2f} %"
                                for w in out.loc[demoted, "worst_out_pct"]]
    group = np.where(rankable & ~demoted, 0, np.where(rankable, 1, np.where(
        has_score, 2, np.where(out["meaningful"].astype(bool), 3, np.where(out["ok"], 4, 5)))))
    out = (out.assign(_g=group, _k=out["J_r_out"].fillna(np.inf))
           .sort_values(["_g", "_k"], kind="stable").reset_index(drop=True))
    n_ranked = int((out["_g"] <= 1).sum())
    out.insert(0, "rank", [i + 1 if i < n_ranked else pd.NA for i in range(len(out))])
    out["rank"] = out["rank"].astype("Int64")
    out["tie"] = False
    first = out[out["_g"] == 0]
    if first.empty:
        return out.drop(columns=["_g", "_k"]), [], None, "no method has an out-of-sample score"
    best = first.iloc[0]
    gen = rng(seed, "calibrate", "tie")
    e_best = errors[best["algorithm"]][0]
    tie = []
    for i, r in first.iterrows():
        e = errors[r["algorithm"]][0]
        low, _ = _tie_interval(e - e_best, gen)
        if r["algorithm"] == best["algorithm"] or low <= 0 or \
                r["J_r_out"] <= (1 + TIE_RTOL) * best["J_r_out"]:
            out.loc[i, "tie"] = True
            tie.append(r["algorithm"])
    members = out[out["tie"]].copy()
    members["_p"] = [MODEL_PARAMETERS[m] for m in members["model"]]
    members["_it"] = members["n_iter"] > 0
    # members are in ranked order, so equally simple methods keep the best held-out J_r first
    order = members.sort_values(["_p", "_it"], kind="stable")
    rest = out[(out["_g"] <= 1) & ~out["tie"]]
    chosen, how = None, ""
    for _, r in pd.concat([order, rest]).iterrows():
        reason = refuse(r) if refuse else ""
        if reason:
            idx = out.index[out["algorithm"] == r["algorithm"]][0]
            out.loc[idx, "note"] = f"refused: {reason}"
            continue
        chosen = r.drop(labels=[c for c in ("_p", "_it") if c in r.index])
        break
    if chosen is not None:
        tie_text = (f"tie (held-out J_r within noise of the best, {best['algorithm']}: 95 % "
                    f"block-bootstrap interval of the difference contains 0, or within "
                    f"{100 * TIE_RTOL:.0f} %): any of {', '.join(tie)}" if len(tie) > 1 else
                    f"{best['algorithm']} is best by held-out J_r, alone beyond noise")
        how = (f"{tie_text}; chosen {chosen['algorithm']}: the simplest of the tie (fewest "
               "model parameters, then closed form, then the best held-out J_r)"
               if chosen["algorithm"] in tie else
               f"{tie_text}; every method of the tie was refused, chosen "
               f"{chosen['algorithm']}, the next in the ranking")
    return out.drop(columns=["_g", "_k"]), tie, chosen, how


def _why_not(r) -> str:
    if isinstance(r.error, str) and r.error:
        return r.error
    if not r.coverage >= 0.5 * r.coverage_sphere:
        return (f"degenerate: calibrated directions cover {r.coverage:.2f} of the sphere, the "
                f"sphere fit's {r.coverage_sphere:.2f}")
    return f"J_r above twice the sphere fit's ({r.J_r_sphere_in:.3g})"


def _bootstrap(rec: Recording, method: str, preprocess: str, options: dict, B: int,
               seed: int, intervals: Intervals) -> dict | None:
    """Spread of ``B`` refits on samples drawn with replacement, against the Fisher
    half-widths: ``ratio`` is the bootstrap's 1.96 x standard deviation over the Fisher
    half-width, entry by entry (1 when the model-based interval is right)."""
    gen = rng(seed, "calibrate", "bootstrap", method)
    hs, As = [], []
    for _ in range(B):
        sample = rec.rows(np.sort(gen.integers(0, rec.K, rec.K)))
        try:
            cal = fit_recording(sample, method, preprocess, options)
            gauge = safe_gauge(cal.T, cal.h)
        except Exception:   # a failed refit is one replicate fewer, not a failed command
            continue
        hs.append(gauge.b)
        As.append(gauge.A)
    if len(hs) < max(10, B // 2):
        return None
    h_half = 1.96 * np.std(hs, axis=0, ddof=1)
    A_half = 1.96 * np.std(As, axis=0, ddof=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rh = h_half / intervals.h_half
        rA = (A_half / intervals.A_half)[intervals.A_half > 0]
    return {"replicates": len(hs), "h_half_width": h_half.tolist(),
            "A_half_width": A_half.tolist(), "ratio_h": rh.tolist(),
            "ratio_A_median": float(np.median(rA)) if rA.size else None,
            "ratio_A_range": [float(rA.min()), float(rA.max())] if rA.size else None}


def bootstrap_check(result: CalibrationResult, B: int, *, preprocess: str = "centre",
                    options: dict | None = None, seed: int = 0) -> dict | None:
    """The bootstrap check of :func:`calibrate_recording`'s choice (module notes, step 7).

    ``calibrate_recording(..., bootstrap=B)`` runs it; ``bootstrap=0`` leaves it to the caller,
    which may then do other work first (``calibrate`` hands its picture to a second process
    before it, so that the two overlap). The same arguments give the same answer either way.

    Parameters
    ----------
    result : CalibrationResult
        What :func:`calibrate_recording` returned.
    B : int
        Refits on samples drawn with replacement (0: none).
    preprocess, options, seed
        As given to :func:`calibrate_recording`.

    Returns
    -------
    dict or None
        The bootstrap / Fisher half-width ratios; None without a choice, without ``B``, or
        when fewer than ``max(10, B // 2)`` refits succeeded.
    """
    if not B or result.chosen is None or result.intervals is None or result.work is None:
        return None
    name = str(result.chosen["algorithm"])
    return _bootstrap(result.work, name, preprocess, dict((options or {}).get(name) or {}), B,
                      seed, result.intervals)


def second_round_reason(tie: Sequence[str], chosen: pd.Series | None, gap_deg: float,
                        first: Sequence[str]) -> str:
    """Why the second round of candidates must be fitted, or "" (module notes, step 3).

    Parameters
    ----------
    tie, chosen
        The first round's tie and choice (:func:`choose`).
    gap_deg : float
        Largest uncovered cap of the recording.
    first : sequence of str
        The methods of the first round.
    """
    if chosen is None:
        return "no method of the first round can be chosen"
    if gap_deg > MAX_GAP_DEG:
        return (f"a {gap_deg:.0f} deg gap in coverage: the methods robust on caps "
                f"({', '.join(ROBUST_ON_CAPS)}) are needed")
    if J_R_MINIMISER in first and J_R_MINIMISER not in tie:
        return (f"{J_R_MINIMISER}, which minimises J_r (81) itself, does not tie the best out "
                "of sample (a short recording, where a regularised fit may do better)")
    return ""


def calibrate_recording(rec: Recording, candidates: Sequence[str], *,
                        preprocess: str = "centre", options: dict | None = None,
                        seed: int = 0, call_timeout_s: float | None = None,
                        bootstrap: int = 50, rounds: int = 3,
                        second_round: Sequence[str] = ()) -> CalibrationResult:
    """Screen, fit, choose, trim and judge (module notes).

    Parameters
    ----------
    rec : Recording
        The (thinned) recording.
    candidates : sequence of str
        Methods to fit; with one, it is the choice unless it is refused or not meaningful.
    preprocess, options, seed, call_timeout_s
        As in :func:`magbench.studies.real.evaluate_recording`.
    bootstrap : int
        Refits on resampled inliers to check the Fisher intervals (0: none).
    rounds : int
        Largest number of fit-and-trim rounds.
    second_round : sequence of str
        Methods fitted only when :func:`second_round_reason` says they could change the
        choice (module notes, step 3); their names end in ``result.not_fitted`` otherwise.
    """
    options = options or {}
    centre, _, inliers = robust_sphere_fit(rec.y)
    screened = int((~inliers).sum())
    cover = coverage_report(rec.y[inliers] - centre)
    gap = cover["largest_gap_deg"]
    named = len(candidates) == 1 and not second_round
    names, later, escalated = list(candidates), list(second_round), ""

    def refuse(row: pd.Series) -> str:
        return refusal_reason(*estimate(row), work.y, centre)

    def fit(methods: list[str]) -> pd.DataFrame:
        return pd.DataFrame(evaluate_recording(work, methods, [preprocess], options=options,
                                               seed=seed, call_timeout_s=call_timeout_s))

    def rank(trials: pd.DataFrame, gap_deg: float) -> tuple:
        return choose(recording_summary(trials), trials, work, gap_deg, seed=seed,
                      refuse=refuse)

    limit = 0.0 if named else gap
    fallback = False
    for _ in range(rounds):
        work = rec.rows(np.flatnonzero(inliers))
        trials = fit(names)
        ranked, tie, chosen, how = rank(trials, limit)
        if later and (escalated := second_round_reason(tie, chosen, gap, names)):
            trials = pd.concat([trials, fit(later)], ignore_index=True)
            names, later = names + later, []
            ranked, tie, chosen, how = rank(trials, limit)
        if chosen is None and not named and MAX_GAP_DEG < gap <= THIN_GAP_DEG:
            # no robust full-model fit on a thin cap: fall back to the sphere and offset-only
            ranked, tie, chosen, how = rank(trials, 180.0)
            fallback = True
        if named and chosen is None:
            row = ranked.iloc[0]
            reason = refuse(row) if np.isfinite(row["T_00"]) else "no estimate"
            if bool(row["meaningful"]) and not reason:
                chosen, how = row, f"named: {row['algorithm']} (no out-of-sample score)"
        elif named:
            how = f"named: {chosen['algorithm']}"
        if chosen is None:
            break
        T, h = estimate(chosen)
        r = np.linalg.norm(np.linalg.solve(T, (rec.y - h).T), axis=0) - 1.0
        new = ~outliers(r, r[inliers])
        if np.array_equal(new, inliers) or new.sum() < 0.5 * rec.K:
            break
        inliers = new
    result = CalibrationResult(rec, inliers, screened, int((~inliers).sum()) - screened,
                               centre, cover, ranked, trials, tie, chosen, how,
                               not_fitted=later, second_round=escalated, work=work)
    if chosen is None:
        return result
    name = str(chosen["algorithm"])
    T, h = estimate(chosen)
    corrected = held_out_corrected(trials, work, name)
    result.verdict = (magnitude_verdict(corrected, held_out=True) if corrected is not None
                      else magnitude_verdict(np.linalg.solve(T, (work.y - h).T).T,
                                             held_out=False))
    model = get_method(name).model
    result.intervals = fisher_intervals(work.y, T, h, model)
    result.bootstrap = bootstrap_check(result, bootstrap, preprocess=preprocess,
                                       options=options, seed=seed)
    if cover["warning"]:
        result.warnings.append(cover["warning"])
    if not named and gap > MAX_GAP_DEG:
        limited = ("the sphere and offset-only models" if gap > THIN_GAP_DEG or fallback else
                   f"the full-model methods that stay robust on 60 deg caps "
                   f"({', '.join(ROBUST_ON_CAPS)})")
        result.warnings.append(
            f"with a {gap:.0f} deg gap in coverage the choice was limited to {limited} (the "
            f"coverage sweep: most full-model fits fail on caps of "
            f"{'45' if gap > THIN_GAP_DEG else '60'} deg); chosen model: {model} "
            f"({MODEL_PARAMETERS[model]} parameters); the result cannot be trusted beyond "
            "the directions recorded")
    elif named and model == "full" and not allowed(name, gap):
        result.warnings.append(f"{name} fits a {model} model, which the coverage sweep found "
                               f"unreliable with a {gap:.0f} deg gap in coverage")
    return result

