"""The heading study's figures: drawn from the CSV files, with the numbers plotted beside."""

from __future__ import annotations

import pandas as pd

from magbench.figures.heading import write_heading_figures
from tests.report.test_heading import write_results


def test_both_figures_and_their_numbers(tmp_path):
    root = write_results(tmp_path)
    paths = write_heading_figures(root / "heading")
    assert [p.name for p in paths] == ["heading_error.png", "heading_vs_J.png"]
    assert all(p.stat().st_size > 5000 for p in paths)
    errors = pd.read_csv(root / "heading" / "heading_error.csv")
    assert len(errors) == 12 and set(errors["part"]) == {"semi", "given"}
    scatter = pd.read_csv(root / "heading" / "heading_vs_J.csv")
    assert set(scatter.groupby("part")["metric"].first().items()) == {("semi", "J"),
                                                                     ("given", "J_r")}
    assert len(scatter) == 12 and scatter["value"].notna().all()
