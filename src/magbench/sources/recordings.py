"""Real recordings: one folder per recording, or a user's own CSV file.

One folder per recording under a data directory (``$MAGBENCH_DATA`` or the config value
``data_dir``), each with ``data.csv`` (columns ``t, mx, my, mz`` and optionally ``gx, gy, gz``
in rad/s and accelerometer columns), or a user's own CSV with the three axes chosen by name or
position (:func:`read_samples`). Units are kept as recorded. Rows with a missing value in a
used column are dropped with a warning that says how many; everything else that is wrong gives
one ``ValueError`` saying what is wrong and what is expected. Recordings longer than
``max_samples`` are thinned deterministically to every ``s``-th sample,
``s = ceil(n / max_samples)`` (a uniform stride keeps the time base uniform for the gyro
methods).
"""

from __future__ import annotations

import bz2
import csv
import gzip
import lzma
import math
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.geometry import MIN_COVERAGE, MIN_THICKNESS, check_geometry
from magbench.core.model import check_magnitude
from magbench.sources.logs import EXTRA_COLUMNS, MIN_LOG_SAMPLES, is_log, read_log

__all__ = ["DATA_ENV", "EXTRA_COLUMNS", "GYRO_COLUMNS", "MAG_COLUMNS", "Recording", "data_dir",
           "list_recordings", "load_recording", "log_recording", "read_samples"]

DATA_ENV = "MAGBENCH_DATA"
MAG_COLUMNS = ("mx", "my", "mz")
GYRO_COLUMNS = ("gx", "gy", "gz")
_MISSING = {"", "nan", "na", "n/a", "null", "none"}


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
    extra : DataFrame or None
        Other time-aligned columns, one row per sample (those of :data:`EXTRA_COLUMNS` the
        file has).
    """

    name: str
    y: np.ndarray
    t: np.ndarray | None = None
    gyro: np.ndarray | None = None
    n_rows: int = 0
    stride: int = 1
    columns: tuple = MAG_COLUMNS
    extra: pd.DataFrame | None = None

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
                       self.extra.iloc[index].reset_index(drop=True))

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


def _sniff(path: Path, compression: str | None = None) -> tuple[str, bool]:
    """Delimiter, and whether the first line is a header."""
    opener = _READABLE.get(compression or "", open)
    try:
        with opener(path, "rt", newline="") as handle:
            head = handle.read(8192)
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not a text file (bytes that are not UTF-8 at its start); "
                         "expected a CSV of magnetometer samples") from None
    except (OSError, EOFError) as exc:
        raise ValueError(f"cannot read {path} ({compression or 'plain'}): {exc}") from None
    lines = [ln for ln in head.splitlines() if ln.strip()]
    if not lines:
        raise ValueError(f"{path} is empty; expected a CSV with one magnetometer sample per row")
    try:
        sep = csv.Sniffer().sniff("\n".join(lines[:20]), delimiters=",;\t ").delimiter
    except csv.Error:
        sep = ","
    first = lines[0].split() if sep == " " else lines[0].split(sep)
    fields = [f.strip().strip('"') for f in first]

    def numeric(text: str) -> bool:
        try:
            float(text)
        except ValueError:
            return text.lower() in _MISSING
        return True

    return sep, not all(numeric(f) for f in fields)


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


def _numeric(table: pd.DataFrame, position: int, name: str, line0: int,
             row0: int = 0) -> np.ndarray:
    """One column as floats; missing cells become NaN, other text is an error naming the cell
    (``table`` starts at data row ``row0`` of the file, whose first data row is line ``line0``).
    """
    text = table.iloc[:, position].astype(str).str.strip()
    missing = text.str.lower().isin(_MISSING)
    values = pd.to_numeric(text.where(~missing), errors="coerce")
    bad = np.flatnonzero(values.isna().to_numpy() & ~missing.to_numpy())
    if bad.size:
        row = row0 + int(bad[0])
        raise ValueError(f"non-numeric value {text.iloc[row - row0]!r} in column {name!r} at "
                         f"data row "
                         f"{row + 1} (line {row + line0} of the file)"
                         + (f" and {bad.size - 1} more cell(s)" if bad.size > 1 else "")
                         + "; expected numbers (missing values may be empty or NaN)")
    return values.to_numpy(dtype=float)


#: Missing-value spellings as the C parser needs them (it matches exactly, after no strip).
_NA_TOKENS = sorted({v for w in _MISSING for v in (w, w.upper(), w.capitalize())})


def _read_csv(path: Path, **kwargs: object) -> pd.DataFrame:
    """``pandas.read_csv`` with its parse errors as one ``ValueError`` naming the file."""
    try:
        return pd.read_csv(path, **kwargs)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, EOFError,
            OSError) as exc:
        raise ValueError(f"cannot read {path} as CSV: {' '.join(str(exc).split())}") from None


def _quiet(reader: Iterator[pd.DataFrame]) -> Iterator[pd.DataFrame]:
    """The chunks, without pandas' mixed-type warning (such a column is checked cell by cell)."""
    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", pd.errors.DtypeWarning)
            chunk = next(reader, None)
        if chunk is None:
            return
        yield chunk


