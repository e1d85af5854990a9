"""The calibrate study: spikes set aside, coverage-limited choice, refusal, the safe gauge.

Real-recording tests read ``$MAGBENCH_DATA`` (or ../shared/data/real beside the repository)
and are skipped when it is absent; their synthetic twins always run.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import magbench
from magbench.core.gauge import safe_gauge
from magbench.core.geometry import fibonacci_sphere
from magbench.core.model import CalibrationFailed
from magbench.core.robust import refusal_reason
from magbench.methods.registry import get_method, methods
from magbench.pipeline.calibration import calibrate_recording
from magbench.pipeline.choice import ROBUST_ON_CAPS, THIN_GAP_DEG, allowed
from magbench.pipeline.fitting import fit_recording
from magbench.sources.recordings import DATA_ENV, Recording, list_recordings, load_recording

SHARED = Path(os.environ.get(DATA_ENV) or Path(__file__).resolve().parents[3] / "shared" /
              "data" / "real")
needs_data = pytest.mark.skipif(not (SHARED / "INDEX.csv").exists(),
                                reason=f"real recordings not found ({DATA_ENV} unset, {SHARED} "
                                       "absent)")

FAST = ["ellipsoid", "fang", "magical", "diagonal", "sphere", "twostep"]
T_TRUE = np.array([[520.0, 20.0, -8.0], [0.0, 470.0, 15.0], [0.0, 0.0, 610.0]])
H_TRUE = np.array([900.0, -350.0, 120.0])


def synthetic(K: int = 1200, seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    m = rng.standard_normal((K, 3))
    m /= np.linalg.norm(m, axis=1)[:, None]
    y = m @ T_TRUE.T + H_TRUE + 3.0 * rng.standard_normal((K, 3))
    return Recording("synthetic", y, t=np.arange(K) * 0.01, n_rows=K)


def with_spikes(rec: Recording, seed: int = 1, share: float = 0.05) -> tuple[Recording, set]:
    """``share`` of the samples replaced by 10x spikes (the issue's test)."""
    rng = np.random.default_rng(seed)
    bad = rng.choice(rec.K, int(share * rec.K), replace=False)
    y = rec.y.copy()
    y[bad] *= 10.0
    return Recording(rec.name, y, t=rec.t, n_rows=rec.n_rows), set(bad.tolist())


def spread(result) -> float:
    return result.verdict["field_error_pct"]["p95"]


def check_spikes(rec: Recording, candidates: list[str]) -> None:
    clean = calibrate_recording(rec, candidates, bootstrap=0)
    spiky, bad = with_spikes(rec)
    dirty = calibrate_recording(spiky, candidates, bootstrap=0)
    set_aside = set(np.flatnonzero(~dirty.inliers).tolist())
    assert bad <= set_aside                                   # every spike reported
    assert len(set_aside - bad) <= 0.01 * rec.K               # few good samples lost
    assert dirty.verdict["held_out"] and clean.verdict["held_out"]
    assert spread(dirty) <= 1.5 * spread(clean)
    T = np.array([[dirty.chosen[f"T_{i}{j}"] for j in range(3)] for i in range(3)])
    assert np.linalg.cond(T) < 100


def test_5_percent_10x_spikes_are_set_aside_on_synthetic_data():
    check_spikes(synthetic(), FAST)


@needs_data
def test_5_percent_10x_spikes_are_set_aside_on_a_real_recording():
    rec = load_recording(SHARED, "hmc5883l_sphere", check=False).thinned(1500)
    check_spikes(Recording(rec.name, rec.y, t=rec.t, n_rows=rec.n_rows), FAST)


def test_allowed_models_follow_the_coverage_sweep():
    assert all(allowed(m, 60.0) for m in FAST)
    assert [m for m in FAST if allowed(m, 120.0)] == [m for m in FAST if m in ROBUST_ON_CAPS
                                                      or m == "sphere"]
    assert [m for m in FAST if allowed(m, THIN_GAP_DEG + 1)] == ["sphere"]


def test_a_60_degree_cap_never_chooses_a_method_that_fails_on_caps():
    rng = np.random.default_rng(3)
    y = fibonacci_sphere(600, z_range=(0.5, 1.0)) @ T_TRUE.T + H_TRUE
    rec = Recording("cap", rng.permutation(y + 2.0 * rng.standard_normal(y.shape)), n_rows=600)
    result = calibrate_recording(rec, FAST, bootstrap=0)
    assert result.coverage["largest_gap_deg"] > 100
    assert result.chosen["algorithm"] in ROBUST_ON_CAPS + ("sphere", "twostep_hi")
    assert any("choice was limited" in w for w in result.warnings)
    assert any("coverage is insufficient" in w for w in result.warnings)


def test_a_collapsing_method_is_never_chosen():
    from magbench.methods.registry import register, unregister

    def collapse(samples, **_):
        c = samples.mean(axis=0)
        far = c + 1e3 * np.array([1.0, 0.0, 0.0])
        return magbench.Calibration(np.linalg.norm(samples - far, axis=1).mean() * np.eye(3),
                                    far)

    register("collapse_test", label="Collapse", min_samples=4, family="extra",
             model="sphere")(collapse)
    try:
        result = calibrate_recording(synthetic(400), ["collapse_test", "fang"], bootstrap=0)
    finally:
        unregister("collapse_test")
    assert result.chosen["algorithm"] == "fang"
    row = next(r for r in result.ranked if r["algorithm"] == "collapse_test")
    assert not row["tie"] or row["note"].startswith("refused")


def test_fisher_intervals_agree_with_the_bootstrap_on_white_noise():
    result = calibrate_recording(synthetic(1000), ["fang"], bootstrap=150)
    b = result.bootstrap
    assert b["replicates"] == 150 and b["block"] <= 6         # white noise: short blocks
    assert all(0.7 < r < 1.4 for r in b["ratio_h"])
    assert 0.7 < b["ratio_A_median"] < 1.4


def large_rotation() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(75.0) * np.array([0.3, -0.5, 0.81]) /
                                np.linalg.norm([0.3, -0.5, 0.81])).as_matrix()


