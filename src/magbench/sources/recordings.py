"""Real recordings: one folder per recording, or a user's own CSV file.

One folder per recording under a data directory (``$MAGBENCH_DATA`` or the config value
``data_dir``), each with ``data.csv`` (columns ``t, mx, my, mz`` and optionally ``gx, gy, gz``
in rad/s and accelerometer columns), or a user's own CSV with the three axes chosen by name or
position (:func:`read_samples`). Units are kept as recorded. Rows with a missing value in a
used column are dropped with a warning that says how many; everything else that is wrong gives
one ``ValueError`` saying what is wrong, on which line of the file (blank lines counted), and
what is expected. A column naming the sensor (:data:`INSTANCE_COLUMNS`, e.g. the ``I`` of
ArduPilot's MAG messages) with several values is refused unless one is chosen; a time column
``t`` may hold seconds or ISO 8601 timestamps, and one that holds neither is dropped with a
warning (it is optional); decimal commas are read when the columns are separated by ``;``, tab
or spaces, and named when a cell holds one in a comma-separated file. Recordings longer than
``max_samples`` are thinned deterministically to every ``s``-th sample,
``s = ceil(n / max_samples)`` (a uniform stride keeps the time base uniform for the gyro
methods).
"""

from __future__ import annotations

import bz2
import csv
import gzip
import io
import lzma
import math
import os
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from magbench.core.files import not_a_file
from magbench.core.geometry import MIN_COVERAGE, MIN_THICKNESS, check_geometry
from magbench.core.model import check_magnitude
from magbench.core.units import parse_units
from magbench.sources.logs import EXTRA_COLUMNS, MIN_LOG_SAMPLES, is_log, read_log

if TYPE_CHECKING:     # pandas reads the files NumPy cannot (:func:`_plain_table`), on demand
    import pandas as pd

__all__ = [
    "ACC_COLUMNS",
    "ATTITUDE_COLUMNS",
    "DATA_ENV",
    "EXTRA_COLUMNS",
    "GYRO_COLUMNS",
    "INSTANCE_COLUMNS",
    "MAG_COLUMNS",
    "InertialRecording",
    "Recording",
    "data_dir",
    "list_recordings",
    "load_recording",
    "log_recording",
    "read_inertial",
    "read_samples",
    "without_unit",
]

DATA_ENV = "MAGBENCH_DATA"
MAG_COLUMNS = ("mx", "my", "mz")
GYRO_COLUMNS = ("gx", "gy", "gz")
_MISSING = {"", "nan", "na", "n/a", "null", "none"}
#: Columns that name which sensor a row comes from (ArduPilot's MAG ``I``, PX4's ``device_id``).
INSTANCE_COLUMNS = ("I", "instance", "Instance", "inst", "device_id", "sensor_id", "mag_id",
                    "compass")
_DECIMAL_COMMA = re.compile(r"^\s*[-+]?\d+,\d+(?:[eE][-+]?\d+)?\s*$")


def _as_columns(arrays: Sequence[np.ndarray]) -> np.ndarray:
    """Arrays of one length as the columns of one float array, each column contiguous in
    memory (the layout pandas' ``to_numpy`` gave): BLAS and NumPy may sum in another order
    over another layout, and the results must stay the same to the last bit."""
    return np.array([np.asarray(a, dtype=float) for a in arrays]).T


@dataclass(frozen=True)
class Recording:
    """Magnetometer samples of one recording, in the units they were recorded in.

    Attributes
    ----------
    name : str
        Folder or file stem.
    y : ndarray, shape (K, 3)
        Magnetometer samples.
    t : ndarray of shape (K,) or None
        Sample times in seconds, if the file has them.
    gyro : ndarray of shape (K, 3) or None
        Angular rate in rad/s in the magnetometer's axes, if the file has it.
    n_rows : int
        Rows of the file before thinning (after dropping rows with missing values).
    stride : int
        Every ``stride``-th row is kept (1 = all).
    columns : tuple of str
        Names of the magnetometer columns read (``column i`` without a header).
    instance : tuple of (str, str) or None
        The instance column and the value kept, when the file has one.
    extra : dict of str to ndarray, or None
        Other time-aligned columns, one float array of length ``K`` each (those of
        :data:`EXTRA_COLUMNS` the file has, in that order); :meth:`stack` gives several as
        one array.
    """

    name: str
    y: np.ndarray
    t: np.ndarray | None = None
    gyro: np.ndarray | None = None
    n_rows: int = 0
    stride: int = 1
    columns: tuple = MAG_COLUMNS
    instance: tuple[str, str] | None = None
    extra: dict[str, np.ndarray] | None = None

    @property
    def K(self) -> int:
        return int(self.y.shape[0])

    @property
    def has_gyro(self) -> bool:
        return self.gyro is not None and self.t is not None

    def rows(self, index: slice | np.ndarray) -> Recording:
        """The recording restricted to some rows (times and gyro alike)."""
        return replace(self, y=self.y[index],
                       t=None if self.t is None else self.t[index],
                       gyro=None if self.gyro is None else self.gyro[index],
                       extra=None if self.extra is None else
                       {name: values[index] for name, values in self.extra.items()})

    def stack(self, names: Sequence[str]) -> np.ndarray:
        """The ``extra`` columns ``names`` as one float array of shape (K, len(names))."""
        return _as_columns([self.extra[n] for n in names])

    def thinned(self, max_samples: int | None) -> Recording:
        """Every ``s``-th sample, ``s = ceil(K / max_samples)``; unchanged if already small."""
        if not max_samples or self.K <= max_samples:
            return self
        stride = math.ceil(self.K / max_samples)
        return replace(self.rows(slice(None, None, stride)), stride=self.stride * stride)

    def halves(self) -> tuple[Recording, Recording]:
        """First and second half in time (the first gets the smaller half for odd K)."""
        mid = self.K // 2
        return self.rows(slice(0, mid)), self.rows(slice(mid, None))


def data_dir(configured: object = None) -> Path:
    """The folder of real recordings: ``configured`` if given, else ``$MAGBENCH_DATA``.

    Raises
    ------
    ValueError
        If neither names an existing folder.
    """
    value = configured if configured not in (None, "") else os.environ.get(DATA_ENV)
    if not value:
        raise ValueError(f"no data directory: set the environment variable {DATA_ENV} or pass "
                         "data_dir=PATH (a folder with one sub-folder per recording, each "
                         "holding data.csv)")
    path = Path(str(value)).expanduser()
    if not path.is_dir():
        raise ValueError(f"data directory {path} does not exist (from "
                         f"{'data_dir' if configured else DATA_ENV})")
    return path


