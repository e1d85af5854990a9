"""The report's bootstrap intervals kept from the last report."""


def test_kept_intervals_are_the_computed_ones_and_only_of_the_same_inputs(tmp_path):
    """Within kept_intervals an interval asked before (same values, stream, options) comes
    from the file, one of other values is drawn; the file keeps what the block asked for,
    and each interval equals the one computed without a store."""
    import json

    import numpy as np

    from magbench.report.kept import (
        bootstrap_inverse_mean,
        bootstrap_mean,
        bootstrap_paired_ratio,
        kept_intervals,
    )

    gen = np.random.default_rng(0)
    x, y = gen.random(30) + 1, gen.random(30) + 1
    asks = [lambda v: bootstrap_inverse_mean(v, "s", "m=a"),
            lambda v: bootstrap_mean(v, "s", level=0.9),
            lambda v: bootstrap_paired_ratio(v, y, "s", "a", "b")]
    plain = [ask(x) for ask in asks]
    path = tmp_path / "intervals.json"
    with kept_intervals(path):
        assert [ask(x) for ask in asks] == plain
    saved = json.loads(path.read_text())
    assert len(saved) == 3
    # Taken from the file, not drawn: a value edited there comes back.
    path.write_text(json.dumps({k: [1.0, 2.0] for k in saved}))
    with kept_intervals(path):
        assert [ask(x) for ask in asks] == [(1.0, 2.0)] * 3
        other = [ask(x * 1.01) for ask in asks]       # other values: drawn
        assert bootstrap_inverse_mean(x, "s", "m=b") != (1.0, 2.0)     # another stream
    assert other == [ask(x * 1.01) for ask in asks]
    assert len(json.loads(path.read_text())) == 7                      # what was asked