def check_gauge(T: np.ndarray, h: np.ndarray, y: np.ndarray) -> None:
    g = safe_gauge(T, h)
    np.testing.assert_array_equal(g.A, g.A.T)
    assert np.linalg.eigvalsh(g.A).min() > 0 and np.linalg.det(g.A) > 0
    own = np.linalg.norm(np.linalg.solve(T, (y - h).T), axis=0)
    np.testing.assert_allclose(np.linalg.norm((y - g.b) @ g.A.T, axis=1), own, rtol=1e-9)


MAG_ONLY = [m for m in methods() if get_method(m).magnetometer_only
            and get_method(m).option_names() != ["attitude"]]


@pytest.mark.parametrize("name", MAG_ONLY)
def test_every_written_A_is_spd_with_the_methods_norms_under_a_large_rotation(name):
    rng = np.random.default_rng(8)
    S = np.array([[1.2, 0.1, 0.0], [0.1, 0.9, 0.05], [0.0, 0.05, 1.1]])
    T = S @ large_rotation()                      # 75 deg of rotation in the model's T
    y = rng.permutation(fibonacci_sphere(300)) @ T.T + [0.3, -0.2, 0.1]
    y += 0.005 * rng.standard_normal(y.shape)
    try:
        cal = magbench.calibrate(y, name)
    except CalibrationFailed:
        pytest.skip(f"{name} fails on these data (its own tests cover that)")
    check_gauge(cal.T, cal.h, y)


@needs_data
def test_every_written_A_is_spd_on_each_real_recording():
    checked = 0
    for rec_name in list_recordings(SHARED):
        rec = load_recording(SHARED, rec_name, check=False).thinned(300)
        for name in MAG_ONLY:
            if get_method(name).min_samples > rec.K:
                continue
            try:
                cal = fit_recording(rec, name, "centre")
            except (CalibrationFailed, ValueError):
                continue
            if refusal_reason(cal.T, cal.h, rec.y, cal.h):
                continue        # never written (e.g. a printed variant's cond(T) of 4e11)
            check_gauge(cal.T, cal.h, rec.y)
            checked += 1
    assert checked > 0.7 * len(MAG_ONLY) * len(list_recordings(SHARED))