def list_recordings(root: Path | str) -> list[str]:
    """Recording names under ``root``: INDEX.csv's order if present, else sorted folders."""
    root = Path(root)
    index = root / "INDEX.csv"
    if index.exists():
        import pandas as pd

        names = [str(n) for n in pd.read_csv(index)["name"]]
        return [n for n in names if (root / n / "data.csv").exists()]
    return sorted(p.parent.name for p in root.glob("*/data.csv"))


def load_recording(root: Path | str, name: str, *, min_samples: int = 4,
                   check: bool = True) -> Recording:
    """Load ``<root>/<name>/data.csv`` (columns mx, my, mz; t and gx, gy, gz if present)."""
    path = Path(root) / name / "data.csv"
    if not path.exists():
        known = ", ".join(list_recordings(root)) or "none"
        raise ValueError(f"no recording {name!r} in {root} (expected {path}); recordings "
                         f"there: {known}")
    rec = read_samples(path, list(MAG_COLUMNS), min_samples=min_samples, check=check)
    return replace(rec, name=name)


#: Leading bytes of the compressed formats: those read transparently (Python's own codecs),
#: and those that must be unpacked first.
_MAGIC = {b"\x1f\x8b": "gzip", b"BZh": "bz2", b"\xfd7zXZ\x00": "xz", b"PK\x03\x04": "zip",
          b"\x28\xb5\x2f\xfd": "zstd"}
_READABLE = {"gzip": gzip.open, "bz2": bz2.open, "xz": lzma.open}

#: Rows parsed per chunk: the file is never held as text, only its used columns as floats.
CHUNK_ROWS = 500_000

#: A compressed recording is unpacked to at most this many times its own size (a CSV of
#: numbers packs 2 to 10 times with gzip, bzip2 or xz: more is a "zip bomb") ...
MAX_UNPACK_RATIO = 100
#: ... and to at most MAX_UNPACKED_BYTES whatever its size: a day of a magnetometer at 200 Hz
#: with 16 columns is under 4 GiB of text. Below MIN_UNPACK_CAP the ratio is not applied.
MAX_UNPACKED_BYTES = 4 << 30
MIN_UNPACK_CAP = 64 << 20
#: Longest line a compressed recording may hold (a row of a CSV is under a few hundred bytes;
#: a parser holds a whole line, so this bounds its memory).
MAX_LINE_BYTES = 1 << 20


class _Capped(io.RawIOBase):
    """A decompressing reader that stops, with one message, past its unpacked-size cap, at a
    line longer than :data:`MAX_LINE_BYTES` or at a NUL byte (binary data, not a CSV)."""

    def __init__(self, path: Path, compression: str) -> None:
        super().__init__()
        self.path, self.compression = path, compression
        self.raw = _READABLE[compression](path, "rb")
        packed = path.stat().st_size
        self.limit = min(MAX_UNPACKED_BYTES, max(MIN_UNPACK_CAP, MAX_UNPACK_RATIO * packed))
        self.total = self.line = 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: bytearray | memoryview) -> int:
        n = self.raw.readinto(buffer)
        chunk = bytes(memoryview(buffer)[:n])
        self.total += n
        last = chunk.rfind(b"\n")
        self.line = self.line + n if last < 0 else n - last - 1
        if self.total > self.limit:
            raise ValueError(f"{self.path.name} unpacks ({self.compression}) to more than "
                             f"{self.limit / 2**20:.0f} MiB ({MAX_UNPACK_RATIO} times its size, "
                             f"at most {MAX_UNPACKED_BYTES >> 30} GiB): not a recording; "
                             "unpack and check it")
        if self.line > MAX_LINE_BYTES or b"\0" in chunk:
            raise ValueError(f"{self.path.name} unpacks ({self.compression}) to "
                             + ("NUL bytes" if b"\0" in chunk else
                                f"a line longer than {MAX_LINE_BYTES >> 20} MiB")
                             + ": binary data, not a CSV of magnetometer samples")
        return n

    def close(self) -> None:
        self.raw.close()
        super().close()


def _open_binary(path: Path, compression: str | None) -> io.BufferedIOBase:
    """``path`` opened for reading bytes, decompressed (and capped, :class:`_Capped`)."""
    if not compression:
        return open(path, "rb")
    return io.BufferedReader(_Capped(path, compression))


def _open_text(path: Path, compression: str | None) -> io.TextIOBase:
    """``path`` opened as text (universal newlines off), decompressed and capped."""
    return io.TextIOWrapper(_open_binary(path, compression), encoding="utf-8", newline="")


def _compression(path: Path) -> str | None:
    """The compression of ``path`` from its first bytes (None for plain text).

    Raises
    ------
    ValueError
        For a compressed format Python cannot read on its own (zip, zstd).
    """
    with open(path, "rb") as handle:
        head = handle.read(8)
    kind = next((k for magic, k in _MAGIC.items() if head.startswith(magic)), None)
    if kind is not None and kind not in _READABLE:
        raise ValueError(f"{path} is compressed input ({kind}): unpack it first, then pass the "
                         "CSV file")
    return kind


def _fields(line: str, sep: str) -> list[str]:
    """The fields of one line, quotes respected (a quoted "1,5" is one field)."""
    return line.split() if sep == " " else next(csv.reader([line], delimiter=sep), [])


def _is_number(text: str, decimal_comma: bool = False) -> bool:
    text = text.strip().strip('"')
    if decimal_comma:
        text = text.replace(",", ".")
    try:
        float(text)
    except ValueError:
        return text.lower() in _MISSING
    return True


def _head_lines(path: Path, compression: str | None) -> list[tuple[int, str]]:
    """The non-blank lines of the first 8 KiB with their line numbers (a cut last line
    dropped)."""
    try:
        with _open_text(path, compression) as handle:
            head = handle.read(8192)
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not a text file (bytes that are not UTF-8 at its start); "
                         "expected a CSV of magnetometer samples") from None
    except (OSError, EOFError) as exc:
        raise ValueError(f"cannot read {path} ({compression or 'plain'}): {exc}") from None
    if "\0" in head:
        raise ValueError(f"{path.name} holds NUL bytes: binary data, not a CSV of magnetometer "
                         "samples")
    lines = head.splitlines()
    if len(head) == 8192 and len(lines) > 1:
        lines = lines[:-1]
    return [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]


