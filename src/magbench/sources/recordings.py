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

import csv
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.geometry import MIN_COVERAGE, MIN_THICKNESS, check_geometry

__all__ = ["DATA_ENV", "GYRO_COLUMNS", "MAG_COLUMNS", "Recording", "data_dir",
           "list_recordings", "load_recording", "read_samples"]

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
    """

    name: str
    y: np.ndarray
    t: np.ndarray | None = None
    gyro: np.ndarray | None = None
    n_rows: int = 0
    stride: int = 1
    columns: tuple = MAG_COLUMNS

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
                       gyro=None if self.gyro is None else self.gyro[index])

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


def _sniff(path: Path) -> tuple[str, bool]:
    """Delimiter, and whether the first line is a header."""
    with open(path, newline="") as handle:
        head = handle.read(8192)
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


def _numeric(table: pd.DataFrame, position: int, name: str, line0: int) -> np.ndarray:
    """One column as floats; missing cells become NaN, other text is an error naming the cell."""
    text = table.iloc[:, position].astype(str).str.strip()
    missing = text.str.lower().isin(_MISSING)
    values = pd.to_numeric(text.where(~missing), errors="coerce")
    bad = np.flatnonzero(values.isna().to_numpy() & ~missing.to_numpy())
    if bad.size:
        row = int(bad[0])
        raise ValueError(f"non-numeric value {text.iloc[row]!r} in column {name!r} at data row "
                         f"{row + 1} (line {row + line0} of the file)"
                         + (f" and {bad.size - 1} more cell(s)" if bad.size > 1 else "")
                         + "; expected numbers (missing values may be empty or NaN)")
    return values.to_numpy(dtype=float)


def read_samples(path: Path | str, columns: Sequence[object] | None = None, *,
                 min_samples: int = 4, check: bool = True,
                 min_coverage: float = MIN_COVERAGE,
                 min_thickness: float = MIN_THICKNESS) -> Recording:
    """Read magnetometer samples from a CSV file (delimiter and header detected).

    Parameters
    ----------
    path : path
        The file. A header row is optional; without one, choose columns by position.
    columns : three names or three 0-based positions, optional
        The magnetometer axes. Default: ``mx, my, mz`` if the header has them, else the three
        columns of a three-column file.
    min_samples : int
        Fewest usable rows accepted (the chosen method's need).
    check : bool
        Also reject nearly coplanar samples and samples covering too little of the sphere
        (:func:`check_geometry`).

    Returns
    -------
    Recording
        Units as recorded; ``t`` if the header has a ``t`` column with values, ``gyro`` if it
        has ``gx, gy, gz`` (rad/s) as well.

    Raises
    ------
    ValueError
        Missing file or columns, non-numeric cells (with row and column), too few samples, or
        bad geometry; one message each.

    Warns
    -----
    UserWarning
        When rows with missing values are dropped (how many).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"file {path} not found; expected a CSV of magnetometer samples")
    sep, has_header = _sniff(path)
    try:
        table = pd.read_csv(path, sep=r"\s+" if sep == " " else sep, dtype=str,
                            keep_default_na=False, header=0 if has_header else None,
                            skip_blank_lines=True, engine="python")
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read {path} as CSV: {' '.join(str(exc).split())}") from None
    header = [str(c).strip() for c in table.columns] if has_header else None
    n_cols = table.shape[1]
    mag = _select(columns, header, n_cols, "columns", MAG_COLUMNS)
    if mag is None:
        if n_cols == 3:
            mag = [0, 1, 2]
        else:
            shown = ", ".join(header) if header else f"{n_cols} unnamed columns"
            raise ValueError(f"cannot tell which columns hold the magnetometer axes: no mx, my, "
                             f"mz header and {n_cols} columns ({shown}); choose them with "
                             "columns=[name,name,name] or columns=[0,1,2]")
    line0 = 2 if has_header else 1
    names = [header[i] if header else f"column {i}" for i in mag]
    y = np.column_stack([_numeric(table, i, n, line0) for i, n in zip(mag, names, strict=True)])
    used = ~np.isnan(y).any(axis=1)
    t = gyro = None
    if header is not None and "t" in header:
        t = _numeric(table, header.index("t"), "t", line0)
        if np.isnan(t).all():
            t = None
    gyro_pos = _select(None, header, n_cols, "gyro columns", GYRO_COLUMNS)
    if gyro_pos is not None and t is not None:
        gyro = np.column_stack([_numeric(table, i, GYRO_COLUMNS[k], line0)
                                for k, i in enumerate(gyro_pos)])
        used &= ~np.isnan(gyro).any(axis=1) & ~np.isnan(t)
    n_dropped = int((~used).sum())
    if n_dropped:
        warnings.warn(f"{path.name}: dropped {n_dropped} of {len(used)} rows with missing or "
                      "NaN values in the columns used", UserWarning, stacklevel=2)
    y = y[used]
    if not np.isfinite(y).all():
        raise ValueError(f"{path.name} contains infinite values; expected finite numbers")
    if y.shape[0] < min_samples:
        raise ValueError(f"{path.name} has {y.shape[0]} usable samples; at least {min_samples} "
                         "are needed (the method's number of unknowns)")
    rec = Recording(path.parent.name if path.name == "data.csv" else path.stem, y,
                    None if t is None else t[used], None if gyro is None else gyro[used],
                    n_rows=int(y.shape[0]), columns=tuple(names))
    if check:
        check_geometry(rec.y, min_coverage=min_coverage, min_thickness=min_thickness,
                       what=path.name)
    return rec