def spiral(seed: int, K: int = 400, phi: float = 0.7, drift: float = 1.0,
           sigma: float = 3.0) -> Recording:
    """A continuous path from +Z to -Z in ten turns, AR(1) noise of coefficient ``phi`` and a
    slow sinusoidal drift of amplitude ``drift`` on every axis (a period of the recording)."""
    gen = np.random.default_rng(seed)
    k = np.arange(K) + 0.5
    z = 1 - 2 * k / K
    theta = 20 * np.pi * k / K + gen.uniform(0, 2 * np.pi)
    m = np.column_stack([np.sqrt(1 - z**2) * np.cos(theta), np.sqrt(1 - z**2) * np.sin(theta),
                         z])
    w = sigma * np.sqrt(1 - phi**2) * gen.standard_normal((K, 3))
    e = np.empty((K, 3))
    e[0] = sigma * gen.standard_normal(3)
    for i in range(1, K):
        e[i] = phi * e[i - 1] + w[i]
    e += drift * np.sin(2 * np.pi * k[:, None] / K + gen.uniform(0, 2 * np.pi, 3))
    return Recording("spiral", m @ T_TRUE.T + H_TRUE + e, t=k / K, n_rows=K)


def test_block_bootstrap_intervals_cover_the_truth_under_correlated_noise():
    """95 % intervals on b and A under AR(1) noise and a slow drift: the model-based ones
    cover far too little, the reported (wider) ones 90-99 % of the time."""
    A_true = safe_gauge(T_TRUE, H_TRUE).A
    upper = np.triu_indices(3)
    model, reported = [], []
    for seed in range(16):
        result = calibrate_recording(spiral(seed), ["ellipsoid"], bootstrap=40, seed=seed)
        iv, bs = result.intervals, result.bootstrap
        assert bs["block"] > 5                       # longer than the residuals' correlation
        err_b, err_A = np.abs(iv.h - H_TRUE), np.abs(iv.A - A_true)[upper]
        model += [*(err_b <= iv.h_half), *(err_A <= iv.A_half[upper])]
        reported += [*(err_b <= bs["wider_h"]), *(err_A <= np.array(bs["wider_A"])[upper])]
    assert np.mean(model) < 0.8
    assert 0.88 <= np.mean(reported) <= 0.995


def test_prepare_strides_the_kept_inliers_to_max_samples():
    from magbench.core.robust import Screen
    from magbench.pipeline.screening import prepare

    rec = synthetic(1000)
    kept = np.arange(1000) % 4 != 0
    inliers = np.arange(1000) != 1
    work, stride = prepare(rec, Screen(np.zeros(3), 1.0, kept, inliers), 300)
    assert stride == 3 and work.K == 250
    np.testing.assert_array_equal(work.y, rec.y[np.flatnonzero(kept & inliers)[::3]])


def test_retrim_sets_aside_what_the_chosen_fit_cannot_explain():
    import pandas as pd

    from magbench.core.robust import screen
    from magbench.pipeline.screening import retrim

    rec, bad = with_spikes(synthetic(600), share=0.02)
    y = rec.y.copy()
    y[10] = H_TRUE + 1.2 * (y[10] - H_TRUE) / 1.0               # 20 % too long: soft spike
    rec = Recording("x", y, t=rec.t, n_rows=600)
    row = pd.Series({**{f"T_{i}{j}": T_TRUE[i, j] for i in range(3) for j in range(3)},
                     **{f"h_{i}": H_TRUE[i] for i in range(3)}})
    out = retrim(rec, screen(rec.y), row)
    assert set(np.flatnonzero(~out.inliers)) >= bad | {10}


def test_judge_fails_a_fit_that_lost_the_data_scale():

    from magbench.core.verdict import Gate
    from magbench.pipeline.gate import judge

    result = calibrate_recording(synthetic(600), ["ellipsoid"], bootstrap=0)
    assert result.fitness["status"] == "PASS"
    result.field_strength *= 10
    judge(result, Gate())
    assert result.fitness["status"] == "FAIL"
    assert "from the data's field" in result.fitness["reasons"][0]


