"""Rows cached per method: a run adds, or recomputes, only the methods whose key changed.

The counting methods (``tests/plugins/counting.py``) write one line per call, from any
process, so each test counts exactly which calls a run made.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import ClassVar

import pytest

from magbench.engine import sweep as engine
from magbench.engine.sweep import ResultsExist, Study, run_study
from magbench.methods.registry import _REGISTRY, unregister
from magbench.sources.synthetic import Point
from magbench.studies.review import ReviewStudy

REPO = Path(__file__).resolve().parents[2]
COUNTING = "tests.plugins.counting"
#: The environment variable the counting methods append their calls to (not imported from the
#: plugin: importing it registers its methods for every test that follows).
CALLS_FILE = "MAGBENCH_COUNT_CALLS"
TRIALS = 6


@pytest.fixture
def calls(tmp_path, monkeypatch):
    """The calls made so far, per method (read from the counting methods' file)."""
    import tests.plugins.counting  # noqa: F401

    path = tmp_path / "calls.txt"
    monkeypatch.setenv(CALLS_FILE, str(path))

    def read() -> dict[str, int]:
        names = path.read_text().split() if path.exists() else []
        path.unlink(missing_ok=True)
        return {n: names.count(n) for n in sorted(set(names))}

    yield read
    for name in ("counting_a", "counting_b"):
        unregister(name)
    sys.modules.pop(COUNTING, None)


def study(algorithms, options=None, plugins=(COUNTING,), trials=TRIALS) -> ReviewStudy:
    return ReviewStudy("baseline", [Point(K=40)], trials, 7, tuple(algorithms),
                       options or {}, plugins=tuple(plugins))


def run(s: ReviewStudy, folder: Path, **kw) -> None:
    run_study(s, folder, chunk_size=2, progress=False, **kw)


def lines(folder: Path, name: str = "trials.csv") -> list[str]:
    return (folder / name).read_text().splitlines()


def of(rows: list[str], method: str) -> list[str]:
    return [r for r in rows if f",{method}," in r]


def test_adding_a_method_computes_only_its_rows(tmp_path, calls, capsys):
    run(study(["counting_a", "sphere"]), tmp_path / "inc")
    first = lines(tmp_path / "inc")
    assert calls() == {"counting_a": TRIALS}
    capsys.readouterr()
    run(study(["counting_a", "sphere", "counting_b"]), tmp_path / "inc")
    assert calls() == {"counting_b": TRIALS}           # counting_a's rows were reused
    said = capsys.readouterr().err
    assert "reusing the rows of counting_a, sphere (unchanged)" in said
    assert "computing counting_b (new)" in said
    after = lines(tmp_path / "inc")
    for method in ("counting_a", "sphere"):
        assert of(after, method) == of(first, method) and len(of(first, method)) == TRIALS
    # The same table, byte for byte, as one run of all three.
    run(study(["counting_a", "sphere", "counting_b"]), tmp_path / "full")
    assert after == lines(tmp_path / "full")
    record = json.loads((tmp_path / "inc" / "run.json").read_text())
    assert record["methods_reused"] == ["counting_a", "sphere"]
    assert record["methods_computed"] == ["counting_b"]
    assert record["rows"] == {"trials": 3 * TRIALS, "times": 3 * TRIALS}
    # The sidecar of times is merged the same way: the reused rows keep their times.
    times = lines(tmp_path / "inc", "trials_times.csv")
    assert of(times, "counting_a") == of(lines(tmp_path / "inc", "trials_times.csv"),
                                         "counting_a")
    assert [r.split(",")[1] for r in times[1:4]] == ["counting_a", "sphere", "counting_b"]


def test_changing_one_methods_option_recomputes_only_that_method(tmp_path, calls, capsys):
    run(study(["counting_a", "counting_b"]), tmp_path)
    calls()
    before = lines(tmp_path)
    capsys.readouterr()
    run(study(["counting_a", "counting_b"], {"counting_b": {"shift": 0.5}}), tmp_path)
    assert calls() == {"counting_b": TRIALS}
    assert "computing counting_b (options changed)" in capsys.readouterr().err
    after = lines(tmp_path)
    assert of(after, "counting_a") == of(before, "counting_a")
    assert of(after, "counting_b") != of(before, "counting_b")
    # Rerun as it is: every row reused, nothing called.
    run(study(["counting_a", "counting_b"], {"counting_b": {"shift": 0.5}}), tmp_path)
    assert calls() == {}
    assert lines(tmp_path) == after


EDITED = '''
import numpy as np
from magbench.core.model import Calibration
from magbench.methods.registry import register
from tests.plugins.counting import _count

@register("edited_m", label="edited", min_samples=5, family="extra", model="sphere")
def edited(samples):
    _count("edited_m")
    h = samples.mean(axis=0)
    return Calibration({scale} * float(np.sqrt(((samples - h) ** 2).sum(axis=1).mean()))
                       * np.eye(3), h)
'''


def test_editing_a_methods_module_recomputes_its_rows(tmp_path, calls, monkeypatch, capsys):
    code = tmp_path / "code"
    code.mkdir()
    monkeypatch.syspath_prepend(str(code))
    module = code / "edited_plugin.py"

    def load(scale: str) -> None:
        # A new process would import the edited file; this one forgets the old module.
        unregister("edited_m")
        sys.modules.pop("edited_plugin", None)
        module.write_text(EDITED.format(scale=scale))

    try:
        load("1.0")
        s = study(["counting_a", "edited_m"], plugins=(COUNTING, "edited_plugin"))
        run(s, tmp_path / "out")
        before = lines(tmp_path / "out")
        assert calls() == {"counting_a": TRIALS, "edited_m": TRIALS}
        load("1.001")
        capsys.readouterr()
        run(s, tmp_path / "out")                 # the same configuration, the code edited
        assert calls() == {"edited_m": TRIALS}   # stale rows recomputed, never reused
        assert "computing edited_m (code changed)" in capsys.readouterr().err
        after = lines(tmp_path / "out")
        assert of(after, "counting_a") == of(before, "counting_a")
        assert of(after, "edited_m") != of(before, "edited_m")
    finally:
        unregister("edited_m")
        sys.modules.pop("edited_plugin", None)


def test_a_run_that_drops_a_method_or_changes_the_base_is_refused(tmp_path, calls):
    run(study(["counting_a", "counting_b"]), tmp_path)
    with pytest.raises(ResultsExist, match="holds a run with counting_b, which this run does "
                                           "not select"):
        run(study(["counting_a"]), tmp_path)
    with pytest.raises(ResultsExist, match="another configuration"):
        run(study(["counting_a", "counting_b"], trials=TRIALS + 1), tmp_path)
    # A run whose table was edited after it finished is not a source of rows either.
    table = tmp_path / "trials.csv"
    table.write_text(table.read_text().replace("counting_a", "counting_A", 1))
    with pytest.raises(ResultsExist, match="another configuration"):
        run(study(["counting_a", "counting_b", "sphere"]), tmp_path)
    assert calls() == {"counting_a": TRIALS, "counting_b": TRIALS}    # the first run's only


def test_a_kill_while_the_merged_tables_are_written_resumes_exactly(tmp_path, calls,
                                                                    monkeypatch):
    """Killed after the new trials.csv replaced the finished one, before run.json: the
    reused rows were staged in parts/, so the rerun merges them again, computing nothing."""
    run(study(["counting_a", "sphere"]), tmp_path / "inc")
    run(study(["counting_a", "sphere", "counting_b"]), tmp_path / "full")
    calls()

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(engine, "write_run_record", killed)
        with pytest.raises(KeyboardInterrupt):
            run(study(["counting_a", "sphere", "counting_b"]), tmp_path / "inc")
    assert calls() == {"counting_b": TRIALS}
    assert lines(tmp_path / "inc") == lines(tmp_path / "full")     # replaced, run.json old
    run(study(["counting_a", "sphere", "counting_b"]), tmp_path / "inc")
    assert calls() == {}
    assert lines(tmp_path / "inc") == lines(tmp_path / "full")
    assert not (tmp_path / "inc" / "parts").exists()


@pytest.mark.slow
@pytest.mark.usefixtures("blank_figures")
def test_a_killed_incremental_run_resumes_to_the_same_rows(tmp_path, calls):
    """SIGKILL while the added method runs; the rerun finishes only what is missing and the
    table is byte-identical to one run of every method. Slow (three command-line runs and a
    killed process, ~11 s): the kill just before run.json above shows the same in CI."""
    from magbench.cli import main

    def args(results: Path, algorithms: str) -> list[str]:
        return ["sweep=baseline", "trials=8", "nominal.K=40", "chunk_size=1", "n_jobs=1",
                "progress=false", f"plugins=[{COUNTING},tests.plugins.faulty]",
                f"algorithms=[{algorithms}]", f"results_dir={results}",
                *(["options.faulty_slow.delay=0.1"] if "faulty_slow" in algorithms else [])]

    try:
        assert main(args(tmp_path / "cut", "counting_a,sphere")) == 0
        assert main(args(tmp_path / "full", "counting_a,sphere,faulty_slow")) == 0
        calls()
        proc = subprocess.Popen([sys.executable, "-m", "magbench",
                                 *args(tmp_path / "cut", "counting_a,sphere,faulty_slow")],
                                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        parts = tmp_path / "cut" / "baseline" / "parts"
        start = time.monotonic()
        while len(list(parts.glob("c*.json"))) < 2:
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.monotonic() - start < 120
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        assert calls() == {}                       # only faulty_slow ran, not counting_a
        assert main(args(tmp_path / "cut", "counting_a,sphere,faulty_slow")) == 0
        assert calls() == {}           # neither in the trials nor in the timing pass (kept)
        record = json.loads((tmp_path / "cut" / "baseline" / "run.json").read_text())
        assert record["units_resumed"] >= 2 and record["methods_computed"] == ["faulty_slow"]
        cut, full = tmp_path / "cut" / "baseline", tmp_path / "full" / "baseline"
        assert lines(cut) == lines(full)
    finally:
        for name in [n for n in _REGISTRY if n.startswith("faulty_")]:
            unregister(name)
        sys.modules.pop("tests.plugins.faulty", None)


def test_overwrite_recomputes_only_what_changed(tmp_path, calls, capsys):
    """overwrite=true (make reproduce) lifts the refusals, not the reuse: an unchanged run is
    kept as it is, and a dropped method's rows go while the others' stay."""
    run(study(["counting_a", "counting_b"]), tmp_path)
    before = lines(tmp_path)
    calls()
    run(study(["counting_a", "counting_b"]), tmp_path, overwrite=True)
    assert calls() == {} and lines(tmp_path) == before
    assert "already holds this run" in capsys.readouterr().err
    run(study(["counting_a"]), tmp_path, overwrite=True)
    assert calls() == {}
    assert lines(tmp_path) == [before[0], *of(before, "counting_a")]
    run(study(["counting_a"], trials=TRIALS - 1), tmp_path, overwrite=True)
    assert calls() == {"counting_a": TRIALS - 1}          # another base: all recomputed


def test_a_study_whose_own_code_changed_is_recomputed_whole(tmp_path, calls, capsys,
                                                            monkeypatch):
    """The base holds the study's code: when it changes, the same configuration recomputes
    every row (said so), without overwrite and without refusing."""
    run(study(["counting_a", "counting_b"]), tmp_path)
    calls()
    monkeypatch.setattr(engine, "study_code", lambda module: "edited")
    capsys.readouterr()
    run(study(["counting_a", "counting_b"]), tmp_path)
    assert calls() == {"counting_a": TRIALS, "counting_b": TRIALS}
    assert "the code that computes this run changed" in capsys.readouterr().err


def test_a_whole_run_differing_only_in_its_plugins_is_reused(tmp_path, calls, capsys):
    """A study not cached per method (here: an option axis) whose methods, options, code and
    settings are unchanged is reused whole when only the plugins loaded differ."""
    from magbench.studies.review import OptionAxis

    axis = OptionAxis("counting_a", "shift", (0.5,))
    run(ReviewStudy("baseline", [Point(K=40)], TRIALS, 7, ("counting_a",), {},
                    plugins=(COUNTING,), axis=axis), tmp_path)
    before = lines(tmp_path)
    calls()
    capsys.readouterr()
    again = ReviewStudy("baseline", [Point(K=40)], TRIALS, 7, ("counting_a",), {},
                        plugins=(COUNTING, "tests.plugins.faulty"), axis=axis)
    try:
        run(again, tmp_path)
    finally:
        for name in [n for n in _REGISTRY if n.startswith("faulty_")]:
            unregister(name)
        sys.modules.pop("tests.plugins.faulty", None)
    assert calls() == {} and lines(tmp_path) == before
    assert "only the plugins loaded differ" in capsys.readouterr().err


def spiral_folder(root: Path, K: int = 900) -> None:
    """One recording ``spiral``: a sensor turned through every direction, in time order."""
    import numpy as np
    import pandas as pd

    s = np.linspace(0.0, 1.0, K)
    theta, phi = np.arccos(1 - 2 * s), 2 * np.pi * 12 * s
    m = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                         np.cos(theta)])
    y = m @ np.diag([52.0, 47.0, 61.0]) + [90.0, -35.0, 12.0]
    y = y + 0.3 * np.random.default_rng(1).standard_normal((K, 3))
    (root / "spiral").mkdir(parents=True)
    pd.DataFrame({"t": np.arange(K) * 0.02, "mx": y[:, 0], "my": y[:, 1],
                  "mz": y[:, 2]}).to_csv(root / "spiral" / "data.csv", index=False)


