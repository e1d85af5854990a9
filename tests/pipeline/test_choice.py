"""calibrate's choice, step by step, on hand-made candidate tables."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.pipeline.choice import (
    TIE_RTOL,
    WHOLE_SPHERE,
    allowed,
    annotate,
    choose,
    eligibility,
    find_tie,
    gyro_rule,
    pick,
    rank,
)

T_COLUMNS = {f"T_{i}{j}": float(i == j) for i in range(3) for j in range(3)}


def table(rows):
    """Candidates as fold_summary gives them: (name, mean held-out J_r, worst fold, n_iter)."""
    return [{"algorithm": a, "J_r_out": m, "J_r_worst": w, "n_iter": it,
             "meaningful": True, "ok": True, "error": "", "coverage": 1.0,
             "coverage_sphere": 1.0, "J_r_sphere_in": 1.0, "J_r_in": m,
             **T_COLUMNS, **{f"h_{i}": 0.0 for i in range(3)}}
            for a, m, w, it in rows]


def by_name(rows):
    """The rows by method name."""
    return {r["algorithm"]: r for r in rows}


def run(rows, gap=20.0, refuse=None):
    return choose(table(rows), {}, gap, refuse=refuse)


def test_a_simpler_model_wins_only_when_it_ties_on_mean_and_worst_fold():
    tie = run([("fang", 1.0, 2.0, 0), ("sphere", 1.0 + TIE_RTOL / 2, 2.0, 0)])
    assert tie.chosen["algorithm"] == "sphere" and tie.tie == ["fang", "sphere"]
    worse_worst = run([("fang", 1.0, 2.0, 0), ("sphere", 1.0, 2.5, 0)])
    assert worse_worst.chosen["algorithm"] == "fang" and worse_worst.tie == ["fang"]
    worse_mean = run([("fang", 1.0, 2.0, 0), ("sphere", 1.2, 2.0, 0)])
    assert worse_mean.chosen["algorithm"] == "fang"


def test_the_sphere_wins_when_it_is_better_out_of_sample():
    # a band: the full models extrapolate badly, the sphere fit holds
    out = run([("fang", 3.0, 6.0, 0), ("ellipsoid", 3.2, 7.0, 0), ("sphere", 1.0, 1.5, 0)])
    assert out.chosen["algorithm"] == "sphere"
    assert out.ranked[0]["algorithm"] == "sphere"


def test_on_a_cap_the_sphere_competes_with_the_cap_robust_full_models():
    out = run([("ellipsoid", 0.5, 0.6, 0), ("fang", 1.0, 1.2, 0), ("sphere", 0.9, 1.0, 0)],
              gap=120.0)
    assert not by_name(out.ranked)["ellipsoid"]["eligible"]
    assert out.chosen["algorithm"] == "sphere"
    assert allowed("magical", 120.0) and not allowed("fang", 150.0)


@pytest.mark.parametrize(("gyro", "chosen"), [((0.5, 0.5), "sar_ls"), ((0.98, 1.0), "fang")])
def test_a_gyro_aided_fit_must_beat_the_best_magnetometer_fit(gyro, chosen):
    out = run([("fang", 1.0, 1.0, 0), ("sar_ls", *gyro, 0)])
    assert out.chosen["algorithm"] == chosen
    if chosen == "fang":
        assert "must beat the best magnetometer-only fit (fang)" in \
            by_name(out.ranked)["sar_ls"]["note"]


def test_a_pass_mark_both_share_does_not_keep_a_gyro_fit_out():
    # A veto's column is 1 for every candidate it lets through: neither can beat the other
    # on it, so it must not decide the gyro rule; the held-out J_r scores do.
    t = [{**r, "direction_ok": 1.0} for r in table([("fang", 1.0, 1.0, 0),
                                                    ("sar_ls", 0.5, 0.5, 0)])]
    scores = ("J_r_out", "J_r_worst", "direction_ok")
    assert choose(t, {}, 20.0, scores=scores).chosen["algorithm"] == "sar_ls"
    worse = [{**r, "direction_ok": d} for r, d in zip(t, [1.0, 2.0], strict=True)]
    out = choose(worse, {}, 20.0, scores=scores)
    assert out.chosen["algorithm"] == "fang"
    assert "must beat" in by_name(out.ranked)["sar_ls"]["note"]


def test_each_step_alone():
    t = eligibility(annotate(table([("fang", 1.0, 1.0, 0), ("magical", np.nan, np.nan, 30)]),
                             {}), 20.0)
    assert by_name(t)["magical"]["note"].startswith("no out-of-sample")
    ranked = rank(gyro_rule(t))
    assert [r["rank"] for r in ranked] == [1, None]
    tied = find_tie(ranked)
    assert [r["tie"] for r in tied] == [True, False]
    out, chosen = pick(tied, refuse=lambda r: "no")
    assert chosen is None and out[0]["note"] == "refused: no"


def test_an_extra_score_joins_the_tie():
    t = [{**r, "direction": d} for r, d in zip(table([("fang", 1.0, 1.0, 0),
                                                      ("sphere", 1.0, 1.0, 0)]), [0.1, 0.5],
                                               strict=True)]
    plain = choose(t, {}, 20.0)
    extra = choose(t, {}, 20.0, scores=("J_r_out", "J_r_worst", "direction"))
    assert plain.chosen["algorithm"] == "sphere" and extra.chosen["algorithm"] == "fang"


def test_a_vetoed_candidate_says_why_in_its_note():
    reason = "held-out direction error 9.00 deg, 4.00 deg worse than fang's 5.00 deg"
    t = [{**r, "direction_ok": ok, "veto": why} for r, ok, why in zip(
        table([("fang", 1.0, 1.0, 0), ("als", 0.5, 0.5, 0), ("sphere", 1.0, 1.0, 0)]),
        [1.0, np.nan, np.nan], ["", reason, ""], strict=True)]
    out = by_name(choose(t, {}, 20.0, scores=("J_r_out", "J_r_worst", "direction_ok")).ranked)
    assert out["als"]["note"] == f"set aside: {reason}" and not out["als"]["eligible"]
    # a missing score without a reason is still said to be missing
    assert out["sphere"]["note"].startswith("no out-of-sample score")
    assert out["fang"]["eligible"]


def test_a_refused_fit_passes_the_choice_to_the_next_of_the_tie():
    out = run([("fang", 1.0, 1.0, 0), ("ellipsoid", 1.0, 1.0, 0)],
              refuse=lambda r: "test refusal" if r["algorithm"] == "fang" else "")
    assert out.chosen["algorithm"] == "ellipsoid"
    assert by_name(out.ranked)["fang"]["note"] == "refused: test refusal"


def with_fit(row, T, h):
    """``row`` with the fit ``y = T m + h``."""
    return {**row, **{f"T_{i}{j}": T[i, j] for i in range(3) for j in range(3)},
            **{f"h_{i}": h[i] for i in range(3)}}


def band_candidates(h):
    """A band's two fits: Fang best held out, alone in the tie, with a scale across the band
    10 % above the in-plane ones; the sphere fit (unit scale) behind it; both centred on h."""
    fang, sphere = table([("fang", 1.0, 1.0, 0), ("sphere", 1.5, 1.5, 0)])
    return [with_fit(fang, np.diag([1.0, 1.0, 1.1]), h), with_fit(sphere, np.eye(3), h)]


def spread_pct(v):
    n = np.linalg.norm(v, axis=1)
    return 100 * n.std() / n.mean()


def test_a_fit_that_could_be_worse_than_raw_off_the_data_is_passed_over():
    # Raw data already calibrated if the sphere fit is right: Fang's correction would then
    # spread the field on the whole sphere (its 10 % across the band), where none would not.
    out = choose(band_candidates(np.zeros(3)), {}, 20.0)
    fang, sphere = by_name(out.ranked)["fang"], by_name(out.ranked)["sphere"]
    assert out.tie == ["fang"] and out.chosen["algorithm"] == "sphere"
    expected = spread_pct(fibonacci_sphere(WHOLE_SPHERE) @ np.diag([1.0, 1.0, 1 / 1.1]))
    assert fang["beyond_raw_if"] == "sphere"
    assert np.isclose(fang["beyond_raw_pct"], expected, rtol=1e-12) and expected > 2.0
    assert fang["note"].startswith("passed over: off the recorded directions it could leave "
                                   f"the field {expected:.2f} points more spread")
    assert sphere["beyond_raw_pct"] <= 0 and sphere["note"] == ""
    assert "chosen sphere, the first that could not" in out.how


def test_where_the_raw_data_need_a_correction_no_fit_is_passed_over():
    # The same two fits about an offset of five times the field: either correction is far
    # better than none on the whole sphere, whichever model is right; the ranking decides.
    out = choose(band_candidates(np.array([5.0, 0.0, 0.0])), {}, 20.0)
    assert out.chosen["algorithm"] == "fang"
    assert all(r["beyond_raw_pct"] < -50 for r in out.ranked)


def test_round_off_is_not_worse_than_raw():
    # A calibrated sensor's noise-free fits differ by round-off: the ranking decides.
    fang, sphere = table([("fang", 1.0, 1.0, 0), ("sphere", 1.5, 1.5, 0)])
    out = choose([with_fit(fang, np.eye(3) * (1 + 1e-15), np.zeros(3)),
                  with_fit(sphere, np.eye(3), np.zeros(3))], {}, 20.0)
    assert 0 < by_name(out.ranked)["fang"]["beyond_raw_pct"] < 1e-12
    assert by_name(out.ranked)["sphere"]["beyond_raw_pct"] <= 0
    assert out.chosen["algorithm"] == "fang"


def test_when_every_fit_could_be_worse_than_raw_the_ranking_stands():
    fang, ellipsoid = table([("fang", 1.0, 1.0, 0), ("ellipsoid", 1.5, 1.5, 0)])
    out = choose([with_fit(fang, np.diag([1.0, 1.0, 1.1]), np.zeros(3)),
                  with_fit(ellipsoid, np.diag([1.1, 1.0, 1.0]), np.zeros(3))], {}, 20.0)
    assert all(r["beyond_raw_pct"] > 0 for r in out.ranked)
    assert out.chosen["algorithm"] == "fang" and by_name(out.ranked)["fang"]["note"] == ""


def test_the_choice_does_not_depend_on_fit_times():
    rows = [("fang", 1.0, 1.0, 0), ("ellipsoid", 1.01, 1.0, 0), ("twostep", 1.0, 1.0, 3)]
    chosen = {choose([{**r, "time_s": t} for r, t in zip(table(rows), times, strict=True)], {},
                     20.0).chosen["algorithm"]
              for times in ([1e-3, 2e-3, 3e-3], [3e-3, 2e-3, 1e-3])}
    assert chosen == {"fang"}            # closed form first, then the better held out
