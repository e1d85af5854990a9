"""The generalisation figure: losses counted as the study counts them."""

from __future__ import annotations

import pandas as pd

from magbench.figures.generalisation import (
    ORACLE,
    RECORDING_BEST,
    generalisation_figure,
    losses_by_protocol,
)


def cases() -> pd.DataFrame:
    return pd.DataFrame({
        "dataset": ["a", "b", "a", "b"], "protocol": ["half", "half", "blocks", "blocks"],
        "best_fixed_pct": [1.0, 10.0, 2.0, 2.0], "auto_pct": [1.2, 10.4, 2.3, 1.0],
        "pct:sphere": [5.0, 10.6, 2.0, 2.2], "regret": [0.2, 0.4, 0.3, -1.0],
        "written": [True, True, False, True]})


def test_losses_use_the_study_tolerance():
    table = losses_by_protocol(cases())
    # calibrate: 1.2 vs 1.0 ties (0.25), 10.4 vs 10 ties (5 %), 2.3 vs 2 loses, 1.0 wins
    assert table.loc["half", "calibrate"] == 0 and table.loc["blocks", "calibrate"] == 1
    # always the sphere fit: 5 vs 1 loses, 10.6 vs 10 loses (> 0.5), 2.0 and 2.2 tie
    assert table.loc["half", "sphere"] == 2 and table.loc["blocks", "sphere"] == 0
    assert list(table.columns) == ["calibrate", "sphere"]


def test_the_oracle_bar_counts_the_best_eligible_fit():
    c = cases().assign(oracle_pct=[1.0, 10.0, 2.3, 3.0])
    table = losses_by_protocol(c)
    assert list(table.columns) == ["calibrate", ORACLE, "sphere"]
    assert table.loc["half", ORACLE] == 0 and table.loc["blocks", ORACLE] == 2


def test_the_recordings_best_fit_bar_counts_the_studys_flags():
    c = cases().assign(oracle_pct=[1.0, 10.0, 2.3, 3.0],
                       loss_recording_best=[True, False, True, True])
    table = losses_by_protocol(c)
    assert list(table.columns) == ["calibrate", ORACLE, RECORDING_BEST, "sphere"]
    assert table[RECORDING_BEST].tolist() == [1, 2]


def test_the_figure_has_both_panels():
    fig = generalisation_figure(cases())
    titles = [ax.get_title(loc="left") for ax in fig.axes]
    assert titles[0].startswith("(a)") and titles[1].startswith("(b)")
    assert "(n=2)" in fig.axes[0].get_xticklabels()[0].get_text()