def test_generalisation_rows_are_cached_per_entrant(tmp_path, calls, capsys):
    """The generalisation study's entrants (calibrate's choice, each fixed method) are cached
    one by one: a fixed method added computes only its rows, byte for byte those of a full
    run; a plugin's option changed recomputes its rows alone (it is not one of calibrate's
    candidates as shipped); an option of a shipped candidate changed recomputes calibrate's
    choice (it may fit the method), and nothing else."""
    from magbench.studies.generalisation import AUTO, GeneralisationStudy

    spiral_folder(tmp_path / "data")

    def gen(algorithms, options=None):
        return GeneralisationStudy(str(tmp_path / "data"), ("spiral",), ("blocks", "half"),
                                   tuple(algorithms), peers=False, bootstrap=0,
                                   options=options or {}, plugins=(COUNTING,))

    def go(s, folder):
        run_study(s, folder, chunk_size=1, progress=False, overwrite=True)

    go(gen(["sphere"]), tmp_path / "inc")
    first = lines(tmp_path / "inc", "generalisation_trials.csv")
    calls()
    capsys.readouterr()
    go(gen(["sphere", "counting_a"]), tmp_path / "inc")
    assert calls() == {"counting_a": 2}                   # one fit per protocol, nothing else
    assert f"reusing the rows of {AUTO}, sphere (unchanged); computing counting_a (new)" in \
        capsys.readouterr().err
    go(gen(["sphere", "counting_a"]), tmp_path / "full")
    for table in ("generalisation_trials.csv", "generalisation_intervals.csv"):
        assert lines(tmp_path / "inc", table) == lines(tmp_path / "full", table)
    second = lines(tmp_path / "inc", "generalisation_trials.csv")
    assert [r for r in second if ",counting_a," not in r] == first
    assert [r.split(",")[2] for r in second[1:]] == [AUTO] * 2 + ["sphere"] * 2 + \
        ["counting_a"] * 2                                 # entrant by entrant
    calls()
    # a plugin is a fixed entrant, not one of calibrate's candidates as shipped: its options
    # changed recompute its rows alone
    go(gen(["sphere", "counting_a"], {"counting_a": {"shift": 0.5}}), tmp_path / "inc")
    assert f"reusing the rows of {AUTO}, sphere (unchanged); computing counting_a (options " \
        "changed)" in capsys.readouterr().err
    assert calls() == {"counting_a": 2}
    third = lines(tmp_path / "inc", "generalisation_trials.csv")
    assert of(third, "sphere") == of(second, "sphere") and of(third, AUTO) == of(second, AUTO)
    # a shipped candidate's options changed: calibrate's choice may fit it, so it is recomputed
    go(gen(["sphere", "counting_a"], {"counting_a": {"shift": 0.5},
                                       "twostep": {"max_iter": 49}}), tmp_path / "inc")
    assert f"computing {AUTO} (options changed)" in capsys.readouterr().err
    assert of(lines(tmp_path / "inc", "generalisation_trials.csv"), "sphere") == \
        of(second, "sphere")


