"""Hostile inputs (issue 40): each answers in one line with exit 2, or is read with a warning
that says what was left out; small files generated here, never kept."""

from __future__ import annotations

import gzip
import os
import sys

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from tests.sources.log_writers import write_dataflash
from tests.sources.test_logs import ardupilot_log, px4_log

MAG_ROWS = [(1000 * i, 100.0 + np.sin(i), 50.0 + np.cos(i), 20.0 + i % 7) for i in range(60)]


def one_line_exit_2(args: list[str], capsys, expected: str) -> str:
    """Run a command that must refuse: exit 2, one short line on stderr naming the fault."""
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and len(lines[0]) < 300, err[:500]
    assert lines[0].startswith("magbench: error: ") and expected in lines[0], lines[0]
    return lines[0]


def both(tmp_path, path) -> list[list[str]]:
    """``extract`` and ``calibrate`` of one file."""
    return [["extract", f"file={path}", f"out={tmp_path / 'x.csv'}"],
            ["calibrate", f"file={path}", f"out={tmp_path / 'out'}", "progress=false",
             "picture=false"]]


@pytest.mark.parametrize("suffix", [".log", ".bin"])
def test_a_dataflash_format_without_magz_is_named(tmp_path, capsys, suffix):
    pytest.importorskip("pymavlink")
    path = write_dataflash(tmp_path / f"nomagz{suffix}",
                           {"MAG": ("Qfff", "TimeUS,MagX,MagY,Foo", MAG_ROWS)}, suffix == ".bin")
    for args in both(tmp_path, path):
        one_line_exit_2(args, capsys, "malformed DataFlash FMT: MAG has no field MagZ")


@pytest.mark.parametrize("suffix", [".log", ".bin"])
def test_a_dataflash_field_of_text_where_a_number_belongs_is_named(tmp_path, capsys, suffix):
    pytest.importorskip("pymavlink")
    text = b"abc" if suffix == ".bin" else "abc"
    rows = [(r[0], text, r[2], r[3]) for r in MAG_ROWS]
    path = write_dataflash(tmp_path / f"ztype{suffix}",
                           {"MAG": ("QZff", "TimeUS,MagX,MagY,MagZ", rows)}, suffix == ".bin")
    for args in both(tmp_path, path):
        one_line_exit_2(args, capsys, "MAG.MagX holds 'abc', not a number (format character "
                                      "'Z')")


def gzip_of(path, chunk: bytes, times: int, head: bytes = b"mx,my,mz\n"):
    with gzip.open(path, "wb", compresslevel=1) as handle:
        handle.write(head)
        for _ in range(times):
            handle.write(chunk)
    return path


def test_a_gzip_bomb_is_refused_at_its_cap(tmp_path, capsys):
    from magbench.sources import recordings

    # Rows that parse, packed ~150 times: past 100 times the file (the 64 MiB floor lowered
    # for the test, so that it stays small).
    path = gzip_of(tmp_path / "bomb.csv.gz", b"1,2,3\n" * 4096, 400)
    assert os.path.getsize(path) < 100_000
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(recordings, "MIN_UNPACK_CAP", 1 << 20)
        line = one_line_exit_2(["calibrate", f"file={path}", f"out={tmp_path / 'out'}"],
                               capsys, "bomb.csv.gz unpacks (gzip) to more than ")
    cap = 100 * os.path.getsize(path) / 2**20
    assert f"to more than {cap:.0f} MiB (100 times its size, at most 4 GiB)" in line


def test_a_compressed_line_without_end_is_refused(tmp_path, capsys):
    path = gzip_of(tmp_path / "line.csv.gz", b"1" * (1 << 16), 32)
    one_line_exit_2(["calibrate", f"file={path}", f"out={tmp_path / 'out'}"], capsys,
                    "line.csv.gz unpacks (gzip) to a line longer than 1 MiB")


@pytest.mark.parametrize("packed", [False, True])
def test_a_file_of_nul_bytes_is_one_short_line(tmp_path, capsys, packed):
    path = tmp_path / "nul.csv"
    if packed:
        path = gzip_of(tmp_path / "nul.csv.gz", b"\0" * (1 << 16), 64, head=b"")
    else:
        path.write_bytes(b"\0" * (4 << 20))
    one_line_exit_2(["calibrate", f"file={path}", f"out={tmp_path / 'out'}"], capsys,
                    "NUL bytes: binary data, not a CSV of magnetometer samples")


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_a_device_and_a_fifo_are_refused_by_name(tmp_path, capsys):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    one_line_exit_2(["calibrate", "file=/dev/zero", f"out={tmp_path / 'out'}"], capsys,
                    "file /dev/zero is a character device, not a regular file")
    one_line_exit_2(["calibrate", f"file={fifo}", f"out={tmp_path / 'out'}"], capsys,
                    "is a named pipe (FIFO), not a regular file")
    os.unlink(fifo)
    os.mkfifo(tmp_path / "pipe.log")
    one_line_exit_2(["extract", f"file={tmp_path / 'pipe.log'}"], capsys,
                    "is a named pipe (FIFO), not a regular file; expected a flight log")


