import numpy as np
import pandas as pd
import pytest

from magbench.core.model import Calibration
from magbench.engine.sweep import run_study
from magbench.methods.registry import register, unregister
from magbench.sources.synthetic import Point
from magbench.studies.review import ROW_COLUMNS, ReviewStudy, points_for, read_trials, trial_rows

SMALL = Point(K=60)


def spec(**kw) -> ReviewStudy:
    base = dict(name="t", points=[SMALL, Point(K=60, gamma=0.5)], trials=6, seed=11,
                algorithms=["magical", "dorveaux"])
    base.update(kw)
    return ReviewStudy(**base)


def without_time(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=["time_s"], errors="ignore")


def run_sweep(study: ReviewStudy, out_dir, **kw) -> tuple[pd.DataFrame, pd.DataFrame]:
    run_study(study, out_dir, progress=False, **kw)
    return read_trials(out_dir / "trials.csv"), study.summarize(out_dir)


def test_rows_have_every_column_and_recomputable_truth():
    rows = trial_rows(SMALL, 0, 1, ["magical", "dorveaux"])
    assert [r["algorithm"] for r in rows] == ["magical", "dorveaux"]
    for r in rows:
        assert [c for c in r if c != "time_s"] == ROW_COLUMNS and r["time_s"] >= 0
        assert r["ok"] and r["error"] == "" and r["meaningful"]
        assert r["J"] == pytest.approx(r["J_h"] + r["J_T"])
    # both methods saw the same dataset
    assert rows[0]["h_true_0"] == rows[1]["h_true_0"]


def test_same_rows_whatever_the_number_of_workers(tmp_path):
    one, _ = run_sweep(spec(), tmp_path / "a", n_jobs=1, chunk_size=2)
    two, _ = run_sweep(spec(), tmp_path / "b", n_jobs=2, chunk_size=4)
    pd.testing.assert_frame_equal(without_time(one), without_time(two))
    a = pd.read_csv(tmp_path / "a" / "trials.csv")
    b = pd.read_csv(tmp_path / "b" / "trials.csv")
    pd.testing.assert_frame_equal(a, b)
    assert len(one) == 2 * 6 * 2
    assert not (tmp_path / "a" / "parts").exists()


@pytest.fixture
def failing_methods():
    def raises(y):
        raise np.linalg.LinAlgError("boom")

    def capped(y):
        return Calibration(np.eye(3), np.zeros(3), n_iter=5, converged=False,
                           message="iteration cap 5 reached")

    register("test_raises", label="raises", min_samples=4)(raises)
    register("test_capped", label="capped", min_samples=4)(capped)
    yield
    unregister("test_raises")
    unregister("test_capped")


def test_failures_are_rows_and_the_run_goes_on(failing_methods, tmp_path):
    trials, summary = run_sweep(spec(algorithms=["test_raises", "test_capped", "magical"],
                                     points=[SMALL], trials=3), tmp_path)
    by = trials.groupby("algorithm")
    raised = by.get_group("test_raises")
    assert (~raised["ok"]).all() and raised["J"].isna().all()
    assert raised["error"].str.contains("linear algebra failed").all()
    capped = by.get_group("test_capped")
    assert (~capped["ok"]).all() and capped["error"].str.contains("iteration cap").all()
    assert capped["J"].notna().all()  # a capped answer is still scored
    assert by.get_group("magical")["ok"].all()
    rb = summary.set_index("algorithm")["RB_pct"]
    assert rb["test_raises"] == 0 and rb["magical"] == 100


def test_points_for_varies_one_parameter():
    pts = points_for(Point(), "K", [50, 150])
    assert [p.K for p in pts] == [50, 150] and all(p.gamma == 0.05 for p in pts)
    assert points_for(Point(), None, []) == [Point()]
    with pytest.raises(ValueError, match="cannot set alpha"):
        points_for(Point(), "alpha", [1])


def test_methods_with_an_assumed_noise_level_get_the_true_one():
    seen = []

    def fit(y, *, sigma=0.005):
        seen.append(sigma)
        return Calibration(np.eye(3), np.zeros(3))

    register("test_sigma", label="sigma", min_samples=4)(fit)
    try:
        trial_rows(Point(K=30, sigma=0.03), 0, 1, ["test_sigma"])
        trial_rows(Point(K=30, sigma=0.03), 0, 1, ["test_sigma"], {"test_sigma": {"sigma": 0.1}})
        trial_rows(Point(K=30, sigma=0.0), 0, 1, ["test_sigma"])
    finally:
        unregister("test_sigma")
    assert seen == [0.03, 0.1, 0.005]