@dataclasses.dataclass(frozen=True)
class Ragged(Study):
    """Rows per unit that differ from unit to unit (0, 1 or 2 per method) and a table owned
    by one method: the layout a generalisation study has (a skipped protocol, intervals)."""

    algorithms: tuple = ()
    options: dict | None = None
    plugins: tuple = (COUNTING,)
    name: str = "ragged"

    tables: ClassVar[dict] = {"rows": ("rows.csv", ["unit", "algorithm", "i"]),
                              "notes": ("notes.csv", ["unit", "note"])}
    method_column: ClassVar[str] = "algorithm"
    table_owner: ClassVar[dict] = {"notes": "counting_a"}
    ragged: ClassVar[bool] = True

    def units(self):
        return list(range(6))

    def run_unit(self, unit):
        import numpy as np

        from magbench.methods.registry import get_method

        y = np.random.default_rng(unit).standard_normal((20, 3))
        rows = []
        for m in self.algorithms:
            get_method(m).fit(y)                         # a counted call, per unit and method
            rows += [{"unit": unit, "algorithm": m, "i": i} for i in range(unit % 3)]
        notes = ([{"unit": unit, "note": f"n{unit}"}] * (unit % 2)
                 if "counting_a" in self.algorithms else [])
        return {"rows": rows, "notes": notes}


