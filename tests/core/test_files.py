"""Atomic writes and the chunked column reader."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.core.files import read_csv_columns, write_csv_atomic, write_records_csv


@pytest.fixture
def table() -> pd.DataFrame:
    rng = np.random.default_rng(0)
    n = 53
    return pd.DataFrame({"K": rng.integers(10, 20, n), "algorithm": rng.choice(["a", "bb"], n),
                         "J": rng.exponential(1.0, n), "meaningful": rng.random(n) < 0.8,
                         "error": np.where(rng.random(n) < 0.9, "", "failed: x"),
                         "skip": rng.random(n)})


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz"])
@pytest.mark.parametrize("chunk_rows", [7, 1000])
def test_reads_the_columns_one_read_csv_reads(tmp_path, table, suffix, chunk_rows):
    path = tmp_path / f"t{suffix}"
    write_csv_atomic(table, path)
    columns = ["K", "algorithm", "J", "meaningful", "error"]
    got = read_csv_columns(path, [*columns, "absent"], chunk_rows=chunk_rows)
    pd.testing.assert_frame_equal(got, pd.read_csv(path, usecols=columns), check_exact=True)


def test_an_empty_table_keeps_its_columns(tmp_path, table):
    write_csv_atomic(table.iloc[:0], tmp_path / "t.csv")
    got = read_csv_columns(tmp_path / "t.csv", ["K", "J"])
    assert list(got.columns) == ["K", "J"] and len(got) == 0


def test_write_is_atomic_and_compresses_gz(tmp_path, table):
    write_csv_atomic(table, tmp_path / "t.csv.gz")
    assert (tmp_path / "t.csv.gz").read_bytes()[:2] == b"\x1f\x8b"
    assert not list(tmp_path.glob(".tmp-*"))


def test_records_are_written_as_pandas_writes_their_table(tmp_path):
    # calibrate's ranking.csv: ints, floats by repr, NaN, a nullable rank, bools (numpy's too),
    # text that needs quoting.
    records = [{"rank": 1, "algorithm": "fang", "K": 1854, "J_r": 1 / 3, "tiny": 1e-300,
                "big": 1e16, "whole": 3.0, "nan": np.nan, "ok": True, "scored": np.bool_(True),
                "p95": np.float64(5.906275100477975), "note": "a, b \"c\"", "error": ""},
               {"rank": None, "algorithm": "sphere", "K": 12, "J_r": -0.0, "tiny": 2.5e-7,
                "big": np.inf, "whole": np.nan, "nan": np.nan, "ok": False,
                "scored": np.bool_(False), "p95": np.nan, "note": " lead\nline", "error": "x"}]
    write_records_csv(records, tmp_path / "ours.csv")
    frame = pd.DataFrame(records).astype({"rank": "Int64"})
    frame.to_csv(tmp_path / "pandas.csv", index=False)
    assert (tmp_path / "ours.csv").read_bytes() == (tmp_path / "pandas.csv").read_bytes()


def awkward_frames() -> list[pd.DataFrame]:
    """Frames whose CSV text is easy to get wrong: floats of every size and sign, missing
    values in every kind of column, text that needs quoting, mixed object columns."""
    rng = np.random.default_rng(7)
    n = 400
    floats = rng.standard_normal(n) * 10.0 ** rng.integers(-320, 300, n)
    floats[:8] = [0.0, -0.0, np.inf, -np.inf, np.nan, 1e16, 1e-5, 123456789.0]
    text = rng.choice(["", "ok", "a,b", 'say "x"', "two\nlines", " pad ", "é"], n)
    frames = [
        pd.DataFrame({"f": floats, "i": rng.integers(-5, 5, n), "b": rng.random(n) < 0.5,
                      "s": text, "u": rng.integers(0, 9, n).astype(np.uint8)}),
        pd.DataFrame([{"x": 1, "y": None, "z": True}, {"x": 2.5, "y": "t", "z": None},
                      {"x": np.nan, "y": 3, "z": False}]),
        pd.DataFrame({"only": ["", "a", ""]}),
        pd.DataFrame({"a": [1.0, np.nan], "s": pd.array(["x", None], dtype="str")}),
        pd.DataFrame({"mixed": pd.Series([1, "a", None, 2.5, True, np.float64(0.1)],
                                         dtype=object)}),
        pd.DataFrame(columns=["a", "b"]),
        pd.DataFrame({"n": pd.array([1, None], dtype="Int64"), "c": ["a", "b"]}),
        pd.DataFrame({"f32": np.array([0.1, 2.0], dtype=np.float32)}),
        pd.DataFrame({3: [1.5], "x": ["y"]}),
    ]
    return frames


@pytest.mark.parametrize("index", range(9))
def test_write_csv_atomic_writes_the_bytes_to_csv_writes(tmp_path, index):
    """The column-by-column writer (or its fallback) gives ``to_csv``'s bytes exactly."""
    frame = awkward_frames()[index]
    write_csv_atomic(frame, tmp_path / "ours.csv")
    frame.to_csv(tmp_path / "pandas.csv", index=False)
    assert (tmp_path / "ours.csv").read_bytes() == (tmp_path / "pandas.csv").read_bytes()


