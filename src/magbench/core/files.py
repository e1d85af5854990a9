"""Atomic file writes: a reader never sees a half-written result.

Every file magbench writes goes to a temporary name beside its destination and is renamed into
place (atomic on POSIX), so a killed run leaves either the old file or the new one.

:func:`exclusive_lock` is the one lock of a folder (a sweep's results folder, ``calibrate``'s
out folder): ``filelock``'s operating-system lock, which dies with its process, so a killed run
blocks nothing. Its file is removed while still held, so a finished folder keeps none; a
contender that opened the file just before is not handed a lock on the removed file
(``filelock`` checks that the locked file still has a name, from 4.0) and tries once more.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import math
import numbers
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["CHUNK_ROWS", "LockHeld", "atomic_path", "csv_cell", "exclusive_lock", "file_sha256",
           "not_a_file", "read_csv_columns", "write_csv_atomic", "write_records_csv",
           "write_rows_csv", "write_text_atomic"]

#: Rows parsed at a time by :func:`read_csv_columns`: the parser's buffers (every column of
#: the chunk, as text and as values) stay at a few hundred MB whatever the file's length.
CHUNK_ROWS = 100_000


def not_a_file(path: Path | str, expected: str) -> str | None:
    """Why ``path`` cannot be read as an input file, as one message, or None if it can.

    A device (``/dev/zero`` never ends), a named pipe (it blocks until a writer comes) or a
    socket is refused by name, not reported as "not found"; ``expected`` says what the
    command reads (e.g. "a CSV of magnetometer samples").
    """
    import stat

    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return f"file {path} not found; expected {expected}"
    except OSError as exc:
        return f"cannot read {path} ({exc.strerror or exc}); expected {expected}"
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return f"file {path} is a folder; expected {expected}"
    kind = ("a named pipe (FIFO)" if stat.S_ISFIFO(mode) else
            "a character device" if stat.S_ISCHR(mode) else
            "a block device" if stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    return f"file {path} is {kind}, not a regular file; expected {expected}"


@contextlib.contextmanager
def atomic_path(path: Path | str) -> Iterator[Path]:
    """A temporary path to write; renamed onto ``path`` when the block ends without error."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


class LockHeld(Exception):
    """Another holder has the lock; ``holder`` is the note it wrote into the lock file."""

    def __init__(self, path: Path, holder: str) -> None:
        super().__init__(f"{path} is held by {holder}")
        self.holder = holder


@contextlib.contextmanager
def exclusive_lock(path: Path | str, note: str = "") -> Iterator[bool]:
    """Hold the exclusive lock of ``path`` for the block, without waiting (module notes).

    Parameters
    ----------
    path : Path or str
        The lock file; created, and removed at the end of the block.
    note : str
        Written into the lock file while held: what a refused contender reports.

    Yields
    ------
    bool
        True; False on a POSIX system without ``fcntl``, where no lock is taken.

    Raises
    ------
    LockHeld
        Another process, or another block of this one, holds the lock.
    """
    path = Path(path)
    if os.name != "nt" and not _has_fcntl():
        yield False
        return
    from filelock import FileLock, Timeout

    # fallback_to_soft=False: a marker file would outlive a killed holder and block the next run.
    lock = FileLock(path, timeout=0, fallback_to_soft=False)
    for attempt in range(2):
        try:
            lock.acquire()
            break
        except Timeout:
            # A second try covers a holder that removed the file and released just as this
            # attempt opened it; a live holder refuses again.
            if attempt:
                try:
                    holder = path.read_text().strip()
                except OSError:
                    holder = ""
                raise LockHeld(path, holder or "another process") from None
    try:
        if note:
            path.write_text(note)
        yield True
    finally:
        with contextlib.suppress(OSError):      # Windows refuses to remove an open file
            path.unlink()
        lock.release()


def _has_fcntl() -> bool:
    try:
        import fcntl  # noqa: F401
    except ImportError:
        return False
    return True


