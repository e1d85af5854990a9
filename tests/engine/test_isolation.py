"""A method that ends or seizes its process is a row: exit, segfault, memory, SystemExit, GIL.

Each fault-injecting method (``tests/plugins/faulty.py``) misbehaves on the "marked" datasets
only, the ones where ``faulty_marked`` raises; the sweep must finish with one ``ok=False`` row
per marked dataset, the reason in it, and every other row as in a run without the method.
"""

from __future__ import annotations

import pandas as pd
import pytest

from magbench.engine.isolation import WorkerDied, hard_limit, run_isolated
from magbench.engine.sweep import run_study
from magbench.sources.synthetic import Point
from magbench.studies.review import ReviewStudy, read_trials
from tests.engine.conftest import FAULTY

LIMIT = 0.3

#: Method -> the reason its marked rows give.
FAULTS = {
    "faulty_exit": "worker died: exit code 3",
    "faulty_segfault": "worker died: signal 11 (SIGSEGV)",
    "faulty_memory": "MemoryError: Unable to allocate 2.00 GiB",
    "faulty_exit_exception": "SystemExit: 5",
    "faulty_gil": f"CallTimeout: call exceeded call_timeout_s = {LIMIT:g} s inside one compiled "
                  "call; its worker process was ended",
}


def spec(algorithms, trials=4) -> ReviewStudy:
    return ReviewStudy(name="iso", points=[Point(K=40)], trials=trials, seed=5,
                       algorithms=algorithms, call_timeout_s=LIMIT, plugins=(FAULTY,))


def rows(study, folder, **kw) -> pd.DataFrame:
    run_study(study, folder, progress=False, chunk_size=2, **kw)
    return read_trials(folder / "trials.csv").drop(columns="time_s")


def check_fault_rows(method: str, got: pd.DataFrame, clean: pd.DataFrame) -> None:
    bad = got[got["algorithm"] == method].set_index("trial")
    twin = clean[clean["algorithm"] == "faulty_marked"].set_index("trial")
    marked = twin["error"] == "RuntimeError: marked dataset"
    assert 0 < marked.sum() < len(marked)          # the seed marks some datasets, not all
    assert not bad.loc[marked, "ok"].any()
    assert bad.loc[marked, "error"].str.startswith(FAULTS[method]).all(), bad["error"]
    # Elsewhere the method gave the trivial answer, as its twin did.
    pd.testing.assert_series_equal(bad.loc[~marked, "error"],
                                   twin.loc[~marked, "error"].str.replace("faulty_marked", method))
    others = got[~got["algorithm"].str.startswith("faulty_") |
                 (got["algorithm"] == "faulty_marked")]
    pd.testing.assert_frame_equal(others.reset_index(drop=True), clean.reset_index(drop=True))


@pytest.mark.parametrize("n_jobs", [1, 2])
@pytest.mark.parametrize("method", [m for m in FAULTS if m != "faulty_gil"])
def test_a_method_that_ends_its_process_is_one_row_per_dataset(faulty, tmp_path, method,
                                                                n_jobs):
    clean = rows(spec(["faulty_marked", "sphere"]), tmp_path / "clean")
    got = rows(spec([method, "faulty_marked", "sphere"]), tmp_path / "bad", n_jobs=n_jobs)
    check_fault_rows(method, got, clean.copy())
    # The other methods' rows are those of a run without the faulty one.
    assert (got["algorithm"] == method).sum() == 4


# With 2 workers the pool's watchdog ends the worker and the supervised child then meets the
# call again, so that case also covers the supervised child of n_jobs=1 (slow, make test-all).
@pytest.mark.parametrize("n_jobs", [pytest.param(1, marks=pytest.mark.slow), 2])
def test_a_call_that_holds_the_interpreter_is_stopped_and_is_a_row(faulty, tmp_path, n_jobs):
    clean = rows(spec(["faulty_marked", "sphere"], trials=2), tmp_path / "clean")
    got = rows(spec(["faulty_gil", "faulty_marked", "sphere"], trials=2), tmp_path / "bad",
               n_jobs=n_jobs)
    check_fault_rows("faulty_gil", got, clean)


def test_the_hard_limit_leaves_room_for_a_loaded_machine():
    assert hard_limit(0.3) == pytest.approx(5.3)
    assert hard_limit(600) == 1200


def test_a_unit_that_dies_outside_a_method_stops_the_run_with_one_line(tmp_path):
    import os

    class Dies(ReviewStudy):
        def run_unit(self, unit):
            os._exit(7)

    study = Dies(name="dies", points=[Point(K=40)], trials=1, seed=0, algorithms=["sphere"])
    with pytest.raises(WorkerDied, match=r"unit 0 of dies ended its process outside any "
                                         r"method call \(worker died: exit code 7\)"):
        run_isolated(study, study.units(), [(0, 1)], lambda *a: None)


def test_on_dask_a_dead_worker_is_a_row_and_a_system_exit_too(faulty, tmp_path):
    pytest.importorskip("distributed")
    methods = ["faulty_segfault", "faulty_exit_exception"]
    clean = rows(spec(["faulty_marked", "sphere"]), tmp_path / "clean")
    got = rows(spec([*methods, "faulty_marked", "sphere"]), tmp_path / "bad", n_jobs=2,
               backend="dask")
    for method in methods:
        check_fault_rows(method, got, clean)
