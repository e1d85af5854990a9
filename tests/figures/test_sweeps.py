"""Figures 2-5 and coverage from hand-made summaries: what is drawn, and how."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.figures.sweeps import FIGURES, figure_data, plot_sweep, write_figure
from magbench.studies.review import with_coverage_column
from tests.report.helpers import NOMINAL, gamma_case


def test_figure_and_its_csv_from_a_fixture(tmp_path):
    s = gamma_case()
    data = figure_data(s, "gamma")
    assert len(data) == 7 * 3 and (data["speed_source"] == "trials").all()
    # The floor enters only as the matched ratio of each method (no global floor series).
    assert "crb" not in set(data["series"]) and (data["efficiency"] == 1.0).all()
    png, csv = write_figure(s, "gamma", tmp_path)
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    columns = [c for c in data.columns if c != "group"]        # empty here: read as NaN
    pd.testing.assert_frame_equal(pd.read_csv(csv)[columns], data[columns], check_dtype=False)


def test_speed_comes_from_the_timing_pass_when_there_is_one():
    s = gamma_case()
    timing = s[["gamma", "algorithm"]].assign(speed_hz=1234.0)
    data = figure_data(s, "gamma", timing)
    assert (data["speed_hz"] == 1234.0).all() and (data["speed_source"] == "timing").all()
    # One source per figure: a method the pass did not time has no speed, not a per-trial one.
    partial = timing[timing["algorithm"] != "ali"]
    data = figure_data(s, "gamma", partial).set_index("series")
    assert (data["speed_source"] == "timing").all() and data.loc["ali", "speed_hz"].isna().all()


def test_no_speed_where_no_run_was_meaningful():
    s = gamma_case()
    s.loc[s["algorithm"] == "crassidis", "RB_pct"] = [100, 50, 0]
    timing = s[["gamma", "algorithm"]].assign(speed_hz=1234.0)
    for t in (None, timing):
        speeds = figure_data(s, "gamma", t).set_index("series").loc["crassidis", "speed_hz"]
        assert speeds.notna().tolist() == [True, True, False]


def coverage_summary():
    return with_coverage_column(pd.DataFrame(
        [{**NOMINAL, "cap_deg": c, "band_deg": b, "algorithm": "magical", "n": 1,
          "RB_pct": 100, "accuracy": 1.0, "speed_hz": 1.0, "tau_s": 1.0, "efficiency": 1.0}
         for c, b in [(180, 90), (60, 90), (180, 30), (180, 10)]]))


def test_coverage_keeps_the_sweep_order_and_never_joins_a_cap_to_a_band(tmp_path):
    s = coverage_summary()
    data = figure_data(s, "coverage")
    assert list(data["x"]) == ["full sphere", "cap 60 deg", "band +-30 deg", "band +-10 deg"]
    assert list(data["group"]) == ["cap", "cap", "band", "band"]
    fig = plot_sweep(data, "coverage")
    for ax in fig.axes:
        runs = [line.get_xdata() for line in ax.get_lines()
                if len(set(line.get_xdata())) > 1 and not line.get_label().startswith("Cramer")]
        # Two lines per panel (caps at 0, 1; bands after a gap at 3, 4), none across.
        assert sorted(map(list, runs)) == [[0, 1], [3, 4]]
    assert write_figure(s, "coverage", tmp_path)[0].exists()
    assert FIGURES["coverage"].stem == "fig_coverage"


def test_figure6_splits_the_review_from_the_others_and_leaves_out_empty_methods():
    from magbench.figures.real import figure6, split_methods

    rows = [{"preprocess": how, "algorithm": name, "label": name, "n_recordings": 4,
             "n_applicable": 4 if name != "magfactor3" else 1,
             "n_meaningful": 0 if name == "magfactor3" else 3, "RB_pct": 75.0,
             "accuracy_in": 900.0}
            for how in ("scale", "centre") for name in ("magical", "fang", "magfactor3",
                                                         "dorveaux")]
    per_method = pd.DataFrame(rows)
    assert split_methods(per_method) == (["dorveaux", "magical"], ["fang"], ["magfactor3"])
    fig = figure6(per_method)
    titles = [ax.get_title(loc="left") for ax in fig.axes]
    assert [t[:3] for t in titles] == ["(a)", "(b)", "(c)", "(d)"]      # one letter each
    assert "MagFactor3" in fig._suptitle.get_text()
    # Nothing meaningful at all: a figure that says so instead of an error.
    empty = per_method.assign(n_meaningful=0)
    assert "No method gave a meaningful fit" in figure6(empty).texts[0].get_text()


def test_the_efficient_estimator_under_selection_is_drawn_beside_the_methods(tmp_path):
    s = coverage_summary()
    pd.DataFrame({"K": 300, "sigma": 0.005, "beta": 0.05, "gamma": 0.05,
                  "cap_deg": [60.0, 180.0], "band_deg": [90.0, 10.0], "RB_pct": [50.0, 98.0],
                  "accuracy": [14.0, 36.0], "efficiency": [4.2, 1.1], "undetermined": 0}
                 ).to_csv(tmp_path / "efficient_selection.csv", index=False)
    csv = write_figure(s, "coverage", tmp_path)[1]
    ref = pd.read_csv(csv).query("family == 'reference'")
    assert list(ref["x"]) == ["cap 60 deg", "band +-10 deg"]
    assert list(ref["efficiency"]) == [4.2, 1.1] and ref["speed_hz"].isna().all()
    fig = plot_sweep(pd.read_csv(csv).fillna({"group": ""}), "coverage")
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any(t.startswith("efficient unbiased estimator") for t in labels)
    assert "speed_hz" not in {line.get_label() for line in fig.axes[1].get_lines()}


def test_figure6_hatches_an_accuracy_set_by_the_recordings_kept():
    from magbench.figures.real import figure6

    per_rec = pd.DataFrame([
        {"dataset": f"r{i}", "preprocess": "scale", "algorithm": a, "skipped": False,
         "meaningful": not (a == "dorveaux" and i >= 2), "J_r_in": (1e-4 if i < 2 else 1e-2)}
        for i in range(4) for a in ("dorveaux", "magical", "ali")])
    per_method = pd.DataFrame([{"preprocess": "scale", "algorithm": a, "label": a,
                                "n_recordings": 4, "n_applicable": 4,
                                "n_meaningful": 2 if a == "dorveaux" else 4,
                                "RB_pct": 50.0 if a == "dorveaux" else 100.0,
                                "accuracy_in": 1e4 if a == "dorveaux" else 198.0}
                               for a in ("dorveaux", "magical", "ali")])
    fig = figure6(per_method, per_rec)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "set by which recordings were kept" in labels
    hatched = [p for p in fig.axes[0].patches if p.get_hatch() == "xxx"]
    assert len(hatched) == 1 and hatched[0].get_height() == pytest.approx(1e4)
    assert "set by which recordings were kept" not in [
        t.get_text() for t in figure6(per_method).legends[0].get_texts()]


def test_a_reference_of_other_points_is_not_drawn(tmp_path):
    pd.DataFrame({"K": 300, "sigma": 0.005, "beta": 0.05, "gamma": 0.05, "cap_deg": [30.0],
                  "band_deg": [90.0], "RB_pct": [8.0], "accuracy": [10.6], "efficiency": [77.0],
                  "undetermined": 0}).to_csv(tmp_path / "efficient_selection.csv", index=False)
    csv = write_figure(gamma_case(), "gamma", tmp_path)[1]
    assert (pd.read_csv(csv)["family"] != "reference").all()


def test_accuracy_from_too_few_meaningful_runs_is_not_drawn():
    from magbench.figures.sweeps import MIN_MEANINGFUL

    s = gamma_case()
    data = figure_data(s, "gamma")
    data.loc[data.index[1], "n_meaningful"] = MIN_MEANINGFUL - 1
    fig = plot_sweep(data, "gamma")
    first = data["series"].iloc[0]
    line = next(ln for ln in fig.axes[0].lines if ln.get_label() == data["label"].iloc[0])
    y = line.get_ydata()
    assert first == data["series"].iloc[1] and np.isnan(y[1]) and np.isfinite(y[0])
    rb = next(ln for ln in fig.axes[2].lines if ln.get_label() == data["label"].iloc[0])
    assert np.isfinite(rb.get_ydata()[1])          # robustness still drawn
