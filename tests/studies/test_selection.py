"""An efficient unbiased estimator under the sweeps' robustness test."""

import pandas as pd
import pytest

from magbench.sources.synthetic import Point
from magbench.studies.selection import efficient_under_selection, write_efficient_selection


def test_without_selection_the_efficient_estimator_sits_on_the_bound():
    # A threshold no draw reaches: every run kept, mean squared error = the bound (MC).
    free = efficient_under_selection(Point(cap_deg=30), trials=20, seed=1, delta=1e9)
    assert free["RB_pct"] == 100.0 and free["efficiency"] == pytest.approx(1.0, abs=0.25)


def test_the_robustness_test_lifts_an_unbiased_estimator_above_the_bound():
    kept = efficient_under_selection(Point(cap_deg=30), trials=20, seed=1, delta=0.5)
    assert kept["RB_pct"] < 50 and kept["efficiency"] > 5          # only the lucky runs
    whole = efficient_under_selection(Point(), trials=10, seed=1, delta=0.5)
    assert whole["RB_pct"] == 100.0                                 # the sphere: no selection


def test_the_file_holds_the_points_of_partial_coverage_only(tmp_path):
    points = [Point(), Point(cap_deg=45), Point(band_deg=10)]
    path = write_efficient_selection(points, trials=3, seed=1, delta=0.5, out_dir=tmp_path,
                                     draws=2)
    table = pd.read_csv(path)
    assert list(zip(table["cap_deg"], table["band_deg"], strict=True)) == [(45, 90), (180, 10)]


def test_a_subset_of_easy_recordings_is_flagged():
    from magbench.studies.real import selection_inflation

    rows = [{"dataset": f"r{i}", "preprocess": "scale", "algorithm": a, "skipped": False,
             "meaningful": not (a == "dorveaux" and i >= 2), "J_r_in": 1e-4 if i < 2 else 1e-2}
            for i in range(4) for a in ("dorveaux", "magical", "ali", "sphere")]
    flags = selection_inflation(pd.DataFrame(rows)).set_index("algorithm")
    # The others score 1e4 on r0, r1 and 1/mean(1e-4, 1e-4, 1e-2, 1e-2) ~ 198 on all four.
    assert list(flags.index) == ["dorveaux"] and flags.loc["dorveaux", "n_kept"] == 2
    assert flags.loc["dorveaux", "others_on_kept"] == pytest.approx(1e4)
    assert flags.loc["dorveaux", "inflation"] == pytest.approx(1e4 * 0.00505)
    assert bool(flags.loc["dorveaux", "set_by_selection"])