def test_an_extra_score_can_decide_the_choice():
    rec = synthetic(600)
    plain = calibrate_recording(rec, ["ellipsoid", "fang", "twostep"], bootstrap=0)
    assert len(plain.tie) > 1
    loser = plain.chosen["algorithm"]

    def penalise(summary, trials, work):                # e.g. a direction veto per method
        assert len(trials) and work.K > 0
        return "direction_deg", [np.nan if r["algorithm"] == loser else 1.0 for r in summary]

    extra = calibrate_recording(rec, ["ellipsoid", "fang", "twostep"], bootstrap=0,
                                extra=penalise)
    assert extra.chosen["algorithm"] != loser
    assert all("direction_deg" in r for r in extra.ranked)


def _spiral_track(K: int, band_deg: float = 90.0) -> np.ndarray:
    """Field directions of a sensor turned smoothly in time: pole to pole in 12 turns, or,
    with ``band_deg`` < 90, round and round within +-``band_deg`` of the xy-plane."""
    s = np.linspace(0.0, 1.0, K)
    if band_deg >= 90:
        theta, phi = np.arccos(1 - 2 * s), 2 * np.pi * 12 * s
        return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                np.cos(theta)])
    el, phi = np.radians(band_deg) * np.sin(2 * np.pi * 17 * s), 2 * np.pi * 6 * s
    return np.column_stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)])


def test_on_a_band_the_sphere_fit_generalises_and_the_full_model_is_not_chosen():
    from magbench.pipeline.auto import candidate_rounds

    T = np.array([[50.5, 0.4, 0.0], [0.0, 49.6, 0.3], [0.0, 0.0, 50.2]])
    h = np.array([30.0, -12.0, 8.0])
    gen = np.random.default_rng(0)
    y = _spiral_track(500, band_deg=8) @ T.T + h + 3.0 * gen.standard_normal((500, 3))
    first, second = candidate_rounds(False, "auto")
    result = calibrate_recording(Recording("band", y, t=np.arange(500) * 0.05, n_rows=500),
                                 first, second_round=second, bootstrap=0)
    assert get_method(result.chosen["algorithm"]).model in ("sphere", "bias")
    # on the whole sphere, where the compass is used, the choice beats the full models that
    # minimise J_r on the band (the first round's), and most full models
    sphere = fibonacci_sphere(2000) @ T.T + h + 3.0 * gen.standard_normal((2000, 3))

    def whole_sphere_spread(row) -> float:
        Tf, hf = (np.array([[row[f"T_{i}{j}"] for j in range(3)] for i in range(3)]),
                  np.array([row[f"h_{i}"] for i in range(3)]))
        n = np.linalg.norm(np.linalg.solve(Tf, (sphere - hf).T), axis=0)
        return 100 * n.std() / n.mean()

    chosen = whole_sphere_spread(result.chosen)
    full = {r["algorithm"]: whole_sphere_spread(r) for r in result.ranked
            if get_method(r["algorithm"]).model == "full" and np.isfinite(r["T_00"])}
    assert chosen < np.median(list(full.values()))
    assert chosen < min(full[n] for n in ("ellipsoid", "fang", "twostep", "wu_shi_nm"))


def test_a_fit_whose_field_is_off_the_data_scale_is_not_ranked_the_next_is_chosen():
    from magbench.pipeline.choice import choose

    base = {"meaningful": True, "error": "", "ok": True, "n_iter": 10, "coverage": 0.9,
            "coverage_sphere": 0.9, "J_r_sphere_in": 1.0}
    rows = [{**base, "algorithm": "ali", "J_r_out": 0.010, "J_r_worst": 0.0010,
             "field_pct": 80.0},
            {**base, "algorithm": "fang", "J_r_out": 0.013, "J_r_worst": 0.0012,
             "field_pct": 2.0, "n_iter": 0}]
    choice = choose(rows, {"ali": None, "fang": None}, gap_deg=0.0, max_field_pct=25.0)
    assert choice.chosen["algorithm"] == "fang"
    ali = next(r for r in choice.ranked if r["algorithm"] == "ali")
    assert not ali["eligible"] and "fitted field 80 % from the data's field" in ali["note"]
    # without the check, the fit with the better score would have been chosen
    assert choose(rows, {"ali": None, "fang": None}, gap_deg=0.0).chosen["algorithm"] == "ali"