def _read_columns(path: Path, layout: dict, wanted: dict[int, str],
                  line0: int) -> np.ndarray:
    """The columns at the positions in ``wanted`` (position -> name) as floats, in the order
    of their positions (shape (rows, len(wanted))).

    Read in chunks of :data:`CHUNK_ROWS` rows by pandas' C parser, keeping only those columns,
    so memory follows the floats kept (24 bytes a row for three axes), never the file's text:
    10 million rows once took 4.5 GB as Python strings. A chunk whose column the parser could
    not turn into numbers (text, padded spaces) goes through :func:`_numeric`, which accepts
    what the text reader accepts and names the first bad cell.
    """
    positions = sorted(wanted)
    chunks: list[np.ndarray] = []
    # A plain file's line count bounds its rows: fill one array instead of concatenating
    # chunks, which would hold every sample twice at the end.
    table = None if layout.get("compression") else np.empty((_count_lines(path),
                                                               len(positions)))
    offset = 0
    try:
        reader = pd.read_csv(path, usecols=positions, chunksize=CHUNK_ROWS, engine="c",
                             na_values=_NA_TOKENS, keep_default_na=False, **layout)
        for chunk in _quiet(reader):
            block = (np.empty((len(chunk), len(positions))) if table is None else
                     table[offset:offset + len(chunk)])
            for j, p in enumerate(positions):
                column = chunk.iloc[:, j]
                if pd.api.types.is_numeric_dtype(column) and \
                        not pd.api.types.is_bool_dtype(column):
                    block[:, j] = column.to_numpy(dtype=float)
                else:
                    block[:, j] = _numeric(chunk, j, wanted[p], line0, offset)
            if table is None:
                chunks.append(block)
            offset += len(chunk)
    except (pd.errors.ParserError, UnicodeDecodeError, EOFError, OSError) as exc:
        raise ValueError(f"cannot read {path} as CSV: {' '.join(str(exc).split())}") from None
    if table is not None:
        return table[:offset]
    if len(chunks) == 1:
        return chunks[0]
    return np.concatenate(chunks) if chunks else np.empty((0, len(positions)))


def _count_lines(path: Path) -> int:
    """Line breaks in ``path`` plus one (an upper bound on its data rows)."""
    n = 1
    with open(path, "rb") as handle:
        while block := handle.read(1 << 24):
            n += block.count(b"\n")
    return n


def _extra_columns(path: Path, layout: dict, header: list[str] | None,
                   used: slice | np.ndarray, has_header: bool) -> pd.DataFrame | None:
    """The :data:`EXTRA_COLUMNS` the header names, on the rows kept (missing cells NaN)."""
    wanted = {header.index(c): c for c in EXTRA_COLUMNS if header and c in header}
    if not wanted:
        return None
    table = _read_columns(path, layout, wanted, line0=2 if has_header else 1)[used]
    names = [wanted[p] for p in sorted(wanted)]
    return pd.DataFrame(table, columns=names)[[c for c in EXTRA_COLUMNS if c in names]]


#: The geometry check of a longer recording looks at an even stride of this many samples: the
#: spread and the coverage of 10 million samples are those of any 100 000 evenly spread ones,
#: at a hundredth of the time and memory.
GEOMETRY_SAMPLES = 100_000