def test_rows_per_unit_that_differ_and_an_owned_table_are_cached(tmp_path, calls, capsys):
    # chunk_size is 1 for a ragged study whatever is asked: each chunk says its layout.
    run_study(Ragged(("counting_a",)), tmp_path / "inc", chunk_size=4, progress=False)
    calls()
    run_study(Ragged(("counting_a", "counting_b")), tmp_path / "inc", chunk_size=4,
              progress=False)
    assert calls() == {"counting_b": 6}
    assert "reusing the rows of counting_a (unchanged)" in capsys.readouterr().err
    run_study(Ragged(("counting_a", "counting_b")), tmp_path / "full", chunk_size=1,
              progress=False)
    for name in ("rows.csv", "notes.csv"):
        assert lines(tmp_path / "inc", name) == lines(tmp_path / "full", name)
    record = json.loads((tmp_path / "inc" / "run.json").read_text())
    assert record["methods"]["counting_a"]["rows_per_unit"] == {
        "rows": [0, 1, 2, 0, 1, 2], "notes": [0, 1, 0, 1, 0, 1]}
    assert record["methods"]["counting_b"]["rows_per_unit"]["notes"] == 0


def test_real_rows_are_cached_per_method(tmp_path, calls, capsys):
    """The real sweep's rows come method by method within a recording: a method added is its
    rows only, the table a full run's, and the summaries keep preprocessing first."""
    import pandas as pd

    from magbench.studies.real import RealStudy

    spiral_folder(tmp_path / "data", K=300)

    def real(algorithms):
        return RealStudy(str(tmp_path / "data"), ["spiral"], tuple(algorithms),
                         plugins=(COUNTING,))

    run_study(real(["counting_a", "sphere"]), tmp_path / "inc", progress=False)
    calls()
    run_study(real(["counting_a", "sphere", "counting_b"]), tmp_path / "inc", progress=False)
    assert calls() == {"counting_b": 6}             # 2 preprocessings x 3 fits
    assert "computing counting_b (new)" in capsys.readouterr().err
    run_study(real(["counting_a", "sphere", "counting_b"]), tmp_path / "full", progress=False)
    assert lines(tmp_path / "inc", "real_trials.csv") == \
        lines(tmp_path / "full", "real_trials.csv")
    real(["counting_a", "sphere", "counting_b"]).summarize(tmp_path / "inc")
    summary = pd.read_csv(tmp_path / "inc" / "real_summary.csv")
    assert list(zip(summary["preprocess"], summary["algorithm"], strict=True)) == [
        (p, a) for p in ("scale", "centre") for a in ("counting_a", "sphere", "counting_b")]