def _gate_refusing(monkeypatch, row) -> None:
    """The gate FAILs the fit of ``row`` (known by its field strength) and judges the rest
    as it would."""
    import magbench.pipeline.gate as gate_module
    from magbench.pipeline.holdout import estimate

    refused = float(np.cbrt(abs(np.linalg.det(estimate(row)[0]))))
    real_fitness = gate_module.fitness

    def fitness(gate, **kw):
        out = real_fitness(gate, **kw)
        if abs(kw["field"] / refused - 1) < 1e-12:
            out = {**out, "status": "FAIL", "reasons": ["refused by this test", *out["reasons"]]}
        return out

    monkeypatch.setattr(gate_module, "fitness", fitness)


def test_when_the_chosen_fit_fails_the_gate_the_next_that_passes_is_written(monkeypatch):
    rec = synthetic(600)
    first = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    assert first.chosen["algorithm"] == "ellipsoid" and first.fitness["status"] == "PASS"
    _gate_refusing(monkeypatch, first.chosen)    # a reason of the fit's own, not the data's
    out = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    assert out.chosen["algorithm"] == "sphere" and out.fitness["status"] != "FAIL"
    assert out.how == ("ellipsoid ranked first but fails the gate (refused by this test); "
                       "sphere, the next eligible one, passes")
    note = next(r for r in out.ranked if r["algorithm"] == "ellipsoid")["note"]
    assert note == "fails the gate: refused by this test"
    # a named method is the user's choice: it is judged, never replaced
    named = calibrate_recording(rec, ["ellipsoid"], bootstrap=0)
    assert named.chosen["algorithm"] == "ellipsoid" and named.fitness["status"] == "FAIL"


def test_a_fit_passed_over_as_possibly_worse_than_raw_is_not_the_gates_fallback(monkeypatch):
    # The choice passed over the ellipsoid (off the recorded directions it could be worse
    # than no correction); when the sphere fit it chose FAILs, the FAIL stands: the raw data
    # it leaves are no worse than that, while the ellipsoid could be.
    import magbench.pipeline.choice as choice

    rec = synthetic(600)
    real_beyond = choice.beyond_raw

    def ellipsoid_could_be_worse(ranked):
        return [{**r, "beyond_raw_pct": 1.0 if r["algorithm"] == "ellipsoid" else -1.0}
                if r["eligible"] else r for r in real_beyond(ranked)]

    monkeypatch.setattr(choice, "beyond_raw", ellipsoid_could_be_worse)
    kept = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    assert kept.chosen["algorithm"] == "sphere"
    assert next(r for r in kept.ranked if r["algorithm"] == "ellipsoid")["note"].startswith(
        "passed over: off the recorded directions")

    _gate_refusing(monkeypatch, kept.chosen)
    out = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    assert out.chosen["algorithm"] == "sphere" and out.fitness["status"] == "FAIL"
    assert out.fitness["reasons"][0] == "refused by this test"
    # with nothing passed over, the ellipsoid (which the gate does not refuse) is chosen
    monkeypatch.setattr(choice, "beyond_raw", real_beyond)
    assert calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0).chosen[
        "algorithm"] == "ellipsoid"


