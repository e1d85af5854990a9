"""The option-sweep figure: what is drawn, from a summary with an option-axis column."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.figures.options import option_column, option_figure_data, write_option_figure


def summary() -> pd.DataFrame:
    return pd.DataFrame({"K": [300] * 4, "crassidis.P0": [np.nan, np.nan, 1e-6, 1e-3],
                         "algorithm": ["crassidis", "crassidis_prior", "crassidis", "crassidis"],
                         "n": [5] * 4, "RB_pct": [100.0, 100.0, 80.0, 100.0],
                         "mse": [1e-5, 2e-5, 1e-2, 4e-5]})


def test_figure_data_separates_the_swept_line_from_the_reference_lines():
    data = option_figure_data(summary())
    assert option_column(summary()) == "crassidis.P0"
    assert list(data["series"]) == ["crassidis (default)", "crassidis_prior", "crassidis",
                                    "crassidis"]
    assert data["value"].isna().tolist() == [True, True, False, False]
    np.testing.assert_allclose(data["accuracy_sq"], [1e5, 5e4, 100.0, 2.5e4])
    assert (data["accuracy_paper"] == 3.31e3).all() and (data["RB_pct_paper"] == 100).all()


def test_writes_png_and_csv(tmp_path):
    path = write_option_figure(summary(), tmp_path, "p0")
    assert path == tmp_path / "fig_p0.png" and path.stat().st_size > 0
    assert len(pd.read_csv(tmp_path / "fig_p0.csv")) == 4
    with pytest.raises(ValueError, match="no option-axis column"):
        option_figure_data(summary().drop(columns="crassidis.P0"))