def test_wushi_rows_are_cached_per_method(tmp_path, calls, capsys):
    """Wu-Shi's runs come method by method (a control row beside a method's row on the first
    runs): a method added computes its rows only; Figures 3 and 6's runs, ML's, are kept."""
    from magbench.studies.wushi import WuShiStudy

    def wushi(algorithms):
        return WuShiStudy(runs=3, N=120, control_runs=1, alphas_pct=(0, 5),
                          algorithms=tuple(algorithms), plugins=(COUNTING,))

    run_study(wushi(["wu_shi", "wu_shi_nm", "counting_a"]), tmp_path / "inc", progress=False)
    calls()
    run_study(wushi(["wu_shi", "wu_shi_nm", "counting_a", "counting_b"]), tmp_path / "inc",
              progress=False)
    assert calls() == {"counting_b": 4}             # 3 runs and 1 control
    assert "computing counting_b (new)" in capsys.readouterr().err
    run_study(wushi(["wu_shi", "wu_shi_nm", "counting_a", "counting_b"]), tmp_path / "full",
              progress=False)
    for name in ("runs.csv", "fig3_objective.csv", "perturbation_runs.csv"):
        assert lines(tmp_path / "inc", name) == lines(tmp_path / "full", name)



def test_a_method_added_keeps_the_others_efficiency_rows(tmp_path, calls):
    """The review sweep's efficiency.csv after a method is added: the reused methods' rows
    are kept from the run they came from (efficiency.json names it) and the new method's
    computed, byte for byte a full run's file; a file of another run is recomputed."""
    import pandas as pd

    from magbench.cli import main

    def sweep(algorithms, folder):
        assert main(["sweep=baseline", "trials=4", "nominal.K=40", "n_jobs=1",
                     "progress=false", f"plugins=[{COUNTING}]", f"algorithms=[{algorithms}]",
                     f"results_dir={folder}", "overwrite=true"]) == 0
        return folder / "baseline"

    full = sweep("counting_a,sphere,counting_b", tmp_path / "full")
    for name, fingerprint in (("kept", None), ("other", "another run")):
        sweep("counting_a,sphere", tmp_path / name)
        if fingerprint:
            (tmp_path / name / "baseline" / "efficiency.json").write_text(
                json.dumps({"fingerprint": fingerprint}))
        out = sweep("counting_a,sphere,counting_b", tmp_path / name)
        assert lines(out, "efficiency.csv") == lines(full, "efficiency.csv")
    # Kept, not recomputed: a row changed by hand stays as it was.
    out = sweep("counting_a,sphere", tmp_path / "edited")
    table = pd.read_csv(out / "efficiency.csv")
    table.loc[table["algorithm"] == "counting_a", "eff_hi"] = 123.0
    table.to_csv(out / "efficiency.csv", index=False)
    sweep("counting_a,sphere,counting_b", tmp_path / "edited")
    table = pd.read_csv(out / "efficiency.csv").set_index("algorithm")
    assert table.loc["counting_a", "eff_hi"] == 123.0 and "counting_b" in table.index