def test_a_written_fit_that_could_be_worse_than_raw_off_the_data_says_so(monkeypatch):
    # When every fit that could be written could be worse than none off the recorded
    # directions, the ranking's choice is written with a warning that says by how much.
    import magbench.pipeline.choice as choice

    rec = synthetic(600)
    plain = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    assert not any("no correction on the directions not recorded" in w
                   for w in plain.warnings)
    real_beyond = choice.beyond_raw

    def every_fit_could_be_worse(ranked):
        return [{**r, "beyond_raw_pct": 1.25, "beyond_raw_if": "sphere"} if r["eligible"]
                else r for r in real_beyond(ranked)]

    monkeypatch.setattr(choice, "beyond_raw", every_fit_could_be_worse)
    out = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    assert out.chosen["algorithm"] == plain.chosen["algorithm"]
    assert f"{plain.chosen['algorithm']} could leave the field 1.25 points more spread than " \
           "no correction on the directions not recorded (if sphere's model is the " \
           "sensor's)" in " ".join(out.warnings)


@pytest.mark.parametrize(("step", "status"), [(0.0, "PASS"), (0.08, "WARN"), (0.25, "WARN")])
def test_a_hard_iron_that_steps_halfway_is_never_a_pass(step, status):
    K = 1200
    gen = np.random.default_rng(4)
    m = np.concatenate([_spiral_track(K // 2), _spiral_track(K // 2)])   # every face, twice
    y = m @ T_TRUE.T + H_TRUE + 1.5 * gen.standard_normal((K, 3))
    y[K // 2:] += step * T_TRUE @ np.array([1.0, 0.0, 0.0]) / np.linalg.norm(T_TRUE[:, 0]) \
        * np.cbrt(np.linalg.det(T_TRUE))
    rec = Recording("step", y, t=np.arange(K) * 0.05, n_rows=K)
    result = calibrate_recording(rec, ["ellipsoid", "sphere"], bootstrap=0)
    moved = [r for r in result.fitness["reasons"] if "offset moves" in r]
    if step == 0.0:
        assert result.fitness["status"] == "PASS" and not moved
        assert result.verdict["halves_offset_change_pct"] < 2.0
    else:
        assert result.fitness["status"] == status and moved
        assert result.verdict["halves_offset_change_pct"] == pytest.approx(100 * step, rel=0.3)
        # past the FAIL line, written only because the raw data (an offset twice the field)
        # are far worse, and it says so
        written = [r for r in result.fitness["reasons"] if r.startswith("written nonetheless")]
        assert bool(written) == (step > 0.12)


@pytest.fixture
def faulty():
    """The fault-injecting methods for one test only: registered for the whole session they
    would join every later ``candidates=all`` (and ``faulty_hangs`` would hang it)."""
    import sys

    import tests.plugins.faulty  # noqa: F401
    from magbench.methods.registry import _REGISTRY, unregister

    yield
    for name in [n for n in _REGISTRY if n.startswith("faulty_")]:
        unregister(name)
    sys.modules.pop("tests.plugins.faulty", None)


def test_a_bootstrap_refit_that_ends_its_process_is_one_replicate_fewer(faulty):
    import dataclasses

    from magbench.pipeline.bootstrap import bootstrap_check
    from magbench.pipeline.choice import Choice

    result = calibrate_recording(synthetic(400), ["sphere"], bootstrap=0)
    chosen = {**result.chosen, "algorithm": "faulty_exit"}
    result = dataclasses.replace(result, choice=Choice(result.ranked, chosen, result.how))
    out = bootstrap_check(result, 40, seed=3)       # about half of the refits end their child
    assert out is not None and 20 <= out["replicates"] < 40


def test_a_cap_whose_sphere_radius_is_biased_is_judged_on_the_agreed_field():
    """A 60-degree cap: the sphere fit's radius is off the true field, the full models agree
    on it; none of them is refused for its scale."""
    gen = np.random.default_rng(2)
    m = fibonacci_sphere(500, z_range=(0.5, 1.0))
    y = m @ T_TRUE.T + H_TRUE + 1.0 * gen.standard_normal((500, 3))
    rec = Recording("cap", y, t=np.arange(500) * 0.05, n_rows=500)
    result = calibrate_recording(rec, ["ellipsoid", "fang", "magical", "sphere"], bootstrap=0)
    truth = np.cbrt(np.linalg.det(T_TRUE))
    assert result.field_strength == pytest.approx(truth, rel=0.05)
    assert not any("from the data's field" in r for r in result.fitness["reasons"])