def _sniff(path: Path, compression: str | None = None) -> dict:
    """Delimiter, header, number of columns and decimal mark of ``path``, from its start.

    Returns a dict with ``sep``, ``has_header``, ``n_cols`` (the most fields of a data row),
    ``decimal`` and ``skip`` (the lines before the first one that is not a '#' note).

    Raises
    ------
    ValueError
        An empty or binary file, or a header that names fewer columns than a row holds.
    """
    lines = _head_lines(path, compression)
    # Leading '#' lines are a logger's notes (device, date): skipped, as pandas' skiprows.
    notes = next((k for k, (_, ln) in enumerate(lines) if not ln.lstrip().startswith("#")),
                 len(lines))
    skip = lines[notes][0] - 1 if notes < len(lines) else 0
    lines = lines[notes:]
    if not lines:
        raise ValueError(f"{path} is empty; expected a CSV with one magnetometer sample per row")
    texts = [ln for _, ln in lines]
    try:
        sep = csv.Sniffer().sniff("\n".join(texts[:20]), delimiters=",;\t ").delimiter
    except csv.Error:
        sep = ","
    if all(len(_fields(ln, sep)) == 1 for ln in texts[:20]):
        # Rows of unequal length defeat the sniffer: take the delimiter that splits most rows.
        sep = max(",;\t ", key=lambda d: sum(len(_fields(ln, d)) > 1 for ln in texts[:20]))
    comma = sep != "," and any(_DECIMAL_COMMA.match(f) for ln in texts[1:21]
                               for f in _fields(ln, sep))
    first = [f.strip().strip('"') for f in _fields(texts[0], sep)]
    has_header = not all(_is_number(f, comma) for f in first)
    data = lines[1:] if has_header and len(lines) > 1 else lines
    n_cols = max(len(_fields(ln, sep)) for _, ln in data)
    width = len(_fields(data[0][1], sep))
    longer = next(((i, n) for i, ln in data if (n := len(_fields(ln, sep))) > width), None)
    if longer is not None and not has_header:
        raise ValueError(f"{path.name}: line {longer[0]} has {longer[1]} fields where the rows "
                         f"before have {width}; every row must hold the same columns")
    if has_header and len(first) < n_cols:
        line = next(i for i, ln in data if len(_fields(ln, sep)) == n_cols)
        raise ValueError(f"{path.name}: the header names {len(first)} columns but line {line} "
                         f"has {n_cols} fields; name every column, or remove the header and "
                         "choose the columns by position (columns=[0,1,2])")
    return {"sep": sep, "has_header": has_header, "n_cols": n_cols,
            "decimal": "," if comma else ".", "skip": skip}


def _line_of(path: Path, compression: str | None, has_header: bool, row: int,
             skip: int = 0) -> int:
    """The line number of data row ``row`` (0-based), counting blank lines as the file does
    (pandas skips them, so its row index alone is short by one per blank line) and the
    ``skip`` lines of notes before the table."""
    seen = -1 if has_header else 0
    with _open_text(path, compression) as handle:
        for number, line in enumerate(handle, start=1):
            if number <= skip or not line.strip():
                continue
            if seen == row:
                return number
            seen += 1
    return number


def _ragged(path: Path, compression: str | None, sep: str, n_cols: int, skip: int = 0) -> str:
    """The first line with more fields than ``n_cols`` (after ``skip`` lines of notes), as
    one message."""
    with _open_text(path, compression) as handle:
        for number, line in enumerate(handle, start=1):
            n = len(_fields(line.rstrip("\r\n"), sep))
            if number > skip and line.strip() and n > n_cols:
                return (f"{path.name}: line {number} has {n} fields where the rows before have "
                        f"{n_cols}; every row must hold the same columns")
    return f"{path.name}: rows of unequal length; every row must hold the same columns"


def _select(columns: Sequence[object] | None, header: list[str] | None, n_cols: int,
            what: str, default: Sequence[str] | None) -> list[int] | None:
    """Positions of the chosen columns (names or 0-based positions), or None if absent."""
    if columns is None:
        if header is not None and default and all(c in header for c in default):
            return [header.index(c) for c in default]
        return None
    columns = list(columns)
    if len(columns) != 3:
        raise ValueError(f"{what} must name exactly 3 columns, got {len(columns)}: {columns}")
    if all(isinstance(c, int | np.integer) and not isinstance(c, bool) for c in columns):
        bad = [c for c in columns if not 0 <= c < n_cols]
        if bad:
            raise ValueError(f"{what} positions {bad} are out of range; the file has {n_cols} "
                             f"columns (positions 0 to {n_cols - 1})")
        return [int(c) for c in columns]
    if all(isinstance(c, str) for c in columns):
        if header is None:
            raise ValueError(f"the file has no header row, so {what} cannot be chosen by name "
                             f"({', '.join(columns)}); choose them by position, e.g. "
                             "columns=[0,1,2]")
        missing = [c for c in columns if c not in header]
        if missing:
            raise ValueError(f"missing column(s) {', '.join(map(repr, missing))}; the file has "
                             f"columns {', '.join(header)}; choose three by name, e.g. "
                             f"columns=[{','.join(header[:3])}], or by position, e.g. "
                             "columns=[0,1,2]")
        return [header.index(c) for c in columns]
    raise ValueError(f"{what} must be three column names or three 0-based positions, got "
                     f"{columns}")


class _Where:
    """How to name a data row's line in a message (only looked up on an error)."""

    def __init__(self, path: Path, compression: str | None, sniffed: dict) -> None:
        self.path, self.compression, self.sniffed = path, compression, sniffed

    def line(self, row: int) -> int:
        return _line_of(self.path, self.compression, self.sniffed["has_header"], row,
                        self.sniffed["skip"])

    def ragged(self) -> str:
        return _ragged(self.path, self.compression, self.sniffed["sep"],
                       self.sniffed["n_cols"], self.sniffed["skip"])

    def unclosed_quote(self) -> str:
        """Where a quoted field opens and never closes (the first line with an odd number of
        double quotes)."""
        with _open_text(self.path, self.compression) as handle:
            line = next((n for n, text in enumerate(handle, start=1) if text.count('"') % 2),
                        None)
        at = f" on line {line}" if line else ""
        return (f"{self.path.name}: a quoted field opens{at} and is never closed; remove the "
                'stray " or close the quote')


