"""Real recordings: loading, checking, and the real-data sweep of review section 10.2 (Figure 6).

Without a ground truth, a calibration is judged by J_r of eq. (81), the mean of
``(||m_k||^2 - 1)^2`` with ``m_k = T^-1 (y_k - h)`` (82). This module adds what the review's
section leaves open and what real files need:

*Loading.* One folder per recording under a data directory (``$MAGBENCH_DATA`` or the config
value ``data_dir``), each with ``data.csv`` (columns ``t, mx, my, mz`` and optionally
``gx, gy, gz`` in rad/s and accelerometer columns), or a user's own CSV with the three axes
chosen by name or position (:func:`read_samples`). Units are kept as recorded. Rows with a
missing value in a used column are dropped with a warning that says how many; everything else
that is wrong gives one ``ValueError`` saying what is wrong and what is expected.

*Geometry checks* (:func:`check_geometry`). ``thickness`` is the smallest over the largest
singular value of the mean-centred samples (1 for a full sphere, 0 for samples in a plane);
below :data:`MIN_THICKNESS` the samples are "nearly coplanar". ``coverage`` is the fraction of
:data:`COVERAGE_GRID` Fibonacci directions lying within :data:`COVERAGE_ANGLE_DEG` of some
sample direction seen from the sphere-fit centre (1 for a full sphere, about 0.5 for a
hemisphere or for a single great circle, which is why both figures are checked); below
:data:`MIN_COVERAGE` the samples cover "too little of the sphere".

*Preprocessing* (:func:`fit_recording`). ``scale`` divides by the mean sample norm: the review's
"remove gross scaling errors" (section 10.1, below eq. 68). ``centre`` also subtracts the centre
of the linear least-squares sphere fit and divides by its radius, so the methods see data close
to the unit sphere about the origin, as in the synthetic sweeps (offsets of at most gamma = 1).
``none`` passes the recording as it is (the registry still scales by a power of two). The
estimate is always mapped back: ``T`` and ``h`` are in the recorded units.

*The sweep* (:func:`run_real_sweep`, ``python -m magbench sweep=real``). Every selected method on
every recording and preprocessing, three fits each: on all samples (J_r in sample), on the
first half in time and on the second half in time, each evaluated on the other half (J_r out of
sample; time halves, not even/odd samples, because neighbouring samples of a slow hand rotation
are nearly equal and an even/odd split would test on the training data). A fit on all of one
qmc5883l recording is also evaluated on the other recording of the same sensor (cross).
Recordings longer than ``max_samples`` are thinned deterministically to every ``s``-th sample,
``s = ceil(n / max_samples)`` (a uniform stride keeps the time base uniform for the gyro methods).

*Robustness on real data* (:func:`is_meaningful`). There is no ``J0`` of eq. (75); a fit counts
as meaningful when (i) the method ended normally (converged, finite), (ii) its J_r on its fit
data is at most ``sphere_factor`` (2) times that of the linear least-squares sphere fit
``T = r I, h = c`` on the same data (every full or sphere model contains that answer, so doing
much worse means the method missed the basin a simple linear fit finds; the factor leaves room
for sphere-model methods, which at best tie with it), and (iii) its calibrated directions cover
at least ``coverage_ratio`` (0.5) times the coverage of the sphere fit's directions.
Condition (iii) is needed because J_r has a
degenerate minimiser: with ``h`` far away and ``T = D I``, every ``m_k`` lands near one point
of the unit sphere and J_r tends to 0 as D grows. Methods that start from ``y_k / ||y_k||``
(MAG.I.C.AL, Dorveaux) walk into it on recordings whose offset exceeds the field radius. RB % is
the share of meaningful fits among the applicable (not skipped) ones (eq. 77 in spirit).

Methods that need more samples than a fit has, or gyro data a recording lacks, or inputs beyond
samples, gyro and time (MagFactor3's attitude), give rows with ``skipped=True`` and the reason;
they count neither for nor against robustness.
"""

from __future__ import annotations

