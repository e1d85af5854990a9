"""The fit step's rounds: when the second round is fitted, the field the fits agree on."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("case", ["chosen", "none", "gap", "minimiser_out"])
def test_second_round_reason(case):
    from magbench.core.verdict import MAX_GAP_DEG
    from magbench.pipeline.rounds import FIRST_ROUND, second_round_reason

    row = {"algorithm": "ellipsoid"}
    tie, chosen, gap = ["ellipsoid", "wu_shi_nm"], row, 10.0
    if case == "none":
        chosen = None
    elif case == "gap":
        gap = MAX_GAP_DEG + 1
    elif case == "minimiser_out":
        tie = ["ellipsoid", "fang"]
    reason = second_round_reason(tie, chosen, gap, FIRST_ROUND)
    assert (reason == "") == (case == "chosen")


def test_the_data_field_is_what_the_fits_agree_on():
    from magbench.pipeline.rounds import AGREEING_FITS, agreed_field

    def row(scale, out=0.01):
        T = scale * np.eye(3)
        return {"J_r_out": out, "h_0": 0.0, "h_1": 0.0, "h_2": 0.0,
                **{f"T_{i}{j}": T[i, j] for i in range(3) for j in range(3)}}

    # three fits near 40 and one that lost the scale: the median, not the sphere radius
    rows = [row(39.0), row(40.0), row(41.0), row(400.0)]
    assert agreed_field(rows, 27.0) == pytest.approx(40.5)
    # a fit without an out-of-sample score does not vote; too few voters: the sphere radius
    assert agreed_field([row(39.0), row(40.0), row(41.0, np.nan)], 27.0) == 27.0
    assert AGREEING_FITS == 3