def _numeric(table: pd.DataFrame, position: int, name: str, where: _Where,
             row0: int = 0) -> np.ndarray:
    """One column as floats; missing cells become NaN, other text is an error naming the cell
    (``table`` starts at data row ``row0`` of the file).
    """
    import pandas as pd

    text = table.iloc[:, position].astype(str).str.strip()
    missing = text.str.lower().isin(_MISSING)
    values = pd.to_numeric(text.where(~missing), errors="coerce")
    bad = np.flatnonzero(values.isna().to_numpy() & ~missing.to_numpy())
    if bad.size:
        row = row0 + int(bad[0])
        cell = text.iloc[row - row0]
        hint = ("; it looks like a decimal comma: save the file with '.' as the decimal mark, "
                "or separate the columns with ';'" if _DECIMAL_COMMA.match(cell) else
                "; expected numbers (missing values may be empty or NaN)")
        raise ValueError(f"non-numeric value {_clip(cell)} in column {name!r} at data row "
                         f"{row + 1} "
                         f"(line {where.line(row)} of the file)"
                         + (f" and {bad.size - 1} more cell(s)" if bad.size > 1 else "") + hint)
    return values.to_numpy(dtype=float)


#: Missing-value spellings as the C parser needs them (it matches exactly, after no strip).
_NA_TOKENS = sorted({v for w in _MISSING for v in (w, w.upper(), w.capitalize())})


def _read_csv(path: Path, **kwargs: object) -> pd.DataFrame:
    """``pandas.read_csv`` with its parse errors as one ``ValueError`` naming the file."""
    import pandas as pd

    try:
        if kwargs.get("compression"):       # unpacked here, within the caps
            with _open_binary(path, str(kwargs["compression"])) as handle:
                return pd.read_csv(handle, **{**kwargs, "compression": None})
        return pd.read_csv(path, **kwargs)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, EOFError,
            OSError) as exc:
        raise ValueError(f"cannot read {path} as CSV: {' '.join(str(exc).split())}") from None


def _quiet(reader: Iterator[pd.DataFrame]) -> Iterator[pd.DataFrame]:
    """The chunks, without pandas' mixed-type warning (such a column is checked cell by cell)."""
    import pandas as pd

    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", pd.errors.DtypeWarning)
            chunk = next(reader, None)
        if chunk is None:
            return
        yield chunk


def _read_columns(path: Path, layout: dict, wanted: dict[int, str], where: _Where,
                  optional: Sequence[int] = (), first: Sequence[int] = ()
                  ) -> tuple[np.ndarray, np.ndarray, set[int]]:
    """The columns at the positions in ``wanted`` (position -> name) as floats, in two
    arrays: those in ``first`` in that order (shape (rows, len(first)), duplicates once), and
    the others in the order of their positions; and the ``optional`` positions that held text
    (NaN in the table; the caller decides what they mean).

    Read in chunks of :data:`CHUNK_ROWS` rows by pandas' C parser, keeping only those columns,
    so memory follows the floats kept (24 bytes a row for three axes), never the file's text:
    10 million rows once took 4.5 GB as Python strings. The samples (``first``) are parsed
    straight into their own array, so they are never copied out of a wider table that holds
    them a second time. A chunk whose column the parser could not turn into numbers (text,
    padded spaces) goes through :func:`_numeric`, which accepts what the text reader accepts
    and names the first bad cell. A small file of plain numbers is read by NumPy instead
    (:func:`_plain_table`), which gives the same values without importing pandas (whose import
    ``calibrate`` avoids).
    """
    firsts = list(dict.fromkeys(first))
    others = [p for p in sorted(wanted) if p not in firsts]
    plain = _plain_table(path, layout, where.sniffed)
    if plain is not None:                # laid out as the pandas path's arrays below
        return (np.ascontiguousarray(plain[:, firsts]), np.ascontiguousarray(plain[:, others]),
                set())
    import pandas as pd

    chunks: list[tuple[np.ndarray, np.ndarray]] = []
    failed: set[int] = set()
    # A plain file's line count bounds its rows: fill the arrays instead of concatenating
    # chunks, which would hold every sample twice at the end.
    tables = None
    if not layout.get("compression"):
        n = _count_lines(path)
        tables = (np.empty((n, len(firsts))), np.empty((n, len(others))))
    place = {p: (0, firsts.index(p)) if p in firsts else (1, others.index(p)) for p in wanted}
    try:
        compression = layout.get("compression")
        with _open_binary(path, compression) as source, pd.read_csv(
                source, usecols=sorted(wanted), chunksize=CHUNK_ROWS, engine="c",
                na_values=_NA_TOKENS, keep_default_na=False,
                **{**layout, "compression": None}) as reader:
            offset = _fill(_quiet(reader), tables, chunks, wanted, place, where, optional,
                           failed)

    except pd.errors.ParserError as exc:
        if "Expected" in str(exc) and "fields" in str(exc):
            raise ValueError(where.ragged()) from None
        if "EOF inside string" in str(exc):
            raise ValueError(where.unclosed_quote()) from None
        raise ValueError(f"cannot read {path} as CSV: {' '.join(str(exc).split())}") from None
    except (UnicodeDecodeError, EOFError, OSError) as exc:
        raise ValueError(f"cannot read {path} as CSV: {' '.join(str(exc).split())}") from None
    if tables is not None:
        return tables[0][:offset], tables[1][:offset], failed
    if len(chunks) == 1:
        return chunks[0][0], chunks[0][1], failed
    if not chunks:
        return np.empty((0, len(firsts))), np.empty((0, len(others))), failed
    return (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
            failed)


#: Largest file :func:`_plain_table` reads (it holds the text and every column at once).
PLAIN_MAX_BYTES = 32 << 20
#: Letters a plain table's data may hold: exponents, and the NaN spellings pandas reads as
#: missing values (any other word, ``inf`` or ``NA`` included, leaves the file to pandas).
_PLAIN_WORDS = {"e", "E", "nan", "NaN", "NAN", "Nan"}


def _plain_layout(layout: dict, sniffed: dict) -> bool:
    """An uncompressed file with no notes before its table and a one-character separator:
    the layout whose header and numbers are read without pandas."""
    return not layout["compression"] and not sniffed["skip"] and sniffed["sep"] in ",;\t"