import csv
import inspect
import math
import os
import sys
import time as _time
import warnings
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.files import write_csv_atomic, write_text_atomic
from magbench.core.geometry import fibonacci_sphere
from magbench.core.metrics import real_cost
from magbench.core.model import Calibration
from magbench.engine.trial import time_limit
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method

__all__ = [
    "COVERAGE_ANGLE_DEG",
    "COVERAGE_GRID",
    "DATA_ENV",
    "DEFAULT_MAX_SAMPLES",
    "MIN_COVERAGE",
    "MIN_THICKNESS",
    "PREPROCESSING",
    "REAL_ROW_COLUMNS",
    "RealSweepSpec",
    "Recording",
    "applicability",
    "check_geometry",
    "coverage",
    "data_dir",
    "fit_recording",
    "is_meaningful",
    "list_recordings",
    "load_recording",
    "method_summary",
    "read_samples",
    "real_report_section",
    "recording_summary",
    "run_real",
    "run_real_sweep",
    "sphere_fit",
    "thickness",
]

DATA_ENV = "MAGBENCH_DATA"
DEFAULT_MAX_SAMPLES = 2000
COVERAGE_GRID = 200
COVERAGE_ANGLE_DEG = 30.0
MIN_COVERAGE = 0.3
MIN_THICKNESS = 0.1
PREPROCESSING = ("none", "scale", "centre")
#: Recordings of the same sensor: a fit on one is also evaluated on the other.
PARTNERS = {"qmc5883l_filtered": "qmc5883l_noisy", "qmc5883l_noisy": "qmc5883l_filtered"}
MAG_COLUMNS = ("mx", "my", "mz")
GYRO_COLUMNS = ("gx", "gy", "gz")
_MISSING = {"", "nan", "na", "n/a", "null", "none"}
_T_COLUMNS = [f"T_{i}{j}" for i in range(3) for j in range(3)]
_H_COLUMNS = [f"h_{i}" for i in range(3)]
REAL_ROW_COLUMNS = (["dataset", "n_rows", "stride", "preprocess", "algorithm", "fit_on", "K_fit",
                     "test_on", "K_test", "skipped", "ok", "error", "time_s", "n_iter",
                     "J_r_fit", "J_r_test", "J_r_sphere_fit", "J_r_sphere_test",
                     "coverage_fit", "coverage_sphere_fit", "usable", "meaningful"]
                    + _H_COLUMNS + _T_COLUMNS)


# --------------------------------------------------------------------------- loading


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


# --------------------------------------------------------------------------- geometry