def read_samples(path: Path | str, columns: Sequence[object] | None = None, *,
                 min_samples: int = 4, check: bool = True,
                 min_coverage: float = MIN_COVERAGE,
                 min_thickness: float = MIN_THICKNESS,
                 instance: int | None = None) -> Recording:
    """Read magnetometer samples from a CSV file (delimiter and header detected).

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
    instance : int, optional
        A flight log's compass (:mod:`magbench.sources.logs`; a ``.ulg``, ``.bin`` or ``.log``
        file is read as one): needed when it has several.

    Returns
    -------
    Recording
        Units as recorded; ``t`` if the header has a ``t`` column with values, ``gyro`` if it
        has ``gx, gy, gz`` (rad/s) as well.

    Raises
    ------
    ValueError
        Missing file or columns, non-numeric cells (with row and column), too few samples,
        magnitudes no fit can square (:func:`magbench.core.model.check_magnitude`), zip or
        zstd input (to unpack first), or bad geometry; one message each.

    Warns
    -----
    UserWarning
        When rows with missing values are dropped (how many).
    """
    path = Path(path)
    if is_log(path):          # .ulg, .bin, .log: magbench.sources.logs
        return log_recording(path, instance, min_samples=min_samples, check=check,
                             min_coverage=min_coverage, min_thickness=min_thickness)
    if path.is_dir():
        raise ValueError(f"file {path} is a folder; expected a CSV of magnetometer samples")
    if not path.is_file():
        raise ValueError(f"file {path} not found; expected a CSV of magnetometer samples")
    compression = _compression(path)
    sep, has_header = _sniff(path, compression)
    layout = {"sep": r"\s+" if sep == " " else sep, "header": 0 if has_header else None,
              "compression": compression, "skip_blank_lines": True}
    first = _read_csv(path, nrows=0 if has_header else 1, dtype=str, keep_default_na=False,
                      **layout)
    header = [str(c).strip() for c in first.columns] if has_header else None
    n_cols = first.shape[1]
    mag = _select(columns, header, n_cols, "columns", MAG_COLUMNS)
    if mag is None:
        if n_cols == 3:
            mag = [0, 1, 2]
        else:
            shown = ", ".join(header) if header else f"{n_cols} unnamed columns"
            raise ValueError(f"cannot tell which columns hold the magnetometer axes: no mx, my, "
                             f"mz header and {n_cols} columns ({shown}); choose them with "
                             "columns=[name,name,name] or columns=[0,1,2]")
    names = [header[i] if header else f"column {i}" for i in mag]
    t_pos = header.index("t") if header is not None and "t" in header else None
    gyro_pos = _select(None, header, n_cols, "gyro columns", GYRO_COLUMNS)
    wanted = {**dict(zip(mag, names, strict=True)),
              **({} if t_pos is None else {t_pos: "t"}),
              **({} if gyro_pos is None or t_pos is None else
                 dict(zip(gyro_pos, GYRO_COLUMNS, strict=True)))}
    table = _read_columns(path, layout, wanted, line0=2 if has_header else 1)
    values = {p: table[:, j] for j, p in enumerate(sorted(wanted))}
    order = [sorted(wanted).index(i) for i in mag]
    # The usual three-column file is its own sample array: no copy of 10 million rows.
    y = table if order == list(range(table.shape[1])) else table[:, order]
    used = ~np.isnan(y).any(axis=1)
    t = gyro = None
    if t_pos is not None:
        t = values[t_pos]
        if np.isnan(t).all():
            t = None
    if gyro_pos is not None and t is not None:
        gyro = np.column_stack([values[i] for i in gyro_pos])
        used &= ~np.isnan(gyro).any(axis=1) & ~np.isnan(t)
    n_dropped = int((~used).sum())
    if not n_dropped:
        used = slice(None)          # a view, not a copy of every sample
    if n_dropped:
        warnings.warn(f"{path.name}: dropped {n_dropped} of {len(y)} rows with missing or "
                      "NaN values in the columns used", UserWarning, stacklevel=2)
    y = y[used]
    if not np.isfinite(y).all():
        raise ValueError(f"{path.name} contains infinite values; expected finite numbers")
    check_magnitude(y, f"the samples of {path.name}")
    if y.shape[0] < min_samples:
        raise ValueError(f"{path.name} has {y.shape[0]} usable samples; at least {min_samples} "
                         "are needed (the method's number of unknowns)")
    rec = Recording(path.parent.name if path.name == "data.csv" else path.stem, y,
                    None if t is None else t[used], None if gyro is None else gyro[used],
                    n_rows=int(y.shape[0]), columns=tuple(names),
                    extra=_extra_columns(path, layout, header, used, has_header))
    if check:
        stride = math.ceil(rec.K / GEOMETRY_SAMPLES)
        check_geometry(rec.y[::stride], min_coverage=min_coverage,
                       min_thickness=min_thickness, what=path.name)
    return rec


def log_recording(path: Path | str, instance: int | None = None, *, min_samples: int = 4,
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
    table = log.table(chosen)
    gyro_cols = list(GYRO_COLUMNS)
    if all(c in table for c in gyro_cols):
        missing = table[gyro_cols].isna().any(axis=1).to_numpy()
        if missing.any():
            warnings.warn(f"{path.name}: dropped {int(missing.sum())} of {len(table)} compass "
                          "samples with no gyro sample around them (outside the gyro stream or "
                          "in a gap of it)", UserWarning, stacklevel=2)
            table = table[~missing].reset_index(drop=True)
    y = table[list(MAG_COLUMNS)].to_numpy(float)
    if not np.isfinite(y).all():
        raise ValueError(f"{path.name}: the compass stream holds non-finite values")
    what = f"the compass samples of {path.name} (instance {chosen})"
    check_magnitude(y, what)
    if y.shape[0] < min_samples:
        raise ValueError(f"{path.name}: instance {chosen} has {y.shape[0]} usable samples; at "
                         f"least {min_samples} are needed")
    extra = table[[c for c in EXTRA_COLUMNS if c in table]]
    rec = Recording(path.stem, y, table["t"].to_numpy(float),
                    table[gyro_cols].to_numpy(float) if all(c in table for c in gyro_cols)
                    else None, n_rows=len(y), columns=MAG_COLUMNS,
                    extra=extra if len(extra.columns) else None)
    if check:
        check_geometry(rec.y, min_coverage=min_coverage, min_thickness=min_thickness,
                       what=path.name)
    return rec