def _plain_table(path: Path, layout: dict, sniffed: dict) -> np.ndarray | None:
    """Every column of a small, plain file of numbers as floats (rows, columns), read by
    NumPy; None when the file is anything else, which pandas then reads (and names what is
    wrong).

    Only what both parsers read alike is taken: an uncompressed ASCII file at most
    :data:`PLAIN_MAX_BYTES` long, one-character separator, '.' decimals, no notes or blank
    lines before the table, no quotes, every cell a finite number or a NaN spelling pandas
    treats as missing, every row as wide as the header. Both round decimal text correctly,
    so the values are the same; NaN cells are dropped later either way.
    """
    if (not _plain_layout(layout, sniffed) or layout["decimal"] != "."
            or path.stat().st_size > PLAIN_MAX_BYTES):
        return None
    with open(path, newline="") as handle:
        try:
            text = handle.read()
        except UnicodeDecodeError:
            return None
    text = text.replace("\r\n", "\n")
    head, _, data = text.partition("\n") if sniffed["has_header"] else ("", "", text)
    if (not text.isascii() or "\r" in text or '"' in text
            or re.search(r"[+-]\s*[A-Za-z]", data)
            or not set(re.findall(r"[A-Za-z]+", data)) <= _PLAIN_WORDS):
        return None
    if not data.strip():                # no rows: pandas says so
        return None
    try:
        table = np.loadtxt(io.StringIO(data), delimiter=sniffed["sep"], comments=None,
                           dtype=float, ndmin=2)
    except ValueError:                  # blank-looking lines, empty cells, ragged rows
        return None
    width = len(head.split(sniffed["sep"])) if head else sniffed["n_cols"]
    if table.shape[1] != width or np.isinf(table).any():
        return None
    return table


def _fill(reader: Iterator[pd.DataFrame], tables: tuple[np.ndarray, np.ndarray] | None,
          chunks: list[tuple[np.ndarray, np.ndarray]], wanted: dict[int, str],
          place: dict[int, tuple[int, int]], where: _Where, optional: Sequence[int],
          failed: set[int]) -> int:
    """Parse each chunk into ``tables`` (or append it to ``chunks``), the column at position
    ``p`` into column ``place[p][1]`` of array ``place[p][0]``; returns the rows read."""
    import pandas as pd

    positions = sorted(wanted)
    widths = [sum(1 for w, _ in place.values() if w == k) for k in (0, 1)]
    offset = 0
    for chunk in reader:
        blocks = (tuple(np.empty((len(chunk), w)) for w in widths) if tables is None else
                  tuple(t[offset:offset + len(chunk)] for t in tables))
        for j, p in enumerate(positions):
            column = chunk.iloc[:, j]
            target = blocks[place[p][0]][:, place[p][1]]
            if pd.api.types.is_numeric_dtype(column) and \
                    not pd.api.types.is_bool_dtype(column):
                target[:] = column.to_numpy(dtype=float)
            elif p in optional:
                try:
                    target[:] = _numeric(chunk, j, wanted[p], where, offset)
                except ValueError:
                    target[:] = np.nan
                    failed.add(p)
            else:
                target[:] = _numeric(chunk, j, wanted[p], where, offset)
        if tables is None:
            chunks.append(blocks)
        offset += len(chunk)
    return offset


def _text_column(path: Path, layout: dict, position: int) -> pd.Series:
    """One column as stripped text (the instance column; a time column that is not numbers)."""
    column = _read_csv(path, usecols=[position], dtype=str, keep_default_na=False,
                       **layout).iloc[:, 0]
    return column.str.strip().str.strip('"')


def _count_lines(path: Path) -> int:
    """Line breaks in ``path`` plus one (an upper bound on its data rows)."""
    n = 1
    with open(path, "rb") as handle:
        while block := handle.read(1 << 20):
            n += block.count(b"\n")
    return n


def _extra_columns(values: dict[int, np.ndarray], positions: dict[int, str],
                   used: slice | np.ndarray) -> dict[str, np.ndarray] | None:
    """The :data:`EXTRA_COLUMNS` read (``positions``: position -> name) on the rows kept, in
    that order; None when the file has none."""
    if not positions:
        return None
    by_name = {name: values[p][used] for p, name in positions.items()}
    return {c: by_name[c] for c in EXTRA_COLUMNS if c in by_name}


#: The geometry check of a longer recording looks at an even stride of this many samples: the
#: spread and the coverage of 10 million samples are those of any 100 000 evenly spread ones,
#: at a hundredth of the time and memory.
GEOMETRY_SAMPLES = 100_000


