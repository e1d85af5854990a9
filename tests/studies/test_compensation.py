"""The compensation sweep on the one engine: rows, what compensation buys, the summary, the
figure and the report section (tiny sizes)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.engine.sweep import run_study
from magbench.figures.compensation import write_compensation_figures
from magbench.report.compensation import compensation_report_section
from magbench.studies.compensation import (
    COMPENSATION_COLUMNS,
    CompensationStudy,
    current_profile,
)


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    out = tmp_path_factory.mktemp("results") / "compensation"
    study = CompensationStudy(strengths=[0.0, 0.1], trials=4, algorithms=("fang",))
    run_study(study, out, n_jobs=1, progress=False)
    study.summarize(out)
    return study, out


def test_rows_and_what_compensation_buys(finished):
    _, out = finished
    trials = pd.read_csv(out / "trials.csv")
    assert list(trials.columns) == COMPENSATION_COLUMNS
    assert len(trials) == 2 * 4 * 3 and trials["ok"].all()
    strong = trials[trials["strength"] == 0.1].set_index(["trial", "variant"])
    for t in range(4):
        static, comp = strong.loc[(t, "static")], strong.loc[(t, "compensated")]
        # A disturbance of a tenth of the field: the static fit is off by percents, the
        # compensated one is at the noise (sigma 0.005 = 0.5 %).
        assert static["field_err_pct"] > 1.0 and comp["field_err_pct"] < 0.3
        assert comp["C_err"] < 0.01 and comp["kept"]
        assert strong.loc[(t, "selected"), "field_err_pct"] == comp["field_err_pct"]
        C_true = strong.loc[(t, "static"), [f"C_true_{i}" for i in range(3)]].to_numpy(float)
        assert np.isclose(np.linalg.norm(C_true), 0.1)
    none = trials[(trials["strength"] == 0.0) & (trials["variant"] == "selected")]
    static = trials[(trials["strength"] == 0.0) & (trials["variant"] == "static")]
    # Where the terms were not kept, selected is the static fit itself.
    dropped = ~none["kept"].to_numpy(bool)
    np.testing.assert_array_equal(none["field_err_pct"].to_numpy()[dropped],
                                  static["field_err_pct"].to_numpy()[dropped])


def test_same_rows_on_a_rerun_with_two_workers(finished, tmp_path):
    study, out = finished
    run_study(study, tmp_path / "again", n_jobs=2, progress=False)
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "again" / "trials.csv"),
                                  pd.read_csv(out / "trials.csv"))


def test_summary_figure_and_section(finished):
    _, out = finished
    summary = pd.read_csv(out / "summary.csv")
    assert len(summary) == 2 * 3 and (summary["n"] == 4).all()
    row = summary.set_index(["strength", "variant"]).loc[(0.1, "compensated")]
    assert row["kept_pct"] == 100 and row["median_field_err_pct"] < 0.3
    paths = write_compensation_figures(out)
    assert [p.name for p in paths] == ["compensation.png"] and paths[0].stat().st_size > 10_000
    plotted = pd.read_csv(out / "compensation.csv")
    assert len(plotted) == 6 and set(plotted["variant"]) == {"static", "compensated",
                                                             "selected"}
    text = compensation_report_section(out.parent)
    assert text.startswith("## Time-varying terms: a current-proportional disturbance")
    assert "| 0.1 | Fang | " in text and "compensation/compensation.png" in text
    assert "No results yet" in compensation_report_section(out.parent / "missing")


def test_current_profile_stays_in_range_and_varies():
    u = current_profile(np.random.default_rng(0), np.linspace(0, 20, 400))
    assert u.min() >= 0 and u.max() <= 1 and u.std() > 0.1


def test_estimates_stored_and_the_section_recomputed_from_them(finished):
    """estimates.csv holds every correction; the field errors recomputed from it alone are
    the trials' own, and the section shows their medians."""
    from magbench.report.compensation import compensation_numbers
    from magbench.studies.compensation import ESTIMATE_COLUMNS, estimate_field_error

    _, out = finished
    est = pd.read_csv(out / "estimates.csv")
    trials = pd.read_csv(out / "trials.csv")
    assert list(est.columns) == ESTIMATE_COLUMNS and len(est) == len(trials)
    recomputed = np.array([estimate_field_error(r) for _, r in est.iterrows()])
    np.testing.assert_allclose(recomputed, trials["field_err_pct"], rtol=1e-12)
    numbers = compensation_numbers(out).set_index(["strength", "algorithm", "variant"])
    summary = pd.read_csv(out / "summary.csv").set_index(["strength", "algorithm", "variant"])
    np.testing.assert_allclose(numbers["median_field_err_pct"],
                               summary.loc[numbers.index, "median_field_err_pct"], rtol=1e-12)
    np.testing.assert_allclose(numbers["kept_pct"], summary.loc[numbers.index, "kept_pct"])
    text = compensation_report_section(out.parent)
    for (strength, _, variant), row in numbers.iterrows():
        if strength == 0.1 and variant == "static":
            assert f"| 0.1 | Fang | {row['median_field_err_pct']:.3g} |" in text