def test_n_jobs_is_bounded_by_the_cpus():
    # The check itself (the command line turns its UsageError into one line and exit 2, as
    # tests/cli/test_main.py shows for every bad value): composing a whole config costs
    # seconds.
    from omegaconf import OmegaConf

    from magbench.cli.config import UsageError, check_common

    most = 4 * (os.cpu_count() or 1)
    with pytest.raises(UsageError, match=rf"^n_jobs must be at most {most} \(4 per CPU of this "
                                         r"machine's \d+; -1 = every core\), got 100000$"):
        check_common(OmegaConf.create({"n_jobs": 100000, "plugins": []}))
    with pytest.raises(UsageError, match="got -100000"):
        check_common(OmegaConf.create({"n_jobs": -100000, "plugins": []}))


def test_dropped_compass_lines_are_counted_and_said(tmp_path, capsys):
    pytest.importorskip("pymavlink")
    path = ardupilot_log(tmp_path / "flight.log", binary=False)
    lines = path.read_text().splitlines()
    mag = [k for k, line in enumerate(lines) if line.startswith("MAG,")]
    for k in mag[::5]:                          # every fifth compass line loses a field
        lines[k] = lines[k].rsplit(",", 1)[0]
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "x.csv"
    assert main(["extract", f"file={path}", "instance=0", f"out={out}"]) == 0
    said = capsys.readouterr().out
    assert f"warning: flight.log: {len(mag[::5])} compass line(s) dropped" in said


def test_a_cut_ulog_is_read_with_a_warning(tmp_path, capsys):
    pytest.importorskip("pyulog")
    path = px4_log(tmp_path / "flight.ulg")
    whole = path.read_bytes()
    assert main(["extract", f"file={path}", "instance=0", f"out={tmp_path / 'a.csv'}"]) == 0
    assert "warning" not in capsys.readouterr().out
    path.write_bytes(whole[:-7])                # the copy stopped inside the last message
    assert main(["extract", f"file={path}", "instance=0", f"out={tmp_path / 'b.csv'}"]) == 0
    said = capsys.readouterr().out
    assert "warning: flight.ulg ends inside a message (the file is cut" in said


def test_extract_writes_no_inf_and_counts_its_blank_cells(tmp_path, capsys):
    pytest.importorskip("pymavlink")
    path = ardupilot_log(tmp_path / "flight.log", binary=False)
    lines = path.read_text().splitlines()
    k = [k for k, line in enumerate(lines) if line.startswith("CTUN,")][4]   # mid-flight
    lines[k] = lines[k].rsplit(",", 1)[0] + ", inf"
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "x.csv"
    assert main(["extract", f"file={path}", "instance=0", f"out={out}"]) == 0
    said = capsys.readouterr().out
    text = out.read_text()
    assert "inf" not in text.lower()
    table = pd.read_csv(out)
    blanks = {c: int(n) for c, n in table.isna().sum().items() if n}
    assert blanks.get("throttle", 0) >= 1
    counted = ", ".join(f"{c} {n}" for c, n in blanks.items())
    assert f"; no value (outside the stream or in a gap, or not finite in the log): {counted}" \
        in said


def test_a_finished_run_lacking_only_its_figures_resumes_on_a_full_disk(tmp_path, monkeypatch):
    import magbench.engine.sweep as sweep
    from magbench.engine.sweep import run_study
    from magbench.sources.synthetic import Point
    from magbench.studies.review import ReviewStudy

    study = ReviewStudy("full", [Point(K=30)], 2, 1, ["sphere"])
    run_study(study, tmp_path, progress=False)
    monkeypatch.setattr(sweep, "_free_bytes", lambda folder: (10, 10))    # disk and memory full
    run_study(study, tmp_path, progress=False)                            # reused, not refused
    other = ReviewStudy("full", [Point(K=30)], 3, 1, ["sphere"])
    with pytest.raises(sweep.TooLarge):                                   # new work still is
        run_study(other, tmp_path / "other", progress=False)


if sys.platform == "win32":                     # mkfifo and /dev/zero are POSIX
    pytestmark = pytest.mark.skip("POSIX files")