def read_samples(path: Path | str, columns: Sequence[object] | None = None, *,
                 min_samples: int = 4, check: bool = True,
                 min_coverage: float = MIN_COVERAGE,
                 min_thickness: float = MIN_THICKNESS,
                 instance: object = None) -> Recording:
    """Read magnetometer samples from a CSV file (delimiter, header and decimal mark detected).

    Parameters
    ----------
    path : path
        The file. A header row is optional; without one, choose columns by position. A file
        compressed with gzip, bzip2 or xz is read as it is (recognised by its first bytes).
    columns : three names or three 0-based positions, optional
        The magnetometer axes. Default: ``mx, my, mz`` if the header has them, else the three
        columns of a three-column file.
    min_samples : int
        Fewest usable rows accepted (the chosen method's need).
    check : bool
        Also reject nearly coplanar samples and samples covering too little of the sphere
        (:func:`check_geometry`).
    instance : str or number, optional
        The rows to keep when the header has an instance column (:data:`INSTANCE_COLUMNS`),
        compared as text or as numbers (``1`` matches ``1.0``); for a flight log (a ``.ulg``,
        ``.bin`` or ``.log`` file, :mod:`magbench.sources.logs`), the compass number, needed
        when it has several.

    Returns
    -------
    Recording
        Units as recorded; ``t`` if the header has a ``t`` column of seconds or ISO 8601 times
        (in seconds from the first), ``gyro`` if it has ``gx, gy, gz`` (rad/s) as well.

    Raises
    ------
    ValueError
        Missing file or columns, non-numeric cells (with row, line and column), rows of unequal
        length, several sensors in an instance column and none chosen, too few samples,
        magnitudes no fit can square (:func:`magbench.core.model.check_magnitude`), zip or
        zstd input (to unpack first), or bad geometry; one message each.

    Warns
    -----
    UserWarning
        When rows with missing values are dropped (how many), or a ``t`` column that holds
        neither seconds nor ISO 8601 times is left out.
    """
    path = Path(path)
    if is_log(path):          # .ulg, .bin, .log: magbench.sources.logs
        return log_recording(path, instance, min_samples=min_samples, check=check,
                             min_coverage=min_coverage, min_thickness=min_thickness)
    problem = not_a_file(path, "a CSV of magnetometer samples")
    if problem:
        raise ValueError(problem)
    layout, where, header, n_cols = _open_csv(path)
    mag, names = _magnetometer_columns(columns, header, n_cols)
    t_pos = _time_column(header)
    gyro_pos = _select(None, header, n_cols, "gyro columns", GYRO_COLUMNS)
    wanted = {**dict(zip(mag, names, strict=True)),
              **({} if t_pos is None else {t_pos: "t"}),
              **({} if gyro_pos is None or t_pos is None else
                 dict(zip(gyro_pos, GYRO_COLUMNS, strict=True)))}
    # Attitude, accelerometer, current, ... ride along (Recording.extra); text there is NaN.
    extra_pos = {header.index(c): c for c in EXTRA_COLUMNS
                 if header and c in header and header.index(c) not in wanted}
    wanted |= extra_pos
    # The samples come in their own array (no copy of 10 million rows out of a wider
    # table); the other columns are views of a second one.
    y, rest, failed = _read_columns(
        path, layout, wanted, where,
        optional=(() if t_pos is None else (t_pos,)) + tuple(extra_pos), first=mag)
    keep, chosen = _instance_rows(path, layout, header, instance, y.shape[0])
    if keep is not None:
        y, rest = y[keep], rest[keep]
    firsts = list(dict.fromkeys(mag))
    values = {p: y[:, firsts.index(p)] for p in firsts} | {
        p: rest[:, j] for j, p in enumerate(p for p in sorted(wanted) if p not in firsts)}
    if len(firsts) < len(mag):          # a column named twice
        y = y[:, [firsts.index(i) for i in mag]]
    t = None
    if t_pos is not None:
        # its own array when others ride along (gyro, attitude): a view would keep them
        # all alive beside their own copies for as long as the recording
        t = np.ascontiguousarray(values[t_pos])
        if t_pos in failed:
            t = _times(path, layout, t_pos, where, keep, gyro_pos is not None)
        if t is not None and np.isnan(t).all():
            t = None
    gyro = (np.column_stack([values[i] for i in gyro_pos])
            if gyro_pos is not None and t is not None else None)
    used = _usable_rows(path, y, t, gyro)
    y = _checked_samples(path, y[used], min_samples)
    rec = Recording(path.parent.name if path.name == "data.csv" else path.stem, y,
                    None if t is None else t[used], None if gyro is None else gyro[used],
                    n_rows=int(y.shape[0]), columns=tuple(names), instance=chosen,
                    extra=_extra_columns(values, extra_pos, used))
    if check:
        stride = math.ceil(rec.K / GEOMETRY_SAMPLES)
        check_geometry(rec.y[::stride], min_coverage=min_coverage,
                       min_thickness=min_thickness, what=path.name)
    return rec


def _open_csv(path: Path) -> tuple[dict, _Where, list[str] | None, int]:
    """How to read ``path`` (pandas' layout arguments), where its lines are, its header (or
    None) and its number of columns."""
    compression = _compression(path)
    sniffed = _sniff(path, compression)
    sep, has_header = sniffed["sep"], sniffed["has_header"]
    layout = {"sep": r"\s+" if sep == " " else sep, "header": 0 if has_header else None,
              "compression": compression, "skip_blank_lines": True,
              "decimal": sniffed["decimal"], "skiprows": sniffed["skip"]}
    header = _plain_header(path, layout, sniffed) if has_header else None
    if has_header and header is None:
        first = _read_csv(path, nrows=0, dtype=str, keep_default_na=False, **layout)
        header = [str(c).strip() for c in first.columns]
    return layout, _Where(path, compression, sniffed), header, sniffed["n_cols"]


def _plain_header(path: Path, layout: dict, sniffed: dict) -> list[str] | None:
    """The header of an uncompressed file whose first line is a plain one (one-character
    separator, no quotes, distinct names that are not blank), read without pandas; None
    otherwise (pandas then reads it, renaming duplicates and blanks its own way)."""
    if not _plain_layout(layout, sniffed):
        return None
    with open(path, newline="") as handle:
        try:
            line = handle.readline().rstrip("\r\n")
        except UnicodeDecodeError:
            return None
    names = line.split(sniffed["sep"])
    stripped = [n.strip() for n in names]
    if not line.isascii() or '"' in line or len(set(names)) < len(names) or not all(stripped):
        return None
    return stripped


#: Other common spellings of the magnetometer axes, matched without regard to case.
MAG_ALIASES = (("x", "y", "z"), ("magx", "magy", "magz"), ("mag_x", "mag_y", "mag_z"),
               ("mag.x", "mag.y", "mag.z"), ("bx", "by", "bz"))


#: A unit after a column's name, ``(uT)`` or ``[nT]``: not part of the name.
_UNIT_SUFFIX = re.compile(r"\s*[(\[][^()\[\]]*[)\]]\s*$")
#: Words of which a magnetometer column's name holds one (beside its axis letter).
MAGNETIC_WORDS = ("mag", "field", "compass")


def _magnetic_unit(name: str) -> bool:
    """Whether ``name`` carries no unit suffix, or one of a magnetic field or of counts (a
    column ``x (m)`` holds a position, not a field)."""
    found = _UNIT_SUFFIX.search(name.strip().strip('"'))
    if found is None:
        return True
    unit = found.group(0).strip()[1:-1].strip().replace("\u03bc", "u").replace("\u00b5", "u")
    if unit.lower() in ("counts", "count", "lsb", "raw", "adc"):
        return True
    try:
        return parse_units(unit).known
    except ValueError:
        return False


def without_unit(name: str) -> tuple[str, bool]:
    """``name`` without a unit suffix (``"Magnetic field x (µT)"`` -> ``"Magnetic field x"``),
    and whether it had one; quotes about the name are dropped with the unit."""
    bare = name.strip().strip('"')
    found = _UNIT_SUFFIX.search(bare)
    if found is None:
        return name, False
    return bare[:found.start()], True


def _bare_name(name: str) -> str:
    """``name`` lower case without its unit suffix, quotes, spaces or punctuation
    (``"Magnetic field x (µT)"`` -> ``magneticfieldx``); ``""`` when its unit is not a
    magnetic one (:func:`_magnetic_unit`), so that it matches no magnetometer name."""
    if not _magnetic_unit(name):
        return ""
    return re.sub(r"[^0-9a-z]", "", without_unit(name)[0].lower())


