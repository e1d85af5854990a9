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


def test_the_shared_runs_are_the_pivot_tables_runs():
    """``paired`` without pivot tables gives the pivot's numbers: trials in any order, a
    trial one method lacks, runs meaningful for one only, another value column; a trial
    twice for a method goes to the pivot, which refuses it."""
    import numpy as np
    import pandas as pd
    import pytest

    from magbench.report.matched import _paired_by_pivot, paired

    gen = np.random.default_rng(3)
    rows = [{"trial": t, "algorithm": m, "meaningful": bool(gen.random() < 0.8),
             "J": float(gen.random()), "J_h": float(gen.random())}
            for t in gen.permutation(40) for m in ("a", "b", "c") if (t, m) != (5, "b")]
    trials = pd.DataFrame(rows)
    for a, b in (("a", "b"), ("b", "c"), ("c", "a"), ("a", "missing")):
        for value in ("J", "J_h"):
            fast = paired(trials, a, b, value, ("k",))
            slow = _paired_by_pivot(trials, a, b, value, ("k",))
            assert fast.n == slow.n
            assert np.array_equal([fast.ratio, fast.low, fast.high],
                                  [slow.ratio, slow.low, slow.high], equal_nan=True)
    twice = pd.concat([trials, trials.iloc[:1]])
    with pytest.raises(ValueError):
        paired(twice, twice["algorithm"].iloc[0], "c")
