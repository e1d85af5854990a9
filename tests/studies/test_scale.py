"""The scale benchmark's bookkeeping on a tiny run (its sizes and times live in make bench)."""

from __future__ import annotations

import numpy as np

from magbench.studies.scale import bench_scale, scale_point


def test_scale_point_runs_summarises_and_bootstraps(tmp_path):
    found = scale_point(str(tmp_path / "s"), trials=6, algorithms=["sphere", "fang"], n_jobs=1)
    assert found["rows"] == 12 and found["methods"] == 2 and found["chunk_size"] == 25
    assert (tmp_path / "s" / "summary.csv").is_file()
    for name in ("sphere", "fang"):
        low, high = found["intervals"][name]
        assert 0 < low <= high
    assert found["peak_rss_mb"] >= found["peak_rss_after_run_mb"] > 0


def test_bench_scale_runs_a_size_in_a_fresh_process_and_cleans_up(tmp_path):
    table = bench_scale([3], algorithms=["sphere"], n_jobs=1, workdir=tmp_path, progress=None)
    assert list(table["trials"]) == [3] and list(table["rows"]) == [3]
    assert np.all(table["acc_lo_sphere"] <= table["acc_hi_sphere"])
    assert not list(tmp_path.iterdir())