def _axis_triple(names: list[str]) -> list[int] | None:
    """The x, y, z columns of the one family of names that differ only in their axis letter
    and name a magnetic quantity (:data:`MAGNETIC_WORDS`), or None (none, or several)."""
    families: dict[str, dict[str, list[int]]] = {}
    for i, name in enumerate(names):
        for j, letter in enumerate(name):
            if letter in "xyz":
                family = families.setdefault(name[:j] + "?" + name[j + 1:], {})
                family.setdefault(letter, []).append(i)
    found = {tuple(f[a][0] for a in "xyz") for key, f in families.items()
             if all(len(f.get(a, ())) == 1 for a in "xyz")
             and any(word in key for word in MAGNETIC_WORDS)}
    return list(found.pop()) if len(found) == 1 else None


def _named_axes(header: list[str]) -> list[int] | None:
    """The positions of the magnetometer axes named in ``header``, or None: one spelling of
    :data:`MAG_ALIASES` (matched as written, then without units, spaces and punctuation),
    else the one family of names that differ only in their axis letter and name a magnetic
    quantity (phones' apps: ``Magnetic field x (µT)``, ``MAGNETIC FIELD X (μT)``)."""
    lower = [h.strip().lower() for h in header]
    bare = [_bare_name(h) for h in header]
    for spelt, alias in [(lower, a) for a in MAG_ALIASES] + \
            [(bare, tuple(_bare_name(n) for n in a)) for a in MAG_ALIASES]:
        if all(spelt.count(n) == 1 for n in alias):
            return [spelt.index(n) for n in alias]
    return _axis_triple(bare)


#: A column of seconds named with its unit: ``Time (s)``, ``t [s]``.
_SECONDS = re.compile(r"(?i)\s*\"?(t|time)\s*[(\[]\s*s\s*[)\]]\"?\s*")


def _time_column(header: list[str] | None) -> int | None:
    """The position of the ``t`` column, else of the one column named as seconds
    (:data:`_SECONDS`), or None."""
    if header is None:
        return None
    if "t" in header:
        return header.index("t")
    seconds = [i for i, h in enumerate(header) if _SECONDS.fullmatch(h)]
    return seconds[0] if len(seconds) == 1 else None


def _clip(text: str, limit: int = 60, quote: bool = True) -> str:
    """``text`` for a one-line message: its repr (or itself), cut at ``limit`` characters."""
    shown = repr(text[:limit]) if quote else text[:limit]
    return shown + (f"... ({len(text)} characters)" if len(text) > limit else "")


def _magnetometer_columns(columns: Sequence[object] | None, header: list[str] | None,
                          n_cols: int) -> tuple[list[int], list[str]]:
    """The positions and names of the three magnetometer columns."""
    mag = _select(columns, header, n_cols, "columns", MAG_COLUMNS)
    if mag is None and columns is None and header:
        mag = _named_axes(header)
    if mag is None:
        if n_cols != 3:
            shown = _clip(", ".join(header), quote=False) if header else f"{n_cols} unnamed columns"
            raise ValueError(f"cannot tell which columns hold the magnetometer axes: no mx, my, "
                             f"mz header and {n_cols} columns ({shown}); choose them with "
                             "columns=[name,name,name] or columns=[0,1,2]")
        mag = [0, 1, 2]
    return mag, [header[i] if header else f"column {i}" for i in mag]


def _usable_rows(path: Path, y: np.ndarray, t: np.ndarray | None,
                 gyro: np.ndarray | None) -> np.ndarray | slice:
    """The rows with every used value present (a warning says how many are dropped); a slice
    of all rows when none is, so the samples stay a view."""
    used = ~np.isnan(y).any(axis=1)
    if gyro is not None:
        used &= ~np.isnan(gyro).any(axis=1) & ~np.isnan(t)
    n_dropped = int((~used).sum())
    if not n_dropped:
        return slice(None)
    warnings.warn(f"{path.name}: dropped {n_dropped} of {len(y)} rows with missing or "
                  "NaN values in the columns used", UserWarning, stacklevel=3)
    return used


def _checked_samples(path: Path, y: np.ndarray, min_samples: int) -> np.ndarray:
    """``y`` if its values are finite, of a magnitude a fit can square, and enough."""
    if not np.isfinite(y).all():
        raise ValueError(f"{path.name} contains infinite values; expected finite numbers")
    check_magnitude(y, f"the samples of {path.name}")
    if y.shape[0] < min_samples:
        raise ValueError(f"{path.name} has {y.shape[0]} usable samples; at least {min_samples} "
                         "are needed (the method's number of unknowns)")
    return y


def _same(a: str, b: str) -> bool:
    """Equal as text, or as numbers (``1`` and ``1.0``)."""
    if a == b:
        return True
    try:
        return float(a) == float(b)
    except ValueError:
        return False


def _instance_rows(path: Path, layout: dict, header: list[str] | None, instance: object,
                   n_rows: int) -> tuple[np.ndarray | None, tuple[str, str] | None]:
    """The rows of the chosen sensor (None: all) and (column, value) when there is a column.

    Raises
    ------
    ValueError
        Several sensors and none chosen (naming them and the ``instance`` key), a chosen one
        that is not in the column, or ``instance`` without an instance column.
    """
    column = next((c for c in INSTANCE_COLUMNS if header and c in header), None)
    wanted = None if instance is None else str(instance).strip()
    if column is None:
        if wanted is not None:
            raise ValueError(f"instance={wanted} was given but {path.name} has no instance "
                             f"column (one of {', '.join(INSTANCE_COLUMNS)})")
        return None, None
    cells = _text_column(path, layout, header.index(column))
    counts = cells.value_counts(sort=False)
    seen = ", ".join(f"{v} ({n} rows)" for v, n in counts.items())
    if wanted is None:
        if len(counts) > 1:
            raise ValueError(f"{path.name} holds {len(counts)} sensors in column {column!r}: "
                             f"{seen}; choose one with instance=, e.g. "
                             f"instance={counts.index[0]}")
        return None, (column, str(counts.index[0]) if len(counts) else "")
    match = [v for v in counts.index if _same(str(v), wanted)]
    if not match:
        raise ValueError(f"instance={wanted} is not in column {column!r} of {path.name}; it "
                         f"holds {seen}")
    keep = cells.isin(match).to_numpy()
    return keep[:n_rows], (column, str(match[0]))


