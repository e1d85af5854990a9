"""Comparisons on the runs meaningful for both methods."""

import numpy as np
import pandas as pd

from magbench.report.matched import paired


def rows(name, J, meaningful):
    return [{"trial": i, "algorithm": name, "J": j, "meaningful": m}
            for i, (j, m) in enumerate(zip(J, meaningful, strict=True))]


def test_a_method_that_fails_the_hard_datasets_is_compared_on_the_easy_ones_only():
    hard = np.r_[np.full(50, 1.0), np.full(50, 10.0)]              # 50 easy, 50 hard datasets
    trials = pd.DataFrame(rows("robust", hard, [True] * 100)
                          + rows("fragile", 1.1 * hard, [True] * 50 + [False] * 50))
    # Each over its own runs the fragile one looks 5x better (1.1 against 5.5); matched, it is
    # 10 % worse, on the 50 datasets both solved.
    p = paired(trials, "fragile", "robust")
    assert p.n == 50 and np.isclose(p.ratio, 1.1) and p.different
    assert p.text() == "1.1 [1.1, 1.1], n = 50"
    assert paired(trials, "robust", "absent").n == 0