def test_a_records_field_is_the_csv_readers():
    """The split on commas of a record without quotes, the reader for the others: the same
    field in every column, line ends, empty fields and quoted commas alike."""
    import csv
    import io

    from magbench.engine.sweep import _field

    records = ["a,bb,,d\n", "a,bb,,d\r\n", "x,y,z", ',"p,q",r\n', '"say ""hi""",b,\n',
               ",,\n", "one\n", 'a,"multi\nline",c\r\n']
    for record in records:
        fields = next(csv.reader(io.StringIO(record)))
        assert [_field(record, i) for i in range(len(fields))] == fields
    with pytest.raises(IndexError):
        _field("a,b\n", 2)


def test_a_new_methods_trials_take_the_bound_columns_of_the_reused_rows(tmp_path, calls,
                                                                       monkeypatch):
    """A method added computes its rows without the Cramer-Rao columns' work: the bound of
    each dataset is read from the reused rows (``given_reused``), and the rows equal those
    computed with it; the fingerprint does not see what was read."""
    from magbench.studies import review

    s = ReviewStudy("gamma", [Point(K=40, gamma=0.05), Point(K=40, gamma=0.1)], 3, 7,
                    ("sphere", "fang"))
    run(s, tmp_path)
    work = s.with_methods(["ellipsoid"])
    given = work.given_reused({"trials": tmp_path / "trials.csv"})
    assert set(given.known_bounds) == set(s.units())
    assert given.fingerprint() == work.fingerprint()
    table = (tmp_path / "trials.csv").read_text().splitlines()
    header = table[0].split(",")
    crb = [r.split(",")[header.index("crb")] for r in table[1:]]
    assert [repr(given.known_bounds[u][0]) for u in s.units() for _ in range(2)] == crb
    expected = {u: work.run_unit(u) for u in s.units()}

    def refused(*args, **kwargs):
        raise AssertionError("the bound was computed again")

    monkeypatch.setattr(review, "efficient_expected_J", refused)
    monkeypatch.setattr(review, "crb_covariance", refused)
    for unit in s.units():
        got = given.run_unit(unit)
        for rows in (got["trials"], expected[unit]["trials"]):
            for row in rows:
                row.pop("time_s", None)
        assert got["trials"] == expected[unit]["trials"]


