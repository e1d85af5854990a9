"""The chunked reader of text DataFlash logs: the values pymavlink gives on integer
and multiplied formats and across chunk boundaries (the fixture log beside the binary one's in
``test_dataflash_reader``); what it does not read as it stands (a short line, text in a number,
a line before its format) is left to pymavlink, whose results and errors are kept."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.sources import logs
from magbench.sources.logs import read_log
from tests.sources.log_writers import write_dataflash
from tests.sources.test_dataflash_reader import same_rows, same_tables
from tests.sources.test_logs import ardupilot_log

pytest.importorskip("pymavlink")


def test_integer_and_multiplied_formats_read_as_pymavlink_reads_them(tmp_path):
    # a text log holds the logged numbers: no multiplier, int() or float() by the character
    n = 50
    rows = [(1000 * k, 1 + k % 2, 1000 * k - 30000, -7 * k, 0.1 * k + 1e-9,
             -123456789 + k) for k in range(n)]
    path = write_dataflash(tmp_path / "mult.log", {
        "MAG": ("QBcefL", "TimeUS,I,MagX,MagY,MagZ,OfsX", rows),
        "BAT": ("QMCd", "TimeUS,Inst,Volt,Curr", [(r[0], 0, 1234 + r[0] % 7, 0.1 * k)
                                                  for k, r in enumerate(rows)]),
        "CTUN": ("qNhg", "TimeUS,Label,ThI,ThO", [(r[0], "text", -3, 0.5 * k)
                                                  for k, r in enumerate(rows)]),
    }, binary=False)
    ours = same_rows(path)
    assert ours["MAG"]["RawX"][3] == -27000.0 - -123456786.0       # MagX - OfsX, as logged
    assert ours["BAT"]["Curr"][3] == 0.1 * 3
    same_tables(path)


@pytest.mark.parametrize("chunk", [7, 64, 333])
def test_lines_cut_across_chunks_read_the_same(tmp_path, monkeypatch, chunk):
    path = ardupilot_log(tmp_path / "flight.log", binary=False)
    whole = logs._text_rows(path)
    monkeypatch.setattr(logs, "TEXT_CHUNK", chunk)       # every line split somewhere
    parts = same_rows(path)
    for kind, columns in whole.items():
        for name in columns.values:
            np.testing.assert_array_equal(parts[kind][name], columns[name])


def test_a_log_without_a_last_newline_or_with_crlf_reads_the_same(tmp_path):
    # pymavlink reads no message from a last line without its newline
    path = ardupilot_log(tmp_path / "flight.log", binary=False)
    text = path.read_text()
    path.write_text(text.rstrip("\n"))
    assert len(same_rows(path)["ATT"]) == 137
    path.write_bytes(text.replace("\n", "\r\n").encode())
    same_rows(path)


def _edited(tmp_path, edit) -> object:
    path = ardupilot_log(tmp_path / "flight.log", binary=False)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(edit(lines)) + "\n")
    return path


def _mag_lines(lines: list[str]) -> list[int]:
    return [k for k, line in enumerate(lines) if line.startswith("MAG, ")]


@pytest.mark.parametrize("case, edit, why", [
    ("short line", lambda ls: [ls[k].rsplit(", ", 1)[0] if k in _mag_lines(ls)[10:20]
                               else ls[k] for k in range(len(ls))], "MAG line pymavlink"),
    ("text in a number", lambda ls: [ls[k].replace(", 0, ", ", x, ", 1)
                                     if k == _mag_lines(ls)[5] else ls[k]
                                     for k in range(len(ls))], "MAG.I does not convert"),
    ("a line before its format", lambda ls: [ls[0], ls[_mag_lines(ls)[0]], *ls[1:]],
     "MAG line pymavlink"),
    ("a format defined twice", lambda ls: [*ls[:3], ls[1], *ls[3:]], "defined twice"),
    ("a last line in the last 16 bytes", lambda ls: [*ls, "CTUN, 9, 1"],
     "the last 16 bytes"),
    ("not ASCII", lambda ls: [*ls[:9], "MSG, 1, caf\u00e9", *ls[9:]], "not ASCII"),
])
def test_what_it_does_not_read_as_it_stands_is_left_to_pymavlink(tmp_path, case, edit, why):
    path = _edited(tmp_path, edit)
    with pytest.raises(logs._Unusual, match=why):
        logs._text_rows(path)
    try:                            # pymavlink's result or its one-line error, as before
        theirs = read_log(path)
    except ValueError as exc:
        assert "\n" not in str(exc)
        return
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(logs, "_text_rows", lambda p: {})
        again = read_log(path)
    assert sorted(theirs.mags) == sorted(again.mags) and theirs.notes == again.notes
    for i in theirs.mags:
        np.testing.assert_array_equal(theirs.mags[i].values, again.mags[i].values)


def test_a_short_compass_line_is_still_counted_as_dropped(tmp_path):
    # pymavlink returns the message after a dropped line twice; the note counts what it read
    path = _edited(tmp_path, lambda ls: [ls[k].rsplit(", ", 1)[0] if k in _mag_lines(ls)[::9]
                                         else ls[k] for k in range(len(ls))])
    log = read_log(path)
    assert any("compass line(s) dropped" in note for note in log.notes)