def sphere_fit(y: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre ``c`` and radius ``r`` of the linear least-squares sphere fit.

    ``||y||^2 = 2 c.y + (r^2 - ||c||^2)`` is linear in ``c`` and ``d = r^2 - ||c||^2``.
    ``T = r I, h = c`` is the simplest calibration (hard iron and one scale), the real-data
    baseline of :func:`is_meaningful`. Computed here, not taken from the registry, so the
    baseline stays fixed whatever methods are registered.
    """
    y = np.asarray(y, dtype=float)
    scale = float(np.sqrt(np.mean(np.einsum("ij,ij->i", y, y)))) or 1.0
    z = y / scale
    A = np.hstack([2.0 * z, np.ones((z.shape[0], 1))])
    sol = np.linalg.lstsq(A, np.einsum("ij,ij->i", z, z), rcond=None)[0]
    c = sol[:3]
    r2 = float(sol[3] + c @ c)
    if not r2 > 0:
        raise ValueError("the sphere fit has no real radius; the samples do not lie near a "
                         "sphere or ellipsoid")
    return c * scale, math.sqrt(r2) * scale


def _unit_rows(x: np.ndarray) -> np.ndarray:
    n = np.sqrt(np.einsum("ij,ij->i", x, x))
    return x[n > 0] / n[n > 0, None]


def coverage(directions: np.ndarray, *, grid: int = COVERAGE_GRID,
             angle_deg: float = COVERAGE_ANGLE_DEG) -> float:
    """Fraction of ``grid`` Fibonacci directions within ``angle_deg`` of a given direction.

    ``directions`` need not be normalised. A full sphere gives 1, a hemisphere about 0.5 + the
    margin, a cap of angular radius theta about ``(1 - cos(theta + angle)) / 2``.
    """
    u = _unit_rows(np.asarray(directions, dtype=float))
    if u.shape[0] == 0:
        return 0.0
    g = fibonacci_sphere(grid)
    cos_limit = math.cos(math.radians(angle_deg))
    best = np.full(grid, -1.0)
    for start in range(0, u.shape[0], 4096):      # bounded memory for long recordings
        best = np.maximum(best, (g @ u[start:start + 4096].T).max(axis=1))
    return float(np.mean(best >= cos_limit))


def thickness(y: np.ndarray) -> float:
    """Smallest over largest singular value of the mean-centred samples (0 = coplanar)."""
    s = np.linalg.svd(np.asarray(y, float) - np.mean(y, axis=0), compute_uv=False)
    return float(s[2] / s[0]) if s[0] > 0 else 0.0


def check_geometry(y: np.ndarray, *, min_coverage: float = MIN_COVERAGE,
                   min_thickness: float = MIN_THICKNESS, what: str = "samples") -> None:
    """Reject samples that are nearly coplanar or cover too little of the sphere.

    Raises
    ------
    ValueError
        With the figure that failed and the threshold (see the module notes for definitions).
    """
    th = thickness(y)
    if th < min_thickness:
        raise ValueError(f"{what}: samples are nearly coplanar (thickness {th:.3g}: smallest/"
                         f"largest singular value of the centred samples; at least "
                         f"{min_thickness:g} is needed); rotate the sensor about more than "
                         "one axis")
    c, _ = sphere_fit(y)
    cov = coverage(y - c)
    if cov < min_coverage:
        raise ValueError(f"{what}: samples cover too little of the sphere (coverage {cov:.2f}: "
                         f"fraction of {COVERAGE_GRID} evenly spread directions within "
                         f"{COVERAGE_ANGLE_DEG:g} deg of a sample direction seen from the "
                         f"sphere-fit centre; at least {min_coverage:g} is needed); point the "
                         "sensor in more directions")


# --------------------------------------------------------------------------- fitting


def applicability(name: str, rec: Recording) -> str:
    """Why ``name`` cannot run on ``rec`` (empty string if it can)."""
    spec = get_method(name)
    if rec.K < spec.min_samples:
        return f"skipped: {name} needs at least {spec.min_samples} samples, this fit has {rec.K}"
    if spec.needs_gyro and not rec.has_gyro:
        return f"skipped: {name} needs gyroscope data and times; the recording has none"
    params = inspect.signature(spec.fit).parameters.values()
    needs = [p.name for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY
             and p.default is inspect.Parameter.empty
             and p.name not in ("angular_rate", "time", "rng")]
    if needs:
        return f"skipped: {name} also needs {', '.join(needs)}, which a recording does not hold"
    return ""


def _preprocessing(y: np.ndarray, how: str) -> tuple[np.ndarray, float]:
    """Offset and scale with ``y' = (y - offset) / scale`` for the named preprocessing."""
    if how == "none":
        return np.zeros(3), 1.0
    if how == "scale":
        return np.zeros(3), float(np.mean(np.sqrt(np.einsum("ij,ij->i", y, y))))
    if how == "centre":
        c, r = sphere_fit(y)
        return c, r
    raise ValueError(f"preprocess must be one of {', '.join(PREPROCESSING)}, got {how!r}")


def fit_recording(rec: Recording, method: str, preprocess: str = "centre",
                  options: dict | None = None) -> Calibration:
    """Calibrate ``rec`` with ``method`` after preprocessing; ``T, h`` in the recorded units.

    With ``y' = (y - o) / s`` and the method's ``y' = T' m + h'``, the recording obeys
    ``y = (s T') m + (s h' + o)``.
    """
    offset, scale = _preprocessing(rec.y, preprocess)
    extra = {}
    if get_method(method).needs_gyro:
        extra = {"angular_rate": rec.gyro, "time": rec.t}
    cal = calibrate((rec.y - offset) / scale, method, **extra, **dict(options or {}))
    return Calibration(scale * cal.T, scale * cal.h + offset, cal.n_iter, cal.converged,
                       cal.message, cal.gyro_bias)


def calibrated_coverage(y: np.ndarray, T: np.ndarray, h: np.ndarray) -> float:
    """Coverage of the calibrated directions ``T^-1 (y - h)``."""
    return coverage(np.linalg.solve(T, (y - h).T).T)


def is_meaningful(ok: bool, J_r: float, J_r_sphere: float, coverage_fit: float,
                  coverage_sphere: float, coverage_ratio: float = 0.5,
                  sphere_factor: float = 2.0) -> bool:
    """Robustness criterion on real data (see the module notes).

    ``ok`` (ended normally), ``J_r <= sphere_factor * J_r_sphere`` and
    ``coverage_fit >= coverage_ratio * coverage_sphere``.
    """
    return bool(ok and is_usable(coverage_fit, coverage_sphere, coverage_ratio)
                and np.isfinite(J_r) and J_r <= sphere_factor * J_r_sphere)


def is_usable(coverage_fit: float, coverage_sphere: float, coverage_ratio: float = 0.5) -> bool:
    """An estimate that is not the degenerate one: its directions keep their coverage."""
    return bool(np.isfinite(coverage_fit) and coverage_fit >= coverage_ratio * coverage_sphere)


def _rng(seed: int, *keys: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(
        int(seed), spawn_key=tuple(zlib.crc32(k.encode()) for k in keys)))


def _fit_row(rec: Recording, part: str, fit: Recording, tests: list[tuple[str, Recording]],
             method: str, preprocess: str, options: dict, seed: int,
             call_timeout_s: float | None, coverage_ratio: float,
             sphere_factor: float) -> list[dict]:
    """Fit once on ``fit`` and evaluate on each test set; one row per test set (at least one)."""
    c, r = sphere_fit(fit.y)
    sphere_T = r * np.eye(3)
    base = {"dataset": rec.name, "n_rows": rec.n_rows, "stride": rec.stride,
            "preprocess": preprocess, "algorithm": method, "fit_on": part, "K_fit": fit.K,
            "J_r_sphere_fit": real_cost(fit.y, sphere_T, c),
            "coverage_sphere_fit": coverage(fit.y - c)}
    tests = tests or [("", None)]
    reason = applicability(method, fit)
    T = h = None
    n_iter, elapsed, error = 0, 0.0, reason
    if not reason:
        opts = dict(options)
        if get_method(method).randomized:
            opts["rng"] = _rng(seed, rec.name, method, part, preprocess)
        start = _time.perf_counter()
        try:
            with time_limit(call_timeout_s):
                cal = fit_recording(fit, method, preprocess, opts)
            elapsed = _time.perf_counter() - start
            T, h, n_iter = cal.T, cal.h, cal.n_iter
            if not cal.converged:
                error = cal.message
        except Exception as exc:  # failures are data, as in runner.run_trial
            elapsed = _time.perf_counter() - start
            error = f"{type(exc).__name__}: {exc}"
    ok = not error
    J_fit = real_cost(fit.y, T, h) if T is not None else np.nan
    cov_fit = calibrated_coverage(fit.y, T, h) if T is not None else np.nan
    rows = []
    for test_name, test in tests:
        J_test = real_cost(test.y, T, h) if (T is not None and test is not None) else np.nan
        rows.append({
            **base, "test_on": test_name, "K_test": 0 if test is None else test.K,
            "skipped": bool(reason), "ok": ok, "error": error, "time_s": elapsed,
            "n_iter": n_iter, "J_r_fit": J_fit, "J_r_test": J_test,
            "J_r_sphere_test": real_cost(test.y, sphere_T, c) if test is not None else np.nan,
            "coverage_fit": cov_fit,
            "usable": T is not None and is_usable(cov_fit, base["coverage_sphere_fit"],
                                                  coverage_ratio),
            "meaningful": is_meaningful(ok, J_fit, base["J_r_sphere_fit"], cov_fit,
                                        base["coverage_sphere_fit"], coverage_ratio,
                                        sphere_factor),
            **dict(zip(_H_COLUMNS, (np.full(3, np.nan) if h is None else h).tolist(),
                       strict=True)),
            **dict(zip(_T_COLUMNS, (np.full(9, np.nan) if T is None else T.ravel()).tolist(),
                       strict=True)),
        })
    return rows


def evaluate_recording(rec: Recording, algorithms: Sequence[str], preprocess: Sequence[str],
                       *, options: dict | None = None, seed: int = 0,
                       partner: Recording | None = None, call_timeout_s: float | None = None,
                       coverage_ratio: float = 0.5, sphere_factor: float = 2.0) -> list[dict]:
    """All rows of one (already thinned) recording: methods x preprocessing x fits."""
    options = options or {}
    first, second = rec.halves()
    fits = [("all", rec, [("partner:" + partner.name, partner)] if partner is not None else []),
            ("first_half", first, [("second_half", second)]),
            ("second_half", second, [("first_half", first)])]
    rows = []
    for how in preprocess:
        for method in algorithms:
            for part, fit, tests in fits:
                rows += _fit_row(rec, part, fit, tests, method, how,
                                 dict(options.get(method) or {}), seed, call_timeout_s,
                                 coverage_ratio, sphere_factor)
    return rows


# --------------------------------------------------------------------------- the sweep


@dataclass(frozen=True)
class RealSweepSpec:
    """What the real-data sweep runs (see the module notes)."""

    datasets: Sequence[str]
    algorithms: Sequence[str]
    preprocess: Sequence[str] = ("scale", "centre")
    max_samples: int = DEFAULT_MAX_SAMPLES
    options: dict | None = None
    seed: int = 0
    call_timeout_s: float | None = None
    coverage_ratio: float = 0.5
    sphere_factor: float = 2.0


def _recording_task(root: str, name: str, spec: RealSweepSpec) -> list[dict]:
    rec = load_recording(root, name, check=False).thinned(spec.max_samples)
    partner = None
    if name in PARTNERS and PARTNERS[name] in spec.datasets:
        partner = load_recording(root, PARTNERS[name], check=False).thinned(spec.max_samples)
    return evaluate_recording(rec, spec.algorithms, spec.preprocess, options=spec.options,
                              seed=spec.seed, partner=partner,
                              call_timeout_s=spec.call_timeout_s,
                              coverage_ratio=spec.coverage_ratio,
                              sphere_factor=spec.sphere_factor)


def run_real_sweep(spec: RealSweepSpec, root: Path | str, out_dir: Path | str, *,
                   n_jobs: int = 1) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Run the sweep and write ``real_trials.csv``, ``real_summary.csv``, ``fig6_real.csv``.

    Returns
    -------
    trials, per_recording, per_method : DataFrame
        One row per fit and test set; one per (recording, preprocessing, method); one per
        (preprocessing, method) — the numbers Figure 6 plots.
    """
    from joblib import Parallel, delayed

    out_dir = Path(out_dir)
    jobs = Parallel(n_jobs=n_jobs)(delayed(_recording_task)(str(root), name, spec)
                                   for name in spec.datasets)
    trials = pd.DataFrame([row for rows in jobs for row in rows], columns=REAL_ROW_COLUMNS)
    per_recording = recording_summary(trials)
    per_method = method_summary(per_recording)
    write_csv_atomic(trials, out_dir / "real_trials.csv")
    write_csv_atomic(per_recording, out_dir / "real_summary.csv")
    write_csv_atomic(per_method, out_dir / "fig6_real.csv")
    return trials, per_recording, per_method


def recording_summary(trials: pd.DataFrame) -> pd.DataFrame:
    """One row per (recording, preprocessing, method).

    ``J_r_in`` is the fit on all samples; ``J_r_out`` the mean of the two half-fits' J_r on the
    other half when both half-fits gave a usable estimate (not the degenerate one; an estimate
    stopped by its iteration cap counts, since it is what a user would get), else NaN;
    ``J_r_cross`` the all-samples fit on the partner recording; ``meaningful`` the
    all-samples fit's criterion.
    """
    keys = ["dataset", "preprocess", "algorithm"]
    rows = []
    for key, group in trials.groupby(keys, sort=False):
        full = group[group["fit_on"] == "all"].iloc[0]
        halves = group[group["fit_on"] != "all"]
        cross = group[group["test_on"].astype(str).str.startswith("partner:")]
        halves_ok = bool(len(halves) == 2 and halves["usable"].astype(bool).all())
        rows.append({
            **dict(zip(keys, key, strict=True)), "K": int(full["K_fit"]),
            "n_rows": int(full["n_rows"]), "stride": int(full["stride"]),
            "skipped": bool(full["skipped"]), "ok": bool(full["ok"]),
            "meaningful": bool(full["meaningful"]), "error": full["error"],
            "time_s": float(full["time_s"]), "n_iter": int(full["n_iter"]),
            "J_r_in": float(full["J_r_fit"]), "J_r_sphere_in": float(full["J_r_sphere_fit"]),
            "J_r_out": float(halves["J_r_test"].mean()) if halves_ok else np.nan,
            "J_r_sphere_out": float(halves["J_r_sphere_test"].mean()) if len(halves) else np.nan,
            "halves_usable": halves_ok,
            "cross_on": cross["test_on"].iloc[0][len("partner:"):] if len(cross) else "",
            "J_r_cross": float(cross["J_r_test"].iloc[0]) if len(cross) else np.nan,
            "coverage": float(full["coverage_fit"]),
            "coverage_sphere": float(full["coverage_sphere_fit"]),
            **{c: float(full[c]) for c in _H_COLUMNS + _T_COLUMNS},
        })
    return pd.DataFrame(rows)


def method_summary(per_recording: pd.DataFrame) -> pd.DataFrame:
    """Figure 6's numbers: one row per (preprocessing, method).

    ``RB_pct`` is the share of meaningful all-samples fits among the applicable recordings;
    ``rho_in`` the mean J_r in sample over the meaningful ones (the review's "mean value of the
    cost function (81) across all the recorded datasets", restricted to meaningful fits as in
    eq. 78) and ``accuracy_in = 1 / rho_in``; ``rho_out`` and ``accuracy_out`` the same for the
    held-out J_r over the meaningful recordings that have one; ``median_ratio_in`` and
    ``median_ratio_out`` the medians over the same recordings of J_r over the sphere fit's J_r
    on the same data (scale-free: the means are dominated by the noisiest recordings).
    """
    rows = []
    for (how, name), g in per_recording.groupby(["preprocess", "algorithm"], sort=False):
        applicable = g[~g["skipped"].astype(bool)]
        good = applicable[applicable["meaningful"].astype(bool)]
        out = good[np.isfinite(good["J_r_out"])]
        rho_in = float(good["J_r_in"].mean()) if len(good) else np.nan
        rho_out = float(out["J_r_out"].mean()) if len(out) else np.nan
        try:
            label = get_method(name).label
        except ValueError:
            label = name
        rows.append({
            "preprocess": how, "algorithm": name, "label": label,
            "n_recordings": len(g), "n_applicable": len(applicable),
            "n_meaningful": len(good), "n_out": len(out),
            "RB_pct": 100.0 * len(good) / len(applicable) if len(applicable) else np.nan,
            "rho_in": rho_in, "accuracy_in": 1.0 / rho_in if len(good) else np.nan,
            "rho_out": rho_out, "accuracy_out": 1.0 / rho_out if len(out) else np.nan,
            "median_ratio_in": float((good["J_r_in"] / good["J_r_sphere_in"]).median())
            if len(good) else np.nan,
            "median_ratio_out": float((out["J_r_out"] / out["J_r_sphere_out"]).median())
            if len(out) else np.nan,
            "tau_s": float(good["time_s"].mean()) if len(good) else np.nan,
        })
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- report


def _fmt(x: float, digits: int = 3) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


def real_report_section(results_dir: Path | str, figure_link: str = "real/fig6_real.png") -> str:
    """Markdown section on the real recordings, from ``<results_dir>/real/`` CSV files alone.

    ``figure_link`` is the figure's path relative to where the Markdown is written (the
    default suits ``<results_dir>/report.md``). Returns an empty string when the real sweep
    has not been run.
    """
    folder = Path(results_dir) / "real"
    if not (folder / "fig6_real.csv").exists() or not (folder / "real_summary.csv").exists():
        return ""
    per_method = pd.read_csv(folder / "fig6_real.csv")
    per_rec = pd.read_csv(folder / "real_summary.csv", dtype={"cross_on": str, "error": str})
    per_rec["cross_on"] = per_rec["cross_on"].fillna("")
    n_rec = per_rec["dataset"].nunique()
    lines = [
        "## Real recordings (review section 10.2, Figure 6)", "",
        f"{n_rec} public recordings (see the README for their sources), J_r of eq. (81). "
        "*In*: fit and J_r on all samples (at most "
        f"{int(per_rec['K'].max())} per recording, evenly thinned). *Out*: fit on one half in "
        "time, J_r on the other, both ways, mean (when both half-fits gave a non-degenerate "
        "estimate). Meaningful (for RB %): ended normally, J_r at most twice that of the "
        "least-squares sphere fit, and calibrated directions covering at least half of what "
        "the sphere fit's do (J_r alone rewards a degenerate answer that maps every sample "
        "near one point of the sphere). accuracy = 1 / mean J_r over meaningful fits; "
        "ratio = median of J_r / J_r of the sphere fit on the same data. Preprocessing "
        "`scale` divides by the mean norm (the review's); `centre` also removes the "
        "sphere-fit centre and radius.", "",
        f"![Figure 6 on real data]({figure_link})", "",
    ]
    for how, g in per_method.groupby("preprocess", sort=False):
        lines += [f"Preprocessing `{how}`:", "",
                  "| method | RB % | accuracy in | accuracy out | ratio in | ratio out | "
                  "n ok / n | time (ms) |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for r in g.itertuples(index=False):
            lines.append(f"| {r.label} | {_fmt(r.RB_pct, 3)} | {_fmt(r.accuracy_in)} | "
                         f"{_fmt(r.accuracy_out)} | {_fmt(r.median_ratio_in, 2)} | "
                         f"{_fmt(r.median_ratio_out, 2)} | "
                         f"{r.n_meaningful} / {r.n_applicable} | {_fmt(1e3 * r.tau_s, 2)} |")
        lines.append("")
    cross = per_rec[per_rec["cross_on"] != ""]
    if len(cross):
        lines += ["Across recordings of the same QMC5883L (fit on one, J_r on the other):", "",
                  "| preprocessing | method | fit on | J_r in | J_r on other | sphere fit in |",
                  "|---|---|---|---:|---:|---:|"]
        for r in cross[cross["meaningful"].astype(bool)].itertuples(index=False):
            lines.append(f"| {r.preprocess} | {r.algorithm} | {r.dataset} | {_fmt(r.J_r_in)} "
                         f"| {_fmt(r.J_r_cross)} | {_fmt(r.J_r_sphere_in)} |")
        lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------- command line


def _options(cfg, algorithms: Sequence[str]) -> dict:
    from omegaconf import OmegaConf

    from magbench.cli import UsageError

    options = OmegaConf.to_container(cfg.options, resolve=True) or {}
    out = {}
    for name, opts in options.items():
        if name not in algorithms:
            raise UsageError(f"options given for {name!r}, which is not among the selected "
                             f"algorithms ({', '.join(algorithms)})")
        bad = sorted(set(opts or {}) - set(get_method(name).option_names()))
        if bad:
            raise UsageError(f"unknown option(s) {', '.join(bad)} for {name}; it accepts: "
                             f"{', '.join(get_method(name).option_names()) or 'no options'}")
        out[name] = dict(opts or {})
    return out


def run_real(cfg) -> int:
    """``python -m magbench sweep=real``: the sweep, Figure 6 and the Markdown section."""
    from omegaconf import OmegaConf

    from magbench.cli import UsageError, check_integer, selected_algorithms
    from magbench.engine.plugins import load_plugins
    from magbench.plots_real import figure6

    try:
        load_plugins(cfg.get("plugins") or ())
        root = data_dir(cfg.get("data_dir"))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    sweep = cfg.sweep
    known = list_recordings(root)
    chosen = sweep.get("datasets", "all")
    chosen = known if chosen == "all" else [chosen] if isinstance(chosen, str) else list(chosen)
    unknown = [d for d in chosen if d not in known]
    if unknown or not chosen:
        raise UsageError(f"unknown recording(s) {', '.join(unknown) or '(none given)'} in "
                         f"{root}; expected 'all' or a list from: {', '.join(known)}")
    preprocess = sweep.get("preprocess", ["scale", "centre"])
    preprocess = [preprocess] if isinstance(preprocess, str) else list(preprocess)
    bad = [p for p in preprocess if p not in PREPROCESSING]
    if bad or not preprocess:
        raise UsageError(f"sweep.preprocess must be a list from {', '.join(PREPROCESSING)}, "
                         f"got {OmegaConf.to_container(sweep.preprocess)}")
    max_samples = check_integer(sweep.get("max_samples", DEFAULT_MAX_SAMPLES),
                                "sweep.max_samples", 8)
    ratio = sweep.get("coverage_ratio", 0.5)
    if isinstance(ratio, bool) or not isinstance(ratio, int | float) or not 0 <= ratio <= 1:
        raise UsageError(f"sweep.coverage_ratio must be a number in [0, 1], got {ratio!r}")
    factor = sweep.get("sphere_factor", 2.0)
    if isinstance(factor, bool) or not isinstance(factor, int | float) or not factor > 0:
        raise UsageError(f"sweep.sphere_factor must be a number > 0, got {factor!r}")
    if isinstance(cfg.n_jobs, bool) or not isinstance(cfg.n_jobs, int) or cfg.n_jobs == 0:
        raise UsageError(f"n_jobs must be a non-zero integer (-1 = every core), got "
                         f"{cfg.n_jobs!r}")
    # Gyro-aided methods too: they run on the recordings that have gyro (hmc5883l_sphere) and
    # give skipped rows, with the reason, on the others.
    algorithms = selected_algorithms(cfg, include_gyro=True)
    spec = RealSweepSpec(chosen, algorithms, tuple(preprocess), max_samples,
                         _options(cfg, algorithms), int(cfg.seed), cfg.get("call_timeout_s"),
                         float(ratio), float(factor))
    out_dir = Path(str(cfg.results_dir)) / str(sweep.name)
    if cfg.progress:
        print(f"sweep {sweep.name}: {len(chosen)} recordings x {len(algorithms)} methods x "
              f"{len(preprocess)} preprocessings x 3 fits ...", file=sys.stderr)
    trials, _, per_method = run_real_sweep(spec, root, out_dir, n_jobs=cfg.n_jobs)
    fig = figure6(per_method, pd.read_csv(out_dir / "real_summary.csv"))
    fig.savefig(out_dir / "fig6_real.png", dpi=120)
    write_text_atomic(real_report_section(out_dir.parent, "fig6_real.png") + "\n",
                      out_dir / "real.md")
    n_bad = int((~trials["ok"].astype(bool) & ~trials["skipped"].astype(bool)).sum())
    n_skip = int(trials["skipped"].astype(bool).sum())
    print(f"sweep {sweep.name}: {len(trials)} rows ({n_bad} not ok, {n_skip} skipped) -> "
          f"{out_dir}/real_trials.csv, real_summary.csv, fig6_real.csv/.png, real.md")
    return 0