def test_plain_frames_take_the_column_writer_and_others_to_csv():
    from magbench.core.files import _csv_columns

    fast = [_csv_columns(f) is not None for f in awkward_frames()]
    assert fast == [True, True, True, True, True, True, False, False, True]


#: Takes and releases the lock ``n`` times, each time checking, under the lock, that no other
#: holder is inside (a shared marker file) and counting the times it was refused.
CONTENDER = """
import os, sys
from pathlib import Path
from magbench.core.files import LockHeld, exclusive_lock
lock, inside, n = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
held = refused = 0
while held < n:
    try:
        with exclusive_lock(lock, f"pid {os.getpid()}"):
            fd = os.open(inside, os.O_CREAT | os.O_EXCL | os.O_WRONLY)   # fails if another is in
            os.close(fd)
            os.unlink(inside)
            held += 1
    except LockHeld:
        refused += 1
print(held, refused)
"""


def test_the_lock_admits_one_holder_at_a_time_and_leaves_no_file(tmp_path):
    # Two processes taking and removing the lock file as fast as they can: a contender that
    # opened the file just before its holder removed it must not hold a second lock.
    import subprocess
    import sys

    lock, inside = tmp_path / ".lock", tmp_path / "inside"
    procs = [subprocess.Popen([sys.executable, "-c", CONTENDER, str(lock), str(inside), "300"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    results = [p.communicate(timeout=120) for p in procs]
    for p, (out, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
        assert out.split()[0] == "300"
    assert list(tmp_path.iterdir()) == []


def test_a_held_lock_refuses_a_second_block_and_names_its_holder(tmp_path):
    from magbench.core.files import LockHeld, exclusive_lock

    with exclusive_lock(tmp_path / ".lock", "pid 1 since noon") as held:
        assert held and (tmp_path / ".lock").read_text() == "pid 1 since noon"
        with pytest.raises(LockHeld) as refused, exclusive_lock(tmp_path / ".lock"):
            pass
        assert refused.value.holder == "pid 1 since noon"
    assert not (tmp_path / ".lock").exists()


@pytest.mark.parametrize("chunk", [3, 100])
def test_each_block_is_formatted_once_with_to_csvs_bytes(tmp_path, monkeypatch, chunk):
    """The first block's cells, formatted to see whether the column writer applies, are
    the ones written: one formatting per block, the bytes still ``to_csv``'s."""
    import magbench.core.files as files

    frame = pd.DataFrame({"a": np.arange(10) / 7.0, "b": list("abcdefghij"),
                          "c": np.arange(10) % 2 == 0})
    calls = []
    real = files._csv_columns
    monkeypatch.setattr(files, "CHUNK_ROWS", chunk)
    monkeypatch.setattr(files, "_csv_columns", lambda f: calls.append(len(f)) or real(f))
    write_csv_atomic(frame, tmp_path / "ours.csv")
    frame.to_csv(tmp_path / "pandas.csv", index=False)
    assert (tmp_path / "ours.csv").read_bytes() == (tmp_path / "pandas.csv").read_bytes()
    assert calls == ([3, 3, 3, 1] if chunk == 3 else [10])


def test_rows_are_written_as_the_frame_of_them_writes(tmp_path):
    """write_rows_csv's bytes are write_csv_atomic's of pd.DataFrame(rows, columns) for
    every kind of column a study gives (and the frame's for the kinds it does not format):
    integers, floats with NaN, inf and integers among them, booleans, text with commas,
    quotes and line breaks, missing keys and values, NumPy scalars, mixed kinds."""
    import numpy as np
    import pandas as pd

    from magbench.core.files import write_csv_atomic, write_rows_csv

    columns = ["i", "f", "fi", "b", "s", "none", "missing", "np", "mixed", "big", "boolnone",
               "intnone"]
    rows = [
        {"i": 1, "f": 0.1, "fi": 2, "b": True, "s": "ok", "none": None, "np": np.float64(1 / 3),
         "mixed": "a", "big": 2 ** 70, "boolnone": True, "intnone": 3},
        {"i": -7, "f": float("nan"), "fi": 2.5, "b": np.bool_(False), "s": 'say "hi", then\nbye',
         "none": None, "np": np.int64(4), "mixed": 1.5, "big": 1, "boolnone": None,
         "intnone": None},
        {"i": np.int32(3), "f": float("inf"), "fi": -0.0, "b": False, "s": None, "none": None,
         "np": np.float64("nan"), "mixed": None, "big": 2, "boolnone": False, "intnone": 5},
    ]
    for subset in (columns, columns[:6], ["i", "f", "b", "s", "intnone"], ["none"]):
        for n in (0, 1, 3):
            write_rows_csv(rows[:n], subset, tmp_path / "fast.csv")
            write_csv_atomic(pd.DataFrame(rows[:n], columns=subset), tmp_path / "frame.csv")
            assert (tmp_path / "fast.csv").read_bytes() == (tmp_path / "frame.csv").read_bytes()