def test_an_option_axis_runs_the_method_per_value_on_the_same_dataset(tmp_path):
    from magbench.studies.review import OptionAxis

    axis = OptionAxis.parse("options.crassidis.P0", [1e-6, 1e-3])
    study = ReviewStudy("p0", [Point()], 3, 5, ["crassidis", "sphere"], axis=axis)
    run_study(study, tmp_path, n_jobs=1, progress=False)
    summary = study.summarize(tmp_path)
    trials = read_trials(tmp_path / "trials.csv")
    assert list(trials.columns) == [*ROW_COLUMNS, "crassidis.P0", "time_s"]
    first = trials[trials["trial"] == 0]
    # default run, the other method (no value), then one row per value, all on one dataset
    assert list(first["algorithm"]) == ["crassidis", "sphere", "crassidis", "crassidis"]
    assert first["crassidis.P0"].isna().tolist() == [True, True, False, False]
    assert first["J0"].nunique() == 1
    # a tighter P0 keeps the EKF closer to its start: a different estimate
    assert first["T_00"].iloc[2] != first["T_00"].iloc[3]
    assert len(summary) == 4 and summary["n"].eq(3).all()
    assert summary["crassidis.P0"].isna().sum() == 2


def test_summary_from_the_chunked_columns_equals_the_whole_file_summary(tmp_path, monkeypatch):
    import magbench.core.files as files
    from magbench.studies.review import summarize_review

    study = spec()
    run_study(study, tmp_path, progress=False)
    expected = summarize_review(read_trials(tmp_path / "trials.csv"))
    # Chunks of 5 rows: every point and method spans several chunks.
    monkeypatch.setattr(files, "CHUNK_ROWS", 5)
    pd.testing.assert_frame_equal(study.summarize(tmp_path), expected, check_exact=True)


def test_efficiency_intervals_match_the_summary_and_bracket_it(tmp_path):
    from magbench.studies.review import efficiency_intervals

    study = spec(trials=12)
    trials, summary = run_sweep(study, tmp_path)
    table = efficiency_intervals(trials, ["K", "gamma", "algorithm"], "t")
    merged = table.merge(summary, on=["K", "gamma", "algorithm"], suffixes=("", "_summary"))
    assert len(merged) == 4
    np.testing.assert_allclose(merged["efficiency"], merged["efficiency_summary"], rtol=1e-12)
    assert (merged["eff_lo"] < merged["efficiency"]).all()
    assert (merged["efficiency"] < merged["eff_hi"]).all()


def test_write_efficiency_reads_the_trials_file_per_point_and_method(tmp_path):
    from magbench.studies.review import POINT_COLUMNS, efficiency_intervals, write_efficiency

    study = spec(trials=12)
    trials, _ = run_sweep(study, tmp_path)
    written = pd.read_csv(write_efficiency(tmp_path, "t"))
    expected = efficiency_intervals(trials, [*POINT_COLUMNS, "algorithm"], "t")
    assert len(written) == 4 and set(written["algorithm"]) == {"magical", "dorveaux"}
    np.testing.assert_allclose(written["efficiency"], expected["efficiency"], rtol=1e-12)
    np.testing.assert_allclose(written["eff_lo"], expected["eff_lo"], rtol=1e-12)


def test_write_efficiency_keeps_an_option_axis_default_run_apart(tmp_path):
    from magbench.studies.review import POINT_COLUMNS, write_efficiency

    point = {c: v for c, v in zip(POINT_COLUMNS, (300, 0.005, 0.05, 0.05, 180.0, 90.0),
                                  strict=True)}
    rows = pd.DataFrame([{**point, "algorithm": "magical", "magical.max_iter": value,
                          "meaningful": kept, "crb": 1.0, "sq_err": err}
                         for value, errs in ((None, (1.0, 3.0)), (10, (2.0, 2.0, 8.0)))
                         for kept, err in [(True, e) for e in errs] + [(False, 50.0)]])
    rows.to_csv(tmp_path / "trials.csv", index=False)
    table = pd.read_csv(write_efficiency(tmp_path, "t", ["magical.max_iter"]))
    assert table["n"].tolist() == [3, 4] and table["n_meaningful"].tolist() == [2, 3]
    np.testing.assert_allclose(table["efficiency"], [1 / 2.0, 1 / 4.0])


def test_the_capacity_check_counts_the_columns_the_summary_reads(tmp_path, monkeypatch):
    import magbench.engine.sweep as sweep

    study = spec(trials=1000)           # 2 points x 1000 trials x 2 methods = 4000 rows
    need = sweep.MEMORY_BYTES_PER_VALUE * 4000 * len(study.summary_columns)
    assert len(study.summary_columns) < len(ROW_COLUMNS) / 3
    monkeypatch.setattr(sweep, "_free_bytes", lambda folder: (10**12, need - 1))
    with pytest.raises(sweep.TooLarge, match="of memory"):
        sweep.check_capacity(study, study.units(), tmp_path)
    monkeypatch.setattr(sweep, "_free_bytes", lambda folder: (10**12, need))
    sweep.check_capacity(study, study.units(), tmp_path)
