"""The NumPy reader of binary DataFlash logs: the values pymavlink gives, on the
fixture logs (the text reader's too), on formats with multipliers, across chunk boundaries and
on the shared sample logs; what it does not read (corrupt bytes) is left to pymavlink."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from magbench.sources import logs
from magbench.sources.logs import read_log
from tests.sources.log_writers import write_dataflash
from tests.sources.test_logs import SHARED, ardupilot_log

pytest.importorskip("pymavlink")

SHARED_BINS = sorted(Path("/work/shared/data/logs").glob("*.bin")) or sorted(
    SHARED.glob("*.bin"))


def same_rows(path: Path) -> dict:
    """The chunked reader's rows (binary or text by the suffix), checked equal (every value,
    bit for bit) to pymavlink's."""
    reader = logs._binary_rows if path.suffix == ".bin" else logs._text_rows
    ours, theirs = reader(path), logs._pymavlink_rows(path)
    ours = {k: v for k, v in ours.items() if len(v)}
    assert sorted(ours) == sorted(theirs)
    for kind, columns in theirs.items():
        assert list(ours[kind].values) == list(columns.values), kind
        for name in columns.values:
            np.testing.assert_array_equal(ours[kind][name], columns[name], err_msg=name)
    return ours


def same_tables(path: Path) -> None:
    """read_log's columns for every compass equal those from pymavlink's rows."""
    ours = read_log(path)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(logs, "_binary_rows", lambda p: {})       # {} -> pymavlink
        patch.setattr(logs, "_text_rows", lambda p: {})
        theirs = read_log(path)
    assert sorted(ours.mags) == sorted(theirs.mags) and ours.notes == theirs.notes
    for i in theirs.mags:
        a, b = ours.columns(i), theirs.columns(i)
        assert list(a) == list(b)
        for name in b:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


@pytest.mark.parametrize("name", ["flight.bin", "flight.log"])
def test_the_fixture_log_reads_as_pymavlink_reads_it(tmp_path, name):
    path = ardupilot_log(tmp_path / name, binary=name.endswith(".bin"))
    rows = same_rows(path)
    assert {k: len(v) for k, v in rows.items()} == {"MAG": 166, "IMU": 650, "ATT": 138,
                                                    "BAT": 70, "CTUN": 35}
    assert "RawX" in rows["MAG"] and "MagX" not in rows["MAG"]     # combined as read
    same_tables(path)


def test_multiplied_and_integer_formats_read_as_pymavlink_reads_them(tmp_path):
    n = 50
    rows = [(1000 * k, 1 + k % 2, 1000 * k - 30000, -7 * k, 0.25 * k, -123456789 + k)
            for k in range(n)]
    path = write_dataflash(tmp_path / "mult.bin", {
        # centi-scaled, unsigned, scaled by 1e-7, double, int64 fields beside the compass
        "MAG": ("QBcefL", "TimeUS,I,MagX,MagY,MagZ,OfsX", rows),
        "BAT": ("QBCd", "TimeUS,Inst,Volt,Curr", [(r[0], 0, 1234 + r[0] % 7, 0.1 * k)
                                                  for k, r in enumerate(rows)]),
        "CTUN": ("qNhE", "TimeUS,Label,ThI,ThO", [(r[0], b"text", -3, 17 * k)
                                                  for k, r in enumerate(rows)]),
    }, binary=True)
    same_rows(path)
    same_tables(path)


def test_messages_cut_across_chunks_read_the_same(tmp_path, monkeypatch):
    path = ardupilot_log(tmp_path / "flight.bin", binary=True)
    whole = logs._binary_rows(path)
    monkeypatch.setattr(logs, "BINARY_CHUNK", 97)          # every message split somewhere
    parts = same_rows(path)
    for kind, columns in whole.items():
        for name in columns.values:
            np.testing.assert_array_equal(parts[kind][name], columns[name])


def test_a_cut_last_message_is_dropped_as_pymavlink_drops_it(tmp_path):
    path = ardupilot_log(tmp_path / "flight.bin", binary=True)
    path.write_bytes(path.read_bytes()[:-5])
    same_rows(path)


def test_corrupt_bytes_are_left_to_pymavlink(tmp_path):
    path = ardupilot_log(tmp_path / "flight.bin", binary=True)
    data = path.read_bytes()
    middle = len(data) // 2
    path.write_bytes(data[:middle] + b"\x00" * 7 + data[middle:])
    with pytest.raises(logs._Unusual, match="no message header"):
        logs._binary_rows(path)
    log = read_log(path)                        # pymavlink skips the bytes
    assert sorted(log.mags) == [0, 1]


@pytest.mark.skipif(not SHARED_BINS, reason="no shared DataFlash .bin logs")
@pytest.mark.parametrize("path", SHARED_BINS, ids=lambda p: p.name)
def test_the_shared_binary_logs_read_as_pymavlink_reads_them(path):
    try:
        logs._binary_rows(path)
    except logs._Unusual:
        pytest.skip("a log the NumPy reader leaves to pymavlink")
    same_rows(path)