def write_csv_atomic(frame: pd.DataFrame, path: Path | str) -> None:
    """Write ``frame`` as CSV (no index) to ``path`` atomically; ``.gz`` paths are compressed.

    The bytes are those of ``frame.to_csv(path, index=False)``. A frame of plain columns
    (floats, integers, booleans, text) is formatted column by column here, faster than
    ``to_csv`` (a sweep writes every trial row this way); any other goes to ``to_csv``.
    """
    gz = str(path).endswith(".gz")
    cells = None if gz else _csv_columns(frame.iloc[:CHUNK_ROWS])
    if cells is not None:
        # Formatted CHUNK_ROWS rows at a time: a long table's cells as text would take ten
        # times its floats. The first block is the one formatted above (a sweep's part file
        # is often a single block, and formatting it twice was half of its writing).
        blocks = (zip(*(cells if a == 0 else _csv_columns(frame.iloc[a:a + CHUNK_ROWS])),
                      strict=True)
                  for a in range(0, len(frame), CHUNK_ROWS))
        _write_rows(path, [str(c) for c in frame.columns],
                    (row for block in blocks for row in block))
        return
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, compression="gzip" if gz else None)


def _write_rows(path: Path | str, header: Sequence[str], rows: Iterable[Sequence[str]]) -> None:
    """``header`` and ``rows`` (cells already text) as CSV to ``path`` atomically, quoted as
    ``to_csv`` quotes (the csv module's minimal quoting, the system's line ends)."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator=os.linesep)
        writer.writerow(header)
        writer.writerows(rows)


def _csv_columns(frame: pd.DataFrame) -> list[list[str]] | None:
    """Every column's cells as ``to_csv`` writes them (floats by ``repr``, missing values
    empty), or None for a frame this does not cover (no columns, a column index of several
    levels, a column of another kind such as dates or categories)."""
    if frame.shape[1] == 0 or frame.columns.nlevels != 1 or frame.columns.has_duplicates:
        return None
    cells = []
    for i in range(frame.shape[1]):
        column = frame.iloc[:, i]
        code = column.dtype.kind if isinstance(column.dtype, np.dtype) else "?"
        if code == "f" and column.dtype.itemsize == 8:
            cells.append(["" if x != x else repr(x) for x in column.tolist()])
        elif code in "iub":
            cells.append([str(x) for x in column.tolist()])
        elif code == "O" or str(column.dtype) in ("str", "string"):
            missing = column.isna().tolist()
            cells.append(["" if m else csv_cell(x)
                          for x, m in zip(column.tolist(), missing, strict=True)])
        else:
            return None
    return cells


def csv_cell(value: object) -> str:
    """One value as ``pandas.DataFrame.to_csv`` writes it in a column of its type: floats by
    ``repr``, NaN and None empty, booleans ``True``/``False``, integers and text as they are."""
    if value is None:
        return ""
    if isinstance(value, bool | np.bool_):
        return str(bool(value))
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        x = float(value)
        return "" if math.isnan(x) else repr(x)
    return str(value)


def write_records_csv(records: Sequence[Mapping[str, object]], path: Path | str) -> None:
    """Write rows of equal keys as CSV to ``path`` atomically, with the bytes
    ``pandas.DataFrame(records).to_csv(path, index=False)`` writes (each value by
    :func:`csv_cell`; a column holding integers and NaN would be floats there, so such a
    column must hold floats here). Without pandas: ``calibrate`` does not import it."""
    columns = list(records[0]) if records else []
    _write_rows(path, columns, ([csv_cell(r.get(c)) for c in columns] for r in records))


def write_rows_csv(rows: Sequence[Mapping[str, object]], columns: Sequence[str],
                   path: Path | str) -> None:
    """Write ``rows`` (dicts; a missing key is a missing value) as CSV with ``columns``,
    atomically, with the bytes ``write_csv_atomic(pd.DataFrame(rows, columns=columns), path)``
    writes. Each column is formatted here when its values are of one plain kind, as the
    frame's column would be (booleans; integers; floats, integers among them written as
    floats, missing values empty; text, missing values empty); a table with any other column
    goes to the frame. A sweep writes every chunk's rows this way: building the frame was most
    of the cost of a small chunk."""
    columns = list(columns)
    cells = [_plain_column([r.get(c) for r in rows]) for c in columns] if rows else None
    if cells is None or any(c is None for c in cells):
        import pandas as pd

        write_csv_atomic(pd.DataFrame(list(rows), columns=columns), path)
        return
    _write_rows(path, columns, zip(*cells, strict=True))


_INT64 = (-(2 ** 63), 2 ** 63 - 1)


def _plain_column(values: list) -> list[str] | None:
    """The cells of one column as a frame built from these values writes them, or None
    when the values are not of one kind :func:`write_rows_csv` formats (it then builds it)."""
    kinds = set()
    for x in values:
        t = type(x)
        if x is None:
            kinds.add("none")
        elif t is bool or t is np.bool_:
            kinds.add("bool")
        elif t is int or isinstance(x, np.integer):
            kinds.add("int" if _INT64[0] <= int(x) <= _INT64[1] else "other")
        elif t is float or t is np.float64:
            kinds.add("float")
        elif t is str:
            kinds.add("str")
        else:
            kinds.add("other")
    if kinds in ({"bool"}, {"int"}) or kinds <= {"float", "none"} or kinds <= {"str", "none"}:
        return [csv_cell(x) for x in values]
    if kinds <= {"float", "int", "none"}:
        # the frame's column is float: its integers are written as floats
        return [csv_cell(None if x is None else float(x)) for x in values]
    return None


def write_text_atomic(text: str, path: Path | str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def file_sha256(path: Path | str) -> str:
    """Hex SHA-256 of a file's bytes (to check a part file before reusing it)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_csv_columns(path: Path | str, columns: Sequence[str], *,
                     chunk_rows: int | None = None, dtype: dict | None = None) -> pd.DataFrame:
    """Only ``columns`` of a CSV file (plain or gzip-compressed), parsed in chunks.

    What is kept is the requested columns alone; the parser sees ``chunk_rows`` rows at a time,
    so a file of millions of rows is read without ever holding all of its columns. Text
    columns repeat a few values (method names, error messages): each chunk's are stored as
    categories and joined, so a million rows of ``algorithm`` cost 8 MB of references to a
    handful of strings rather than a million strings; they come back in the dtype and with the
    values that one ``pandas.read_csv`` call gives.

    Parameters
    ----------
    path : path
        The CSV file; a name ending in ``.gz`` is decompressed on the fly.
    columns : sequence of str
        Columns to keep; those absent from the file are skipped.
    chunk_rows : int, optional
        Rows parsed per chunk; :data:`CHUNK_ROWS` by default.
    dtype : dict, optional
        ``pandas.read_csv`` dtypes of some columns.

    Returns
    -------
    DataFrame
        The columns, in the file's order, with a default index.
    """
    import pandas as pd
    from pandas.api.types import union_categoricals

    wanted = set(columns)
    parts = []
    with pd.read_csv(path, usecols=lambda c: c in wanted, dtype=dtype,
                     chunksize=chunk_rows or CHUNK_ROWS) as reader:
        for chunk in reader:
            text = chunk.select_dtypes(include=["object", "string"]).columns
            parts.append(chunk.astype({c: "category" for c in text}))
    if not parts:
        return pd.read_csv(path, usecols=lambda c: c in wanted, dtype=dtype)
    out = {}
    for name in parts[0].columns:
        pieces = [p[name] for p in parts]
        text = [p for p in pieces if isinstance(p.dtype, pd.CategoricalDtype)]
        if text and all(isinstance(p.dtype, pd.CategoricalDtype) or p.isna().all()
                        for p in pieces):
            # A chunk where a text column is empty parsed it as float NaN: an empty category.
            kind = text[0].cat.categories.dtype
            empty = pd.Index([], dtype=kind)
            joined = union_categoricals([p if isinstance(p.dtype, pd.CategoricalDtype)
                                         else pd.Categorical([None] * len(p), categories=empty)
                                         for p in pieces])
            out[name] = pd.Series(joined.astype(kind), name=name)
        else:
            out[name] = pd.concat(pieces, ignore_index=True)
    return pd.DataFrame(out)