def _times(path: Path, layout: dict, position: int, where: _Where, keep: np.ndarray | None,
           has_gyro: bool) -> np.ndarray | None:
    """A ``t`` column that is not numbers: ISO 8601 times as seconds from the first, or None
    with a warning."""
    import pandas as pd

    text = _text_column(path, layout, position)
    if keep is not None:
        text = text[keep]
    missing = text.str.lower().isin(_MISSING)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stamps = pd.to_datetime(text.where(~missing), format="ISO8601", errors="coerce",
                                utc=True)
    bad = np.flatnonzero(stamps.isna().to_numpy() & ~missing.to_numpy())
    if not bad.size and stamps.notna().any():
        seconds = (stamps - stamps.dropna().iloc[0]).dt.total_seconds()
        return seconds.to_numpy(dtype=float)
    row = int(bad[0]) if bad.size else 0
    line = where.line(row) if keep is None else None
    at = f" on line {line}" if line else ""
    warnings.warn(f"{path.name}: column 't' holds neither seconds nor ISO 8601 times (e.g. "
                  f"{text.iloc[row]!r}{at}); reading without times"
                  + (", so the gyro columns are not used" if has_gyro else ""),
                  UserWarning, stacklevel=3)
    return None


ACC_COLUMNS = ("ax", "ay", "az")
ATTITUDE_COLUMNS = ("qw", "qx", "qy", "qz")


@dataclass(frozen=True)
class InertialRecording:
    """A recording with its inertial streams and reference attitude, every row kept.

    Attributes
    ----------
    name : str
        Folder or file stem.
    t : ndarray, shape (K,)
        Sample times, s.
    y : ndarray, shape (K, 3)
        Magnetometer samples, units as recorded.
    gyro, acceleration : ndarray of shape (K, 3) or None
        Angular rate (rad/s) and specific force (m/s^2), if the file has them.
    attitude : ndarray of shape (K, 4) or None
        Reference attitude, unit quaternions scalar first, sensor -> world, NaN where the
        reference is missing (``qw, qx, qy, qz``).
    """

    name: str
    t: np.ndarray
    y: np.ndarray
    gyro: np.ndarray | None = None
    acceleration: np.ndarray | None = None
    attitude: np.ndarray | None = None

    @property
    def K(self) -> int:
        return int(self.y.shape[0])

    def rows(self, index: slice | np.ndarray) -> InertialRecording:
        """The recording restricted to some rows (every stream alike)."""
        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[index]

        return replace(self, t=self.t[index], y=self.y[index], gyro=cut(self.gyro),
                       acceleration=cut(self.acceleration), attitude=cut(self.attitude))


def read_inertial(path: Path | str) -> InertialRecording:
    """Read ``t, mx, my, mz`` and, where present, ``gx..gz``, ``ax..az`` and ``qw..qz``.

    Rows without time or magnetometer values are dropped; missing attitude values stay NaN
    (the reference is often missing at a recording's ends).

    Raises
    ------
    ValueError
        If the file lacks ``t`` or a magnetometer column.
    """
    path = Path(path)
    header = [c.strip() for c in _read_csv(path, nrows=0).columns]
    need = ["t", *MAG_COLUMNS]
    if any(c not in header for c in need):
        raise ValueError(f"{path} needs columns {', '.join(need)}; it has {', '.join(header)}")
    groups = {"gyro": GYRO_COLUMNS, "acceleration": ACC_COLUMNS,
              "attitude": ATTITUDE_COLUMNS}
    present = {k: list(cols) for k, cols in groups.items() if all(c in header for c in cols)}
    table = _read_csv(path, usecols=need + [c for cols in present.values() for c in cols])
    keep = table[need].notna().all(axis=1).to_numpy()
    table = table[keep]
    streams = {k: table[cols].to_numpy(dtype=float) for k, cols in present.items()}
    return InertialRecording(path.parent.name if path.name == "data.csv" else path.stem,
                             table["t"].to_numpy(dtype=float),
                             table[list(MAG_COLUMNS)].to_numpy(dtype=float), **streams)


def log_recording(path: Path | str, instance: object = None, *, min_samples: int = 4,
                  check: bool = True, min_coverage: float = MIN_COVERAGE,
                  min_thickness: float = MIN_THICKNESS) -> Recording:
    """One compass of a flight log (:mod:`magbench.sources.logs`) as a :class:`Recording`.

    ``check`` (a calibration) also asks for :data:`MIN_LOG_SAMPLES` samples and the geometry
    of :func:`~magbench.core.geometry.check_geometry`. The other streams go to
    ``Recording.extra``; the gyro is ``Recording.gyro`` as well (rows where it is missing are
    dropped with a warning, as the CSV reader does).

    Raises
    ------
    ValueError
        What :meth:`FlightLog.choose` and :func:`read_log` raise; non-finite or unusable
        magnitudes; bad geometry. One line each.
    """
    path = Path(path)
    log = read_log(path)
    chosen = log.choose(instance, max(min_samples, MIN_LOG_SAMPLES) if check else min_samples)
    for note in log.notes:
        warnings.warn(note, UserWarning, stacklevel=2)
    table = {c: np.asarray(v, dtype=float) for c, v in log.columns(chosen).items()}
    gyro_cols = list(GYRO_COLUMNS)
    if all(c in table for c in gyro_cols):
        missing = np.isnan(_as_columns([table[c] for c in gyro_cols])).any(axis=1)
        if missing.any():
            warnings.warn(f"{path.name}: dropped {int(missing.sum())} of {len(missing)} "
                          "compass samples with no gyro sample around them (outside the gyro "
                          "stream or in a gap of it)", UserWarning, stacklevel=2)
            table = {c: v[~missing] for c, v in table.items()}
    y = _as_columns([table[c] for c in MAG_COLUMNS])
    if not np.isfinite(y).all():
        raise ValueError(f"{path.name}: the compass stream holds non-finite values")
    what = f"the compass samples of {path.name} (instance {chosen})"
    check_magnitude(y, what)
    if y.shape[0] < min_samples:
        raise ValueError(f"{path.name}: instance {chosen} has {y.shape[0]} usable samples; at "
                         f"least {min_samples} are needed")
    # their own arrays: a view of the compass's temperature would keep the log's whole
    # (K, 4) compass array alive beside the samples' copy
    extra = {c: np.ascontiguousarray(table[c]) for c in EXTRA_COLUMNS if c in table}
    rec = Recording(path.stem, y, table["t"],
                    _as_columns([table[c] for c in gyro_cols])
                    if all(c in table for c in gyro_cols) else None,
                    n_rows=len(y), columns=MAG_COLUMNS,
                    instance=("instance", str(chosen)),
                    extra=extra or None)
    if check:               # on an even stride, as for a CSV (GEOMETRY_SAMPLES)
        check_geometry(rec.y[::math.ceil(rec.K / GEOMETRY_SAMPLES)], min_coverage=min_coverage,
                       min_thickness=min_thickness, what=path.name)
    return rec