def test_the_efficient_selection_is_kept_when_a_method_is_added(tmp_path, calls,
                                                                 monkeypatch):
    """``efficient_selection.csv`` depends on the points, trials, seed and delta, not on the
    methods: a method added keeps it (no call), byte for byte a full run's; a file edited
    since, or another delta, is computed again."""
    from magbench.cli.kinds.review import finish
    from magbench.studies import review

    made = []
    write = review.write_efficient_selection
    monkeypatch.setattr(review, "write_efficient_selection",
                        lambda *a, **k: made.append(1) or write(*a, **k))

    def sweep(algorithms, folder, delta=0.5):
        s = ReviewStudy("coverage", [Point(K=40, cap_deg=60.0)], 2, 7, tuple(algorithms),
                        delta=delta, plugins=(COUNTING,))
        run(s, folder, overwrite=True)
        finish(s, folder, {"progress": False})
        return folder

    full = sweep(["counting_a", "counting_b"], tmp_path / "full")
    sweep(["counting_a"], tmp_path / "inc")
    made.clear()
    out = sweep(["counting_a", "counting_b"], tmp_path / "inc")
    assert made == []
    assert lines(out, "efficient_selection.csv") == lines(full, "efficient_selection.csv")
    (out / "efficient_selection.csv").write_text("edited\n")
    sweep(["counting_a", "counting_b"], tmp_path / "inc")
    assert made == [1]
    assert lines(out, "efficient_selection.csv") == lines(full, "efficient_selection.csv")
    sweep(["counting_a", "counting_b"], tmp_path / "inc", delta=0.4)
    assert made == [1, 1]
