"""Flight logs: PX4 ULog (``.ulg``) and ArduPilot DataFlash (``.bin`` binary, ``.log`` text).

One compass at a time (``instance``); its samples set the time base, and every other stream
is interpolated onto their times, so a log gives the columns a CSV recording has:

==========================  ===========================================================
``t``                       seconds since the autopilot booted
``mx, my, mz``              the compass, in the log's units (PX4 gauss, ArduPilot mGauss)
``gx, gy, gz``              gyro, rad/s, vehicle body axes (FRD)
``ax, ay, az``              accelerometer, m/s^2, body axes (``-g`` at rest)
``qw, qx, qy, qz``          attitude, quaternion scalar first, body to world (NED)
``current``                 battery current, A
``throttle``                throttle demand, 0 to 1
``temperature``             degrees C: the compass's own (PX4), else the IMU's (ArduPilot)
==========================  ===========================================================

A stream the log lacks is absent; a sample that falls outside another stream's span, or in a
gap of it longer than :data:`GAP_INTERVALS` of that stream's median interval, gets NaN in
that stream's columns (never a value carried across a gap). Vectors are interpolated
linearly, the attitude quaternion by normalised linear interpolation along the shorter arc.

The sources, and their conventions:

- PX4 ULog (pyulog): ``sensor_mag`` (multi-instance; ``x, y, z`` in gauss, uncalibrated and
  before ``CAL_MAGn_ROT``; ``temperature``; ``device_id``), ``sensor_combined``
  (``gyro_rad``, ``accelerometer_m_s2``; else ``sensor_gyro`` / ``sensor_accel`` instance 0),
  ``vehicle_attitude.q`` ("rotation from the FRD body frame to the NED earth frame", Hamilton,
  ``q[0]`` the scalar: PX4 ``msg/VehicleAttitude.msg``, so taken as it is),
  ``battery_status.current_a`` (negative means unknown), ``actuator_controls_0.control[3]``.
  Times are ``timestamp_sample`` where logged, else ``timestamp`` (microseconds).
- ArduPilot DataFlash (pymavlink's ``DFReader``): ``MAG`` (instance ``I``; older logs
  ``MAG2``, ``MAG3``). ``MagX..Z`` is the field after the firmware's own correction,
  ``M (raw + OFS) + MOT`` (``AP_Compass_Backend::correct_field``); this reader returns
  ``Mag - Ofs - MO``, which is the raw field when ``COMPASS_DIA``/``ODI`` are at their
  defaults (1, 0), as MAVExplorer's magfit does. ``IMU`` instance 0 (``GyrX..``,
  ``AccX..``, ``T``), ``ATT`` (``Roll, Pitch, Yaw`` in degrees, body to NED as
  ``Matrix3::from_euler``, converted to the quaternion), ``BAT`` instance 0 (``Curr``),
  ``CTUN.ThO``. Times are ``TimeUS``.

The body axes are the vehicle's: they are the compass's own when its mounting rotation is
none (:mod:`magbench.core.mounting` detects it).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from magbench.core.files import not_a_file
from magbench.core.quaternions import blocks, matrix_to_quat
from magbench.core.rotations import euler_zyx_to_matrix

if TYPE_CHECKING:     # DataFlash logs and table() only: calibrate of a CSV needs no pandas
    import pandas as pd

__all__ = ["EXTRA_COLUMNS", "GAP_INTERVALS", "LOG_COLUMNS", "LOG_SUFFIXES", "MIN_LOG_SAMPLES",
           "FlightLog", "align", "is_log", "log_units", "rate_hz", "read_log"]

#: File suffixes read as flight logs.
LOG_SUFFIXES = (".ulg", ".bin", ".log")

#: Optional time-aligned columns beside the gyro (``Recording.extra``; a CSV may have them
#: too): accelerometer m/s^2, attitude quaternion (scalar first, body to world), current A,
#: throttle 0-1, temperature C.
EXTRA_COLUMNS = ("ax", "ay", "az", "qw", "qx", "qy", "qz", "current", "throttle", "temperature")

#: The columns a log adds to ``t, mx, my, mz`` (when it has the stream), in this order.
LOG_COLUMNS = ("gx", "gy", "gz", *EXTRA_COLUMNS)

#: A stream's value is interpolated only between two of its samples at most this many of its
#: median intervals apart (a longer gap gives NaN).
GAP_INTERVALS = 5.0

#: Fewest compass samples a calibration from a log accepts: each half in time must hold the
#: full model's minimum (10), since the verdict is held out.
MIN_LOG_SAMPLES = 20


def log_units(path: Path | str) -> str:
    """The compass unit of a log by its kind: PX4 logs gauss, ArduPilot milligauss."""
    return "gauss" if Path(path).suffix.lower() == ".ulg" else "milligauss"


def is_log(path: Path | str) -> bool:
    """Whether ``path`` is read as a flight log (by its suffix)."""
    return Path(path).suffix.lower() in LOG_SUFFIXES


@dataclass
class Stream:
    """One logged stream: times (s, increasing) and values (n, d)."""

    t: np.ndarray
    values: np.ndarray

    def clean(self) -> Stream:
        """Sorted by time, repeated times and rows with a non-finite time dropped."""
        keep = np.isfinite(self.t)
        if keep.all() and (self.t.size < 2 or bool((self.t[1:] > self.t[:-1]).all())):
            return Stream(self.t, self.values)      # the usual log: no copies of its rows
        t, v = self.t[keep], self.values[keep]
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        first = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)
        return Stream(t[first], v[first])


@dataclass
class FlightLog:
    """The streams of one log, before alignment.

    Attributes
    ----------
    path : Path
    kind : str
        ``ulog`` or ``dataflash``.
    mags : dict
        ``instance -> Stream`` of the compasses (values: x, y, z and, PX4, temperature).
    devices : dict
        ``instance -> device id`` where logged.
    units : str
        The compass's units.
    streams : dict
        ``group -> (columns, Stream)`` for the gyro, accelerometer, attitude, current,
        throttle and board temperature.
    notes : list of str
        What the reader left out or could not read (a cut file, compass lines dropped for
        missing fields, a stream whose format lacks its fields), one sentence each: the
        commands say them.
    """

    path: Path
    kind: str
    mags: dict[int, Stream]
    units: str
    devices: dict[int, int] = field(default_factory=dict)
    streams: dict[str, tuple[tuple[str, ...], Stream]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """The compasses, e.g. ``0 (device 396809, 6 samples), 1 (...)``."""
        parts = []
        for i, s in sorted(self.mags.items()):
            dev = f"device {self.devices[i]}, " if i in self.devices else ""
            parts.append(f"{i} ({dev}{len(s.t)} samples)")
        return ", ".join(parts)

    def choose(self, instance: object, min_samples: int = 1) -> int:
        """The compass instance to read.

        Raises
        ------
        ValueError
            No compass; an unknown instance; several and none named (listed); or every
            candidate shorter than ``min_samples``.
        """
        name = self.path.name
        instance = _instance_number(instance, name)
        if not self.mags:
            raise ValueError(f"{name}: no magnetometer stream in this {self.kind} log "
                             f"({'sensor_mag' if self.kind == 'ulog' else 'MAG'} messages)")
        if instance is not None and int(instance) not in self.mags:
            raise ValueError(f"{name}: no compass instance {instance}; instances: "
                             f"{self.describe()}")
        pool = [int(instance)] if instance is not None else sorted(self.mags)
        if all(len(self.mags[i].t) < min_samples for i in pool):
            counts = " and ".join(str(len(self.mags[i].t)) for i in pool)
            what = "stream is" if len(pool) == 1 else "streams are"
            raise ValueError(f"{name}: the magnetometer {what} too short to calibrate: {counts} "
                             f"samples (instance{'' if len(pool) == 1 else 's'} "
                             f"{', '.join(map(str, pool))}); at least {min_samples} are needed "
                             "(log the compass at its full rate over a calibration manoeuvre)")
        if len(pool) > 1:
            raise ValueError(f"{name} has {len(pool)} compasses; choose one with instance=N: "
                             f"{self.describe()}")
        return pool[0]

    def table(self, instance: int) -> pd.DataFrame:
        """The compass ``instance`` and every other stream on its times (module notes): the
        :meth:`columns` as a DataFrame."""
        import pandas as pd

        return pd.DataFrame(self.columns(instance))

    def columns(self, instance: int) -> dict[str, np.ndarray]:
        """The columns of :meth:`table` (name -> array), without pandas."""
        mag = self.mags[instance]
        out = {"t": mag.t, "mx": mag.values[:, 0], "my": mag.values[:, 1],
               "mz": mag.values[:, 2]}
        extra: dict[str, np.ndarray] = {}
        for group, (columns, stream) in self.streams.items():
            values = align(mag.t, stream, quaternion=group == "attitude")
            if np.isfinite(values).any():           # a stream never measured is left out
                extra.update(zip(columns, values.T, strict=True))
        if mag.values.shape[1] > 3 and np.isfinite(mag.values[:, 3]).any():
            extra["temperature"] = mag.values[:, 3]       # the compass's own, preferred
        out.update((c, extra[c]) for c in LOG_COLUMNS if c in extra)
        return out


def _instance_number(value: object, name: str) -> int | None:
    """``instance`` as a compass number (``1``, ``"1"``, ``1.0``), or None if unset."""
    if value is None:
        return None
    try:
        number = float(str(value).strip())
    except ValueError:
        number = math.nan
    if not (number.is_integer() and number >= 0):
        raise ValueError(f"{name}: instance must be a compass number of the log (0, 1, ...), "
                         f"got {value!r}")
    return int(number)


def align(t: np.ndarray, stream: Stream, *, quaternion: bool = False) -> np.ndarray:
    """``stream`` linearly interpolated at times ``t`` (NaN outside it and across gaps).

    A gap is two consecutive samples more than :data:`GAP_INTERVALS` median intervals apart.
    ``quaternion``: rows are unit quaternions; their signs are made continuous first and the
    result is normalised (normalised linear interpolation along the shorter arc).
    """
    s = stream.clean()
    out = np.full((len(t), s.values.shape[1]), np.nan)
    if len(s.t) < 2:
        return out
    v = s.values.astype(float)
    if quaternion:
        flips = np.cumprod(np.where(np.einsum("ki,ki->k", v[1:], v[:-1]) < 0, -1.0, 1.0))
        v = v * np.concatenate([[1.0], flips])[:, None]
    t = np.asarray(t)
    limit = GAP_INTERVALS * float(np.median(np.diff(s.t)))
    # a block of rows at a time: each row's value depends on its own time only, and the
    # whole log's interpolation held several (K, columns) temporaries beside ``out``
    for rows in blocks(len(t)):
        tb = t[rows]
        j = np.searchsorted(s.t, tb, side="right")      # s.t[j-1] <= t < s.t[j]
        inside = (j > 0) & (j < len(s.t)) | (tb == s.t[-1])
        j = np.clip(j, 1, len(s.t) - 1)
        dt = s.t[j] - s.t[j - 1]
        inside &= dt <= limit
        w = ((tb - s.t[j - 1]) / dt)[:, None]
        values = (1 - w) * v[j - 1] + w * v[j]
        if quaternion:
            values /= np.linalg.norm(values, axis=1, keepdims=True)
        out[rows][inside] = values[inside]
    return out


def read_log(path: Path | str) -> FlightLog:
    """Read a ULog or DataFlash log's streams (by suffix).

    Raises
    ------
    ValueError
        An unknown suffix, a file that is not such a log, or a missing reader package (the
        ``logs`` extra); one line.
    """
    path = Path(path)
    problem = not_a_file(path, "a flight log (.ulg, .bin or .log)")
    if problem:
        raise ValueError(problem)
    suffix = path.suffix.lower()
    readers: dict[str, Callable[[Path], FlightLog]] = {".ulg": _read_ulog, ".bin": _read_dataflash,
                                                       ".log": _read_dataflash}
    if suffix not in readers:
        raise ValueError(f"{path.name}: not a flight log ({', '.join(LOG_SUFFIXES)})")
    return readers[suffix](path)


def _need(module: str, package: str) -> object:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ValueError(f"reading this log needs {package}: pip install 'magbench[logs]' (or "
                         f"pip install {package})") from None


ULOG_TOPICS = ["sensor_mag", "sensor_combined", "sensor_accel", "sensor_gyro",
               "vehicle_attitude", "battery_status", "actuator_controls_0"]


class _ShortReads(io.BufferedReader):
    """A log opened for pyulog, which stops silently where a message is cut short: ``cut``
    says whether a read came back shorter than asked (other than a clean end, an empty read
    of the next message's 3-byte header)."""

    def __init__(self, path: Path) -> None:
        super().__init__(io.FileIO(path, "rb"))
        self.cut = False

    def read(self, size: int | None = -1) -> bytes:
        data = super().read(size)
        if size is not None and 0 <= len(data) < size and (data or size != 3):
            self.cut = True
        return data


def _read_ulog(path: Path) -> FlightLog:
    pyulog = _need("pyulog", "pyulog")
    try:
        with contextlib.redirect_stdout(io.StringIO()), \
                contextlib.redirect_stderr(io.StringIO()), \
                _ShortReads(path) as handle:                 # pyulog prints its warnings
            ulog = pyulog.ULog(handle, ULOG_TOPICS)
    except Exception as exc:        # pyulog raises bare exceptions on a corrupt file
        raise ValueError(f"{path.name}: cannot read as ULog ({exc})") from None
    notes = []
    if handle.cut:
        notes.append(f"{path.name} ends inside a message (the file is cut: a copy stopped "
                     "early, or the logger lost power); its samples up to there are read")
    elif getattr(ulog, "file_corruption", False):
        notes.append(f"{path.name} holds corrupt bytes that the reader skipped")
    data = {(d.name, d.multi_id): d.data for d in ulog.data_list}

    def times(d: dict) -> np.ndarray:
        return np.asarray(d.get("timestamp_sample", d["timestamp"]), dtype=float) / 1e6

    def cols(d: dict, names: list[str]) -> np.ndarray:
        # filled a column at a time: no float copy of every field beside the stacked array
        out = np.empty((len(d["timestamp"]), len(names)))
        for j, n in enumerate(names):
            out[:, j] = d[n] if n in d else np.nan
        return out

    mags, devices = {}, {}
    for (name, i), d in data.items():
        if name == "sensor_mag":
            mags[i] = Stream(times(d), cols(d, ["x", "y", "z", "temperature"])).clean()
            if "device_id" in d and len(d["device_id"]):
                devices[i] = int(d["device_id"][0])
    log = FlightLog(path, "ulog", mags, "gauss", devices, notes=notes)
    combined = data.get(("sensor_combined", 0))
    if combined is not None:
        t = times(combined)
        log.streams["gyro"] = (("gx", "gy", "gz"), Stream(t, cols(
            combined, [f"gyro_rad[{i}]" for i in range(3)])))
        t_acc = t + np.asarray(combined.get("accelerometer_timestamp_relative", 0)) / 1e6
        log.streams["accel"] = (("ax", "ay", "az"), Stream(t_acc, cols(
            combined, [f"accelerometer_m_s2[{i}]" for i in range(3)])))
    else:
        for topic, group, names in (("sensor_gyro", "gyro", ("gx", "gy", "gz")),
                                    ("sensor_accel", "accel", ("ax", "ay", "az"))):
            if (topic, 0) in data:
                d = data[(topic, 0)]
                log.streams[group] = (names, Stream(times(d), cols(d, ["x", "y", "z"])))
    if ("vehicle_attitude", 0) in data:
        d = data[("vehicle_attitude", 0)]
        log.streams["attitude"] = (("qw", "qx", "qy", "qz"),
                                   Stream(times(d), cols(d, [f"q[{i}]" for i in range(4)])))
    if ("battery_status", 0) in data:
        d = data[("battery_status", 0)]
        current = cols(d, ["current_a"])
        current[current < 0] = np.nan                      # -1: not measured
        log.streams["current"] = (("current",), Stream(times(d), current))
    if ("actuator_controls_0", 0) in data:
        d = data[("actuator_controls_0", 0)]
        log.streams["throttle"] = (("throttle",), Stream(times(d), cols(d, ["control[3]"])))
    return log


#: DataFlash messages read and the fields taken from each.
DATAFLASH_TYPES = ["MAG", "MAG2", "MAG3", "IMU", "ATT", "BAT", "CTUN"]


@contextlib.contextmanager
def _held_back() -> Iterator[io.StringIO]:
    """Standard output and error, the file descriptors themselves, go to a buffer for the
    block (pymavlink's compiled indexer prints a line per unreadable byte from C); the text
    is in the yielded buffer afterwards."""
    text = io.StringIO()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile(mode="w+b") as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
                yield text
        finally:
            for stream in (sys.stdout, sys.stderr):
                stream.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            text.write(sink.read().decode(errors="replace"))
            text.seek(0)


#: The fields read from each DataFlash message (others are never kept: a long log's messages
#: as dicts of every field took 20 times the file's size in memory).
DATAFLASH_FIELDS = {
    **{m: ("TimeUS", "I", "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ", "MOX", "MOY", "MOZ")
       for m in ("MAG", "MAG2", "MAG3")},
    "IMU": ("TimeUS", "I", "Inst", "Instance", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ",
            "T"),
    "ATT": ("TimeUS", "Roll", "Pitch", "Yaw"),
    "BAT": ("TimeUS", "I", "Inst", "Instance", "Curr"),
    "CTUN": ("TimeUS", "ThO"),
}


#: The compass field this reader returns (module notes), ``Mag - Ofs - MO`` per axis:
#: combined as each message is read, so that a long log's nine compass fields (72 bytes a
#: sample) are never all kept.
RAW_FIELDS = {f"Raw{a}": (f"Mag{a}", f"Ofs{a}", f"MO{a}") for a in "XYZ"}


class _Columns:
    """One message type's wanted fields as growing float arrays (8 bytes a value); a
    compass's ``Mag``, ``Ofs`` and ``MO`` fields are kept as their :data:`RAW_FIELDS`."""

    def __init__(self, name: str, path: Path, columns: list[str], fmt: str) -> None:
        from array import array

        self.name, self.path = name, path
        self.all = list(columns)
        self.fields = [f for f in DATAFLASH_FIELDS[self.name] if f in self.all]
        self.format = dict(zip(self.all, fmt, strict=False))
        self.combine = name in ("MAG", "MAG2", "MAG3") and not self.lacking(MAG_FIELDS)
        kept = [f for f in self.fields
                if not (self.combine and any(f in parts for parts in RAW_FIELDS.values()))]
        self.values = {f: array("d") for f in kept + (list(RAW_FIELDS) if self.combine else [])}

    @classmethod
    def of(cls, msg: object, path: Path) -> _Columns:
        """The columns of ``msg``'s type (a pymavlink message)."""
        return cls(msg.get_type(), path, list(getattr(msg, "_fieldnames", [])),
                   getattr(msg.fmt, "format", ""))

    def add(self, msg: object) -> None:
        row = {}
        for name in self.fields:
            value = getattr(msg, name, math.nan)
            try:
                row[name] = float(value)
            except (TypeError, ValueError):
                raise ValueError(
                    f"{self.path.name}: malformed DataFlash FMT: {self.name}.{name} holds "
                    f"{str(value)[:20]!r}, not a number (format character "
                    f"{self.format.get(name, '?')!r})") from None
        self.extend({k: [v] for k, v in row.items()})

    def extend(self, row: dict) -> None:
        """Append values (``field -> sequence of floats``, every wanted field)."""
        if self.combine:
            row = dict(row)
            for raw, (mag, ofs, mo) in RAW_FIELDS.items():
                # the same float operations, in the same order, as on whole arrays before
                value = np.asarray(row.pop(mag), dtype=float)
                value = value - (np.asarray(row.pop(ofs), dtype=float) if ofs in row else 0.0)
                row[raw] = value - (np.asarray(row.pop(mo), dtype=float) if mo in row
                                    else 0.0)
        for name, values in self.values.items():
            values.frombytes(np.ascontiguousarray(row[name], dtype=float).tobytes())

    def __len__(self) -> int:
        return len(next(iter(self.values.values()))) if self.values else 0

    def __contains__(self, name: str) -> bool:
        return name in self.values

    def __getitem__(self, name: str) -> np.ndarray:
        return np.frombuffer(self.values[name], dtype=float)

    def take(self, name: str) -> np.ndarray:
        """The field ``name``, no longer held here (freed when the caller drops it)."""
        return np.frombuffer(self.values.pop(name), dtype=float)

    def lacking(self, names: tuple[str, ...]) -> list[str]:
        return [n for n in names if n not in self.fields]

    def rows(self, keep: np.ndarray) -> _Columns:
        out = object.__new__(_Columns)
        out.name, out.path, out.all, out.fields, out.format, out.combine = (
            self.name, self.path, self.all, self.fields, self.format, self.combine)
        out.values = {f: self[f][keep] for f in self.values}
        return out


class _Unusual(Exception):
    """Something in a binary log that :func:`_binary_rows` leaves to pymavlink (corrupt
    bytes, a message type without a format, a format it does not read)."""


#: Bytes of a binary log read at a time by :func:`_binary_rows`.
BINARY_CHUNK = 1 << 22

#: NumPy types of the DataFlash format characters read as numbers (pymavlink's
#: ``FORMAT_TO_STRUCT``, with its multipliers); text and arrays are left to pymavlink.
_DF_NUMBERS = {"b": ("i1", None), "B": ("u1", None), "h": ("<i2", None), "H": ("<u2", None),
               "i": ("<i4", None), "I": ("<u4", None), "f": ("<f4", None), "d": ("<f8", None),
               "g": ("<f2", None), "q": ("<i8", None), "Q": ("<u8", None), "M": ("i1", None),
               "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01), "E": ("<u4", 0.01),
               "L": ("<i4", 1.0e-7)}
_DF_SIZES = {"n": 4, "N": 16, "Z": 64, "a": 64}


def _null_term(raw: bytes) -> str:
    return raw.decode(errors="backslashreplace").split("\0", 1)[0]


def _binary_rows(path: Path) -> dict[str, _Columns]:
    """The wanted messages of a binary log, read by NumPy a chunk of :data:`BINARY_CHUNK`
    bytes at a time: the messages are walked by the lengths their ``FMT`` gives and each
    wanted type's records are decoded together by a structured dtype, so memory is the
    kept fields and one chunk (pymavlink indexes every message of every type first, and
    keeps the whole file mapped). Values are pymavlink's, multipliers included.

    Raises
    ------
    _Unusual
        Anything but a clean log (the caller reads such a file with pymavlink, whose
        messages and errors it keeps).
    """
    lengths = [0] * 256
    lengths[0x80] = 89
    decode: dict[int, tuple[_Columns, np.dtype, dict[str, float | None]]] = {}
    formats: dict[int, bytes] = {}
    rows: dict[str, _Columns] = {}
    tail = b""
    with open(path, "rb") as handle:
        while True:
            block = handle.read(BINARY_CHUNK)
            data = tail + block
            found: dict[int, list[int]] = {}
            ofs, size = 0, len(data)
            while ofs + 3 <= size:
                if data[ofs] != 0xA3 or data[ofs + 1] != 0x95:
                    raise _Unusual(f"no message header at byte {ofs}")
                kind = data[ofs + 2]
                length = lengths[kind]
                if length < 3:
                    raise _Unusual(f"message type {kind} has no format")
                if ofs + length > size:
                    break                   # continued in the next chunk
                if kind == 0x80:
                    body = data[ofs + 3:ofs + 89]
                    if formats.get(body[0], body) != body:
                        raise _Unusual("a format defined twice")
                    formats[body[0]] = body
                    lengths[body[0]] = body[1]
                    name = _null_term(body[2:6])
                    if name in DATAFLASH_TYPES:
                        decode[body[0]] = _wanted_format(path, name, body, rows)
                elif kind in decode:
                    found.setdefault(kind, []).append(ofs)
                ofs += length
            raw = np.frombuffer(data, np.uint8)
            for kind, offsets in found.items():
                columns, dtype, mults = decode[kind]
                body = np.arange(3, dtype.itemsize + 3)
                for start in range(0, len(offsets), 1 << 12):     # small index arrays
                    at = np.asarray(offsets[start:start + (1 << 12)])
                    records = raw[at[:, None] + body].view(dtype)[:, 0]
                    values = {}
                    for name, mult in mults.items():
                        column = records[name].astype(float)
                        if mult is not None:        # as pymavlink: divide by 1/mult below 1
                            column = column / (1 / mult) if 0.0 < mult < 1.0 else column * mult
                        values[name] = column
                    columns.extend(values)
            del raw
            tail = data[ofs:]
            if not block:
                break
    if len(tail) >= 3 and not (tail[0] == 0xA3 and tail[1] == 0x95
                               and len(tail) < lengths[tail[2]]):
        raise _Unusual("bytes after the last message")      # a cut last message is dropped
    return rows


def _wanted_format(path: Path, name: str, body: bytes, rows: dict[str, _Columns]
                   ) -> tuple[_Columns, np.dtype, dict[str, float | None]]:
    """The columns, record dtype and multipliers of a wanted message type's ``FMT`` body."""
    fmt = _null_term(body[6:22])
    columns = _null_term(body[22:86]).split(",")
    columns = [] if columns == [""] else columns
    if len(columns) != len(fmt) or len(set(columns)) != len(columns):
        raise _Unusual(f"{name}: its format and columns disagree")
    names, offsets, types, position = [], [], [], 0
    for column, char in zip(columns, fmt, strict=True):
        if char in _DF_NUMBERS:
            names.append(column)
            offsets.append(position)
            types.append(_DF_NUMBERS[char][0])
            position += np.dtype(types[-1]).itemsize
        elif char in _DF_SIZES:
            position += _DF_SIZES[char]
        else:
            raise _Unusual(f"{name}: format character {char!r}")
    if 3 + position != body[1]:
        raise _Unusual(f"{name}: its length is not its format's")
    if name in rows:
        raise _Unusual(f"{name} defined twice")
    rows[name] = _Columns(name, path, columns, fmt)
    wanted = rows[name].fields
    if any(fmt[columns.index(f)] not in _DF_NUMBERS for f in wanted):
        raise _Unusual(f"{name}: a wanted field is text")
    dtype = np.dtype({"names": names, "formats": types, "offsets": offsets,
                      "itemsize": position})
    return rows[name], dtype, {f: _DF_NUMBERS[fmt[columns.index(f)]][1] for f in wanted}


#: Bytes of a text log read at a time by :func:`_text_rows` (its lines split into fields
#: take some ten times the bytes while a chunk is parsed).
TEXT_CHUNK = 1 << 20

#: Message types pymavlink's text reader parses besides the wanted ones (``recv_match``
#: adds them): a short line of any of them makes it return the next line instead.
_TEXT_VISITED = frozenset(DATAFLASH_TYPES) | {"MODE", "MSG", "PARM", "STAT", "ORGN", "VER"}

#: Format characters pymavlink's text reader converts by ``int`` (``M`` stays text, read by
#: ``float``); the others by ``float``, with no multiplier in a text log.
_TEXT_INTS = frozenset("bBhHiIqQ")


def _text_rows(path: Path) -> dict[str, _Columns]:
    """The wanted messages of a text log (``NAME, v1, v2, ...`` lines after their ``FMT``
    lines), a chunk of :data:`TEXT_CHUNK` bytes at a time: each wanted type's lines are
    split and converted together, so memory is the kept fields and one chunk (pymavlink
    maps the file and indexes every line of every type first). Values are pymavlink's:
    ``int`` or ``float`` of the field's text by its format character, then ``float``.

    Raises
    ------
    _Unusual
        Anything but a clean log: a first line other than ``FMT, ``, bytes that are not
        ASCII, a malformed or repeated ``FMT`` (or one with characters pymavlink lacks), a
        line of a type pymavlink visits that has no format yet or fewer fields than its
        format (it then returns the next line, at times twice), a wanted field that is
        text or does not convert, a line in the last 16 bytes (pymavlink never indexes
        those). The caller reads such a file with pymavlink, whose messages and errors it
        keeps.
    """
    size = path.stat().st_size
    formats: dict[str, tuple[int, list[tuple[str, int, Callable]]]] = {"FMT": (5, [])}
    rows: dict[str, _Columns] = {}
    with open(path, "rb") as handle:
        if handle.read(5) != b"FMT, " or size <= 16:
            raise _Unusual("not a plain text log")
        handle.seek(max(0, size - 17))
        end = handle.read()
        if any(end[i] == 0x0A and end[i + 1:].split(b"\n", 1)[0].strip()
               for i in range(len(end) - 1)):
            raise _Unusual("a line in the last 16 bytes")
        handle.seek(0)
        tail = b""
        while True:
            block = handle.read(TEXT_CHUNK)
            if not block:
                break           # pymavlink reads no message from a last line without its end
            data = tail + block
            cut = data.rfind(b"\n") + 1
            if not cut:
                tail = data
                continue
            try:
                text = data[:cut].decode("ascii")
            except UnicodeDecodeError:
                raise _Unusual("bytes that are not ASCII") from None
            tail = data[cut:]
            found: dict[str, list[list[str]]] = {}
            for line in text.split("\n"):
                key = line[:4].split(",")[0] if len(line) >= 4 else ""
                if key == "FMT":
                    _text_format(path, line, formats, rows)
                elif key in _TEXT_VISITED:
                    fields = line.rstrip().split(", ")
                    if fields[0] != key or key not in formats \
                            or len(fields) < formats[key][0] + 1:
                        raise _Unusual(f"a {key} line pymavlink does not read as it stands")
                    if key in rows:
                        found.setdefault(key, []).append(fields)
            for kind, lines in found.items():
                columns = {}
                for name, index, convert in formats[kind][1]:
                    try:
                        columns[name] = np.fromiter(
                            (convert(fields[index]) for fields in lines), float, len(lines))
                    except (ValueError, OverflowError):
                        raise _Unusual(f"{kind}.{name} does not convert") from None
                rows[kind].extend(columns)
            del text, found
    return rows


def _as_int(value: str) -> float:
    return float(int(value))


def _text_format(path: Path, line: str, formats: dict, rows: dict[str, _Columns]) -> None:
    """Read one ``FMT`` line of a text log into ``formats`` (name -> number of fields and
    the wanted ones' ``(name, index, converter)``) and ``rows``."""
    fields = line.rstrip().split(", ")
    if fields[0] != "FMT" or len(fields) != 6:
        raise _Unusual("a malformed FMT line")
    name, fmt, columns = fields[3], fields[4], fields[5].split(",")
    columns = [] if columns == [""] else columns
    if (not fields[1].strip().isdigit() or not fields[2].strip().isdigit()
            or len(columns) != len(fmt) or len(set(columns)) != len(columns)
            or any(c not in _DF_NUMBERS and c not in _DF_SIZES for c in fmt)):
        raise _Unusual(f"{name}: a format pymavlink may not read as it stands")
    if name == "FMT":
        if fmt != "BBnNZ":
            raise _Unusual("FMT redefined")
        return
    if name in formats:
        raise _Unusual(f"{name} defined twice")
    wanted: list[tuple[str, int, Callable]] = []
    if name in DATAFLASH_TYPES:
        rows[name] = _Columns(name, path, columns, fmt)
        for f in rows[name].fields:
            char = fmt[columns.index(f)]
            if char not in _DF_NUMBERS:
                raise _Unusual(f"{name}.{f} is text")
            wanted.append((f, columns.index(f) + 1, _as_int if char in _TEXT_INTS else float))
    formats[name] = (len(fmt), wanted)


def _dataflash_rows(path: Path) -> tuple[dict[str, _Columns], bool]:
    """Every wanted message's wanted fields, per type, and whether every wanted line was
    read as it stands: a clean binary log by :func:`_binary_rows`, a clean text log by
    :func:`_text_rows`, anything else by pymavlink, whose own messages (a line per
    unreadable byte) are held back; a file with no readable message is one error, a field
    that holds text where a number belongs another."""
    with contextlib.suppress(_Unusual):
        rows = (_binary_rows if path.suffix.lower() == ".bin" else _text_rows)(path)
        if rows:
            return {k: v for k, v in rows.items() if len(v)}, True
    return _pymavlink_rows(path), False


def _pymavlink_rows(path: Path) -> dict[str, _Columns]:
    """:func:`_dataflash_rows` by pymavlink's ``DFReader``."""
    reader = _need("pymavlink.DFReader", "pymavlink")
    cls = reader.DFReader_binary if path.suffix.lower() == ".bin" else reader.DFReader_text
    rows: dict[str, _Columns] = {}
    try:
        with _held_back() as chatter:
            log = cls(str(path), zero_time_base=False)
            try:
                while (msg := log.recv_match(type=DATAFLASH_TYPES)) is not None:
                    kind = msg.get_type()
                    if kind not in rows:
                        rows[kind] = _Columns.of(msg, path)
                    rows[kind].add(msg)
            finally:
                with contextlib.suppress(Exception):
                    log.close()
    except ValueError as exc:
        if "malformed DataFlash FMT" in str(exc):
            raise
        raise ValueError(f"{path.name}: cannot read as a DataFlash log "
                         f"({' '.join(str(exc).split()) or type(exc).__name__})") from None
    except Exception as exc:        # pymavlink raises bare exceptions on a corrupt file
        raise ValueError(f"{path.name}: cannot read as a DataFlash log "
                         f"({' '.join(str(exc).split()) or type(exc).__name__})") from None
    if not rows and "bad header" in chatter.read():
        raise ValueError(f"{path.name}: not a DataFlash log (no valid message header; expected "
                         "ArduPilot's binary .bin or text .log)")
    return rows


def _text_lines(path: Path, names: tuple[str, ...]) -> int:
    """Lines of a text DataFlash log that start with one of the message ``names``, counted
    in blocks (the reader drops a line with fewer fields than its format, without a word)."""
    marks = [b"\n" + n.encode() + b"," for n in names]
    count, tail = 0, b"\n"
    with open(path, "rb") as handle:
        while block := handle.read(1 << 24):
            data = tail + block
            count += sum(data.count(m) for m in marks)
            tail = data[-8:]
            # a mark cut across the boundary is found in tail + next block, never twice
            count -= sum(tail.count(m) for m in marks)
    return count + sum(tail.count(m) for m in marks)


def _instance(columns: _Columns, instance: int = 0) -> _Columns | None:
    """The rows of one instance when the message carries an instance field."""
    if not len(columns):
        return None
    key = next((k for k in ("I", "Inst", "Instance") if k in columns), None)
    if key is None:
        return columns
    keep = columns[key] == instance
    return columns.rows(keep) if keep.any() else None


MAG_FIELDS = ("TimeUS", "MagX", "MagY", "MagZ")


def _read_dataflash(path: Path) -> FlightLog:
    rows, clean = _dataflash_rows(path)
    mags: dict[int, Stream] = {}
    notes: list[str] = []
    parts: list[tuple[int, _Columns]] = []
    for message in ("MAG", "MAG2", "MAG3"):
        if message not in rows or not len(rows[message]):
            continue
        columns = rows[message]
        lacking = columns.lacking(MAG_FIELDS)
        if lacking:
            raise ValueError(f"{path.name}: malformed DataFlash FMT: {message} has no field "
                             f"{', '.join(lacking)} (its fields: {', '.join(columns.all)}); "
                             f"expected {', '.join(MAG_FIELDS)}")
        if message == "MAG" and "I" in columns:
            numbers = np.unique(columns["I"])
            # one compass needs no copy of its rows
            parts += [(int(i), columns if numbers.size == 1 else columns.rows(columns["I"] == i))
                      for i in numbers]
        else:
            parts.append((0 if message == "MAG" else int(message[-1]) - 1, columns))
    if path.suffix.lower() == ".log" and parts and not clean:     # clean: no line dropped
        names = tuple(k for k in ("MAG", "MAG2", "MAG3") if k in rows)
        # pymavlink's text reader returns the message after a dropped line twice: distinct
        # (time, instance) rows are what it read.
        read = sum(len(np.unique(np.column_stack(
            [rows[k]["TimeUS"], rows[k]["I"] if "I" in rows[k] else 0 * rows[k]["TimeUS"]]),
            axis=0)) for k in names)
        dropped = _text_lines(path, names) - read
        if dropped > 0:
            notes.append(f"{path.name}: {dropped} compass line(s) dropped (fewer fields than "
                         "their format lists)")
    for message in ("MAG", "MAG2", "MAG3"):      # in ``parts``: freed as they are read
        rows.pop(message, None)
    while parts:            # each compass's fields freed as its stream is built
        i, f = parts.pop(0)
        t = f.take("TimeUS") / 1e6
        f.values.pop("I", None)
        raw = np.empty((len(t), 3))                                 # Mag - Ofs - MO
        for j, name in enumerate(RAW_FIELDS):
            raw[:, j] = f.take(name)
        mags[i] = Stream(t, raw).clean()
        del f, t, raw
    log = FlightLog(path, "dataflash", mags, "milligauss", notes=notes)
    for message, group, names, fields in (
            ("IMU", "gyro", ("gx", "gy", "gz"), ("GyrX", "GyrY", "GyrZ")),
            ("IMU", "accel", ("ax", "ay", "az"), ("AccX", "AccY", "AccZ")),
            ("IMU", "temperature", ("temperature",), ("T",)),
            ("ATT", "attitude", ("qw", "qx", "qy", "qz"), ("Roll", "Pitch", "Yaw")),
            ("BAT", "current", ("current",), ("Curr",)),
            ("CTUN", "throttle", ("throttle",), ("ThO",))):
        frame = _instance(rows[message]) if message in rows else None
        if frame is None:
            continue
        lacking = frame.lacking(("TimeUS", *fields))
        if lacking:
            optional = message in ("BAT", "CTUN") and lacking == list(fields)
            if group != "temperature" and not optional:
                notes.append(f"{path.name}: {message} has no field {', '.join(lacking)}: its "
                             f"{group} stream is left out")
            continue
        values = np.column_stack([frame[c] for c in fields])
        if group == "attitude":
            angles = np.deg2rad(values)
            values = matrix_to_quat(euler_zyx_to_matrix(angles[:, 0], angles[:, 1],
                                                        angles[:, 2]))
        log.streams[group] = (names, Stream(frame["TimeUS"] / 1e6, values))
    return log


def rate_hz(t: np.ndarray) -> float:
    """Median sample rate of increasing times (nan with fewer than two)."""
    return float(1.0 / np.median(np.diff(t))) if len(t) > 1 else math.nan

