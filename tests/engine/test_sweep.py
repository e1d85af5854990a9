"""The sweep runner on a toy study: order, resume, damaged parts, chunking, the folder lock."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import ClassVar

import pandas as pd
import pytest

from magbench.core.seeding import rng
from magbench.engine.sweep import FolderBusy, ResultsExist, Study, folder_lock, run_study


@dataclass(frozen=True)
class Toy(Study):
    """Rows that are a pure function of the unit: easy to check after any interruption."""

    name: str = "toy"
    n: int = 12
    seed: int = 0
    stop_at: int = -1           # raise KeyboardInterrupt at this unit (a kill, in-process)
    plugins: tuple = ()

    tables: ClassVar[dict] = {"rows": ("rows.csv", ["unit", "x"]),
                              "extra": ("extra.csv", ["unit", "k"])}

    def units(self):
        return list(range(self.n))

    def run_unit(self, unit):
        if unit == self.stop_at:
            raise KeyboardInterrupt
        x = float(rng(self.seed, unit).standard_normal())
        return {"rows": [{"unit": unit, "x": x}],
                "extra": [{"unit": unit, "k": k} for k in range(unit % 3)]}


def read(folder, name="rows.csv"):
    return pd.read_csv(folder / name)


def test_rows_come_in_unit_order_whatever_the_workers(tmp_path):
    run_study(Toy(), tmp_path / "a", n_jobs=1, chunk_size=5, progress=False)
    run_study(Toy(), tmp_path / "b", n_jobs=2, chunk_size=2, progress=False)
    for name in ("rows.csv", "extra.csv"):
        pd.testing.assert_frame_equal(read(tmp_path / "a", name), read(tmp_path / "b", name))
    assert list(read(tmp_path / "a")["unit"]) == list(range(12))
    assert len(read(tmp_path / "a", "extra.csv")) == sum(u % 3 for u in range(12))
    assert not (tmp_path / "a" / "parts").exists()
    record = json.loads((tmp_path / "a" / "run.json").read_text())
    assert record["units"] == 12 and record["units_resumed"] == 0
    assert record["rows"] == {"rows": 12, "extra": 12}
    assert {"git_commit", "cpu_model", "packages", "settings", "wall_s"} <= set(record)


def test_local_workers_write_their_own_chunks(tmp_path, monkeypatch):
    """With workers on this machine the rows of a chunk never cross to the main process: each
    worker writes its chunk's part files, and the tables are those one process writes."""
    from magbench.engine import sweep

    taken = []
    monkeypatch.setattr(sweep._Parts, "write", lambda self, *args: taken.append(args))
    run_study(Toy(), tmp_path / "b", n_jobs=2, chunk_size=2, progress=False)
    assert taken == []
    monkeypatch.undo()
    run_study(Toy(), tmp_path / "a", n_jobs=1, chunk_size=5, progress=False)
    for name in ("rows.csv", "extra.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def interrupted(folder, chunk_size=2, stop_at=7):
    with pytest.raises(KeyboardInterrupt):
        run_study(Toy(stop_at=stop_at), folder, chunk_size=chunk_size, progress=False)


def cut_at(folder, unit, chunk_size=2, study=None):
    """Run ``study`` (a Toy of the same settings by default) and stop it with a
    KeyboardInterrupt at ``unit``, as a kill would (the fingerprint is unchanged)."""
    original = Toy.run_unit

    def stopping(self, u):
        if u == unit:
            raise KeyboardInterrupt
        return original(self, u)

    Toy.run_unit = stopping
    try:
        with pytest.raises(KeyboardInterrupt):
            run_study(study or Toy(), folder, chunk_size=chunk_size, progress=False)
    finally:
        Toy.run_unit = original


def test_a_resumed_run_reuses_finished_chunks_and_gives_the_same_rows(tmp_path):
    run_study(Toy(), tmp_path / "full", chunk_size=2, progress=False)
    # The stop_at field changes the fingerprint, so interrupt with a study of the same settings
    # by monkey-patching run_unit instead.
    cut = tmp_path / "cut"
    calls = []
    original = Toy.run_unit

    def counting(self, unit):
        calls.append(unit)
        if unit == 7:
            raise KeyboardInterrupt
        return original(self, unit)

    Toy.run_unit = counting
    try:
        with pytest.raises(KeyboardInterrupt):
            run_study(Toy(), cut, chunk_size=2, progress=False)
    finally:
        Toy.run_unit = original
    assert len(list((cut / "parts").glob("c*.json"))) == 3      # units 0-5 finished
    run_study(Toy(), cut, chunk_size=2, progress=False)
    pd.testing.assert_frame_equal(read(cut), read(tmp_path / "full"))
    assert json.loads((cut / "run.json").read_text())["units_resumed"] == 6


@pytest.mark.parametrize("damage", ["truncate", "header_only", "delete_row", "empty",
                                    "random_bytes", "bad_record", "bad_manifest",
                                    "no_manifest"])
def test_damaged_parts_are_recomputed_never_reused(tmp_path, damage):
    run_study(Toy(), tmp_path / "full", chunk_size=4, progress=False)
    cut = tmp_path / "cut"
    cut_at(cut, 9, chunk_size=4)
    parts = cut / "parts"
    part = sorted(parts.glob("c*.rows.csv"))[0]
    text = part.read_text()
    if damage == "truncate":
        part.write_text(text[: len(text) // 2])
    elif damage == "header_only":
        part.write_text(text.splitlines()[0] + "\n")
    elif damage == "delete_row":
        part.write_text("\n".join(text.splitlines()[:-1]) + "\n")
    elif damage == "empty":
        part.write_text("")
    elif damage == "random_bytes":
        part.write_bytes(bytes(range(256)))
    elif damage == "bad_record":
        sorted(parts.glob("c*.json"))[0].write_text("{not json")
    elif damage == "bad_manifest":
        (parts / "manifest.json").write_text("garbage")
    elif damage == "no_manifest":
        (parts / "manifest.json").unlink()
    with pytest.warns(RuntimeWarning):
        run_study(Toy(), cut, chunk_size=4, progress=False)
    for name in ("rows.csv", "extra.csv"):
        pd.testing.assert_frame_equal(read(cut, name), read(tmp_path / "full", name))


def test_another_chunk_size_or_setting_never_mixes_rows(tmp_path):
    interrupted(tmp_path, chunk_size=2, stop_at=7)
    # Other settings: the parts of the interrupted run belong to another fingerprint.
    run_study(Toy(seed=5), tmp_path, chunk_size=2, progress=False)
    fresh = tmp_path / "fresh"
    run_study(Toy(seed=5), fresh, chunk_size=2, progress=False)
    pd.testing.assert_frame_equal(read(tmp_path), read(fresh))
    # Same settings, other chunking: parts are named by their unit range, so none is misread.
    run_study(Toy(seed=5), tmp_path / "c5", chunk_size=5, progress=False)
    pd.testing.assert_frame_equal(read(tmp_path / "c5"), read(fresh))


def test_a_second_run_on_a_busy_folder_is_refused(tmp_path):
    with folder_lock(tmp_path), pytest.raises(FolderBusy, match="in use by a running magbench"):
        run_study(Toy(), tmp_path, progress=False)
    run_study(Toy(), tmp_path, progress=False)          # the lock went with its holder
    assert len(read(tmp_path)) == 12


def test_a_finished_run_is_reused_and_never_silently_replaced(tmp_path, capsys):
    run_study(Toy(), tmp_path, progress=False)
    first = (tmp_path / "run.json").read_text()
    run_study(Toy(), tmp_path, progress=False)           # same config: reused, not rerun
    assert (tmp_path / "run.json").read_text() == first
    assert "its tables are reused" in capsys.readouterr().err
    with pytest.raises(ResultsExist, match=r"another configuration.*overwrite=true"):
        run_study(Toy(seed=5), tmp_path, progress=False)
    assert json.loads((tmp_path / "run.json").read_text())["fingerprint"] == Toy().fingerprint()
    run_study(Toy(seed=5), tmp_path, progress=False, overwrite=True)
    run_study(Toy(seed=5), tmp_path / "fresh", progress=False)
    pd.testing.assert_frame_equal(read(tmp_path), read(tmp_path / "fresh"))


def test_tables_without_a_run_record_are_not_replaced(tmp_path):
    """Results written by an older magbench (no run.json) count as another configuration."""
    (tmp_path / "rows.csv").write_text("unit,x\n0,1.0\n")
    with pytest.raises(ResultsExist, match=r"no readable run\.json"):
        run_study(Toy(), tmp_path, progress=False)
    assert (tmp_path / "rows.csv").read_text() == "unit,x\n0,1.0\n"


def test_a_run_too_large_for_the_disk_or_memory_is_refused_before_any_work(tmp_path,
                                                                           monkeypatch):
    import magbench.engine.sweep as sweep

    # 12 rows of 2 columns: 960 bytes of CSV (parts and merged table), 576 bytes in memory.
    monkeypatch.setattr(sweep, "_free_bytes", lambda folder: (900, 10**9))
    with pytest.raises(sweep.TooLarge, match=r"about 12 rows.*of disk \(9e-07 GB free"):
        run_study(Toy(), tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()
    monkeypatch.setattr(sweep, "_free_bytes", lambda folder: (10**9, 500))
    with pytest.raises(sweep.TooLarge, match="of memory"):
        run_study(Toy(), tmp_path / "out", progress=False)
    monkeypatch.setattr(sweep, "_free_bytes", lambda folder: (1000, 600))
    run_study(Toy(), tmp_path / "out", progress=False)          # just fits
    assert len(read(tmp_path / "out")) == 12


#: Run in a fresh interpreter where ``import fcntl`` and ``import resource`` fail (as on
#: Windows): ``calibrate`` works and a sweep still runs (without an OS lock, with a warning
#: naming it).
NO_FCNTL = """
import sys, warnings
class Block:
    def find_spec(self, name, path=None, target=None):
        if name in ("fcntl", "resource"):
            raise ImportError(f"no {name} on this system")
sys.meta_path.insert(0, Block())
sys.modules.pop("fcntl", None)
sys.modules.pop("resource", None)
import numpy as np, pandas as pd
from magbench.cli import main
from magbench.core.geometry import fibonacci_sphere
from magbench.engine.sweep import run_study
from tests.engine.test_sweep import Toy
folder = sys.argv[1]
y = fibonacci_sphere(200) * 50 + np.array([10.0, -5.0, 3.0])
pd.DataFrame(y, columns=["mx", "my", "mz"]).to_csv(folder + "/rec.csv", index=False)
code = main(["calibrate", "progress=false", f"file={folder}/rec.csv", "method=sphere",
             f"out={folder}/cal", "bootstrap=0"])
with warnings.catch_warnings(record=True) as seen:
    warnings.simplefilter("always")
    run_study(Toy(), folder + "/toy", progress=False)
print(code, "fcntl" in sys.modules or "resource" in sys.modules,
      [str(w.message)[:27] for w in seen])
"""


def test_calibrate_and_a_sweep_need_no_fcntl(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": f"{repo / 'src'}{os.pathsep}{repo}"}
    done = subprocess.run([sys.executable, "-c", NO_FCNTL, str(tmp_path)], cwd=repo, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "0 False ['no file locking on this sys']"
    assert (tmp_path / "cal" / "calibration.json").exists()
    assert len(read(tmp_path / "toy")) == 12


def test_a_kill_between_the_tables_and_run_json_is_resumed(tmp_path, monkeypatch):
    """Tables merged, run.json not yet written: the parts are complete, so a rerun finishes
    the run instead of refusing the folder."""
    import magbench.engine.sweep as sweep

    run_study(Toy(), tmp_path / "full", chunk_size=4, progress=False)
    real = sweep.write_run_record

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "write_run_record", killed)
    with pytest.raises(KeyboardInterrupt):
        run_study(Toy(), tmp_path / "cut", chunk_size=4, progress=False)
    assert (tmp_path / "cut" / "rows.csv").exists() and (tmp_path / "cut" / "parts").exists()
    assert not (tmp_path / "cut" / "run.json").exists()
    monkeypatch.setattr(sweep, "write_run_record", real)
    run_study(Toy(), tmp_path / "cut", chunk_size=4, progress=False)
    record = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert record["units_resumed"] == 12
    for name in ("rows.csv", "extra.csv"):
        pd.testing.assert_frame_equal(read(tmp_path / "cut", name), read(tmp_path / "full", name))


@pytest.mark.parametrize("change", ["delete_rows", "cut_half", "edit_value", "remove"])
def test_a_finished_table_changed_afterwards_is_refused_never_reused(tmp_path, change):
    from magbench.core.files import file_sha256

    run_study(Toy(), tmp_path, progress=False)
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["tables"]["rows"] == {"file": "rows.csv", "rows": 12,
                                        "sha256": file_sha256(tmp_path / "rows.csv")}
    assert record["tables"]["extra"]["rows"] == 12
    path = tmp_path / "rows.csv"
    lines = path.read_text().splitlines(keepends=True)
    if change == "delete_rows":
        path.write_text("".join(lines[:-3]))
    elif change == "cut_half":
        path.write_text(path.read_text()[: len(path.read_text()) // 2])
    elif change == "edit_value":
        path.write_text("".join([lines[0], lines[1].replace(",", ",1", 1), *lines[2:]]))
    else:
        path.unlink()
    with pytest.raises(ResultsExist, match=r"rows\.csv \((checksum differs from run\.json|"
                                           r"missing)\).*changed after it ended.*overwrite"):
        run_study(Toy(), tmp_path, progress=False)
    run_study(Toy(), tmp_path, progress=False, overwrite=True)
    run_study(Toy(), tmp_path / "fresh", progress=False)
    pd.testing.assert_frame_equal(read(tmp_path), read(tmp_path / "fresh"))


def test_chunks_of_another_configuration_are_never_reused_even_under_its_manifest(tmp_path):
    """Chunk files copied from a run with another seed into this run's parts: every chunk
    record carries its fingerprint, so they are recomputed, not merged."""
    import shutil

    interrupted(tmp_path / "seed7", chunk_size=2, stop_at=7)        # Toy(stop_at=7), seed 0
    run_study(Toy(seed=2), tmp_path / "run", chunk_size=2, progress=False)
    cut = tmp_path / "seed2"
    cut_at(cut, 3, study=Toy(seed=2))
    for part in (tmp_path / "seed7" / "parts").glob("c*"):
        if not (cut / "parts" / part.name).exists():
            shutil.copy(part, cut / "parts" / part.name)
    with pytest.warns(RuntimeWarning, match="written by another configuration"):
        run_study(Toy(seed=2), cut, chunk_size=2, progress=False)
    pd.testing.assert_frame_equal(read(cut), read(tmp_path / "run"))


def test_another_chunk_size_on_resume_warns_and_gives_the_same_rows(tmp_path):
    run_study(Toy(), tmp_path / "full", chunk_size=5, progress=False)
    cut = tmp_path / "cut"
    cut_at(cut, 7)
    with pytest.warns(RuntimeWarning, match=r"3 finished chunk\(s\) \(6 units\) were cut with "
                                            "another chunk_size"):
        run_study(Toy(), cut, chunk_size=5, progress=False)
    pd.testing.assert_frame_equal(read(cut), read(tmp_path / "full"))
    assert json.loads((cut / "run.json").read_text())["units_resumed"] == 0


def test_a_run_stopped_between_chunks_leaves_no_joblib_warning(tmp_path, monkeypatch):
    """A Ctrl-C while a finished chunk is taken in stops the run with the chunks still on the
    workers cancelled on purpose: joblib's warning about them would follow the run's one line."""
    import warnings

    import tqdm

    calls = []

    def stop(self, n=1):
        calls.append(n)
        if len(calls) > 1:           # the first sets the bar to the chunks already done
            raise KeyboardInterrupt

    monkeypatch.setattr(tqdm.tqdm, "update", stop)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(KeyboardInterrupt):
            run_study(Toy(n=40), tmp_path / "a", n_jobs=2, chunk_size=1, progress=False)
    assert [str(w.message) for w in caught if "tasks" in str(w.message)] == []
