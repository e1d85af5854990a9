"""A live magnetometer stream, one message at a time: text lines and MAVLink messages.

Pure parsing (no port, no clock): :class:`LineParser` turns the lines a board prints on a serial
port (or a program writes to standard input) into samples, :func:`mavlink_sample` a MAVLink
message. ``python -m magbench capture`` (:mod:`magbench.cli.capture`) reads the port.

Text lines it accepts (numbers separated by commas, semicolons, tabs or spaces):

=======================================  ====================================================
``Raw:ax,ay,az,gx,gy,gz,mx,my,mz``       PJRC MotionCal's raw line: integers, the magnetometer
                                         the last three at 10 counts per uT (units ``0.1uT``)
``Uni:ax,ay,az,gx,gy,gz,mx,my,mz``       MotionCal's line in physical units: the magnetometer
                                         the last three, in uT
``mx my mz``                             three numbers: the magnetometer
``t mx my mz``                           four numbers: time in seconds, then the magnetometer
a header such as ``t,mx,my,mz,gx,...``   names the columns of the lines that follow (``mx``,
                                         ``my``, ``mz``; ``t`` or ``time``), so a CSV file can
                                         be played as it is
=======================================  ====================================================

Lines of five or more numbers without a header need ``columns=[i,j,k]`` (0-based positions of
the magnetometer). Once a line of ``n`` numbers gave a sample, a line of another count is a
broken line (a serial port opened in the middle of a line, a dropped byte): counted as garbage
and skipped, as is any line that parses as none of these, or holds a number that is not finite.

MAVLink (:func:`mavlink_sample`): one compass at a time, ``instance`` 0, 1 or 2. ``SCALED_IMU``,
``SCALED_IMU2`` and ``SCALED_IMU3`` carry compass 0, 1 and 2 in mgauss; ``HIGHRES_IMU`` the
compass of its ``id`` field (0 when absent) in gauss (its ``fields_updated`` bits 6-8 say
whether the magnetometer is new); ``RAW_IMU`` the compass of its ``id`` field in the sensor's
raw units, which the message does not state. A message whose three fields are all zero is a
vehicle without that compass.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["MAVLINK_TYPES", "LineParser", "Sample", "mavlink_sample"]


@dataclass(frozen=True)
class Sample:
    """One magnetometer sample: the device's time in seconds (None if it sends none) and the
    three components as received."""

    t: float | None
    m: tuple[float, float, float]


_SPLIT = re.compile(r"[,;\s]+")
#: MotionCal's prefixes with the magnetometer's unit (parse_units syntax).
_PREFIXES = {"raw:": "0.1uT", "uni:": "uT"}
_TIME_NAMES = ("t", "time", "timestamp", "time_s")
_AXIS_NAMES = (("mx", "magx", "mag_x", "x"), ("my", "magy", "mag_y", "y"),
               ("mz", "magz", "mag_z", "z"))


def _numbers(tokens: Sequence[str]) -> list[float] | None:
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        return None
    return values if all(math.isfinite(v) for v in values) else None


class LineParser:
    """Samples from text lines (module notes); counts what it skips.

    Parameters
    ----------
    columns : sequence of int, optional
        0-based positions of ``mx, my, mz`` in a line of numbers (``capture``'s ``columns``).

    Attributes
    ----------
    lines, samples, garbage : int
        Lines seen (blank ones excepted), samples returned, lines skipped as unparseable.
    units : str or None
        The unit the format states (``0.1uT`` for ``Raw:``, ``uT`` for ``Uni:``), else None.
    form : str
        What the lines were read as, for the view (``"Raw: (MotionCal)"``, ``"3 numbers"``...).
    widest : int
        The most numbers seen on one line that gave no sample (to say why, when none does).
    """

    def __init__(self, columns: Sequence[int] | None = None) -> None:
        self.columns = list(columns) if columns is not None else None
        self.lines = self.samples = self.garbage = self.widest = 0
        self.units: str | None = None
        self.form = ""
        self._header: tuple[int | None, list[int]] | None = None
        self._count: int | None = None
        self._prefix: str | None = None

    def parse(self, line: str | bytes) -> Sample | None:
        """The sample in ``line``, or None (a header, a blank line, or garbage: counted)."""
        if isinstance(line, bytes):
            line = line.decode("ascii", errors="replace")
        text = line.strip().strip("\x00")
        if not text:
            return None
        self.lines += 1
        sample = self._parse(text)
        if sample is None:
            return None
        self.samples += 1
        return sample

    def _parse(self, text: str) -> Sample | None:
        prefix = text[:4].lower()
        if prefix in _PREFIXES:
            values = _numbers([v for v in _SPLIT.split(text[4:].strip()) if v])
            if values is None or len(values) != 9 or self._prefix not in (None, prefix):
                return self._skip(values)
            self._prefix, self.units = prefix, _PREFIXES[prefix]
            self.form = f"{text[:3].capitalize()}: lines (MotionCal)"
            return Sample(None, (values[6], values[7], values[8]))
        tokens = [v for v in _SPLIT.split(text) if v]
        values = _numbers(tokens)
        if values is None:
            if self._read_header(tokens):
                return None
            return self._skip(None)
        if self._count is not None and len(values) != self._count:
            return self._skip(values)
        where = self._where(len(values))
        if where is None:
            return self._skip(values)
        t_at, m_at = where
        self._count = len(values)
        return Sample(None if t_at is None else values[t_at],
                      (values[m_at[0]], values[m_at[1]], values[m_at[2]]))

    def _where(self, n: int) -> tuple[int | None, list[int]] | None:
        """Positions of the time and the magnetometer in a line of ``n`` numbers."""
        if self._header is not None:
            t_at, m_at = self._header
            if max(m_at + ([t_at] if t_at is not None else [])) >= n:
                return None
            self.form = "CSV lines with a header"
            return self._header
        if self.columns is not None:
            if max(self.columns) >= n:
                return None
            self.form = f"lines of {n} numbers, columns {self.columns}"
            return None, self.columns
        if n == 3:
            self.form = "lines of 3 numbers (mx my mz)"
            return None, [0, 1, 2]
        if n == 4:
            self.form = "lines of 4 numbers (t mx my mz)"
            return 0, [1, 2, 3]
        return None

    def _read_header(self, tokens: Sequence[str]) -> bool:
        names = [t.strip().strip('"').lower() for t in tokens]
        m_at = []
        for choices in _AXIS_NAMES:
            at = next((names.index(c) for c in choices if c in names), None)
            if at is None:
                return False
            m_at.append(at)
        t_at = next((names.index(c) for c in _TIME_NAMES if c in names), None)
        self._header, self._count = (t_at, m_at), len(names)
        return True

    def _skip(self, values: list[float] | None) -> None:
        self.garbage += 1
        if values is not None:
            self.widest = max(self.widest, len(values))
        return None

    def why_none(self) -> str:
        """Why no line gave a sample yet, in words (for the 'no magnetometer' line)."""
        if not self.lines:
            return "no text lines"
        if self.widest > 4 and self._header is None and self.columns is None:
            return (f"{self.lines} lines, some of {self.widest} numbers: say which three are "
                    "the magnetometer with columns=[i,j,k] (0-based), or send a header line "
                    "naming mx,my,mz")
        return (f"{self.lines} lines, none of three or four numbers, a header naming mx,my,mz, "
                "or MotionCal's Raw:/Uni: lines")


#: MAVLink message -> (compass instance it carries, or None: the ``id`` field; its unit).
MAVLINK_TYPES: dict[str, tuple[int | None, str | None]] = {
    "SCALED_IMU": (0, "mgauss"), "SCALED_IMU2": (1, "mgauss"), "SCALED_IMU3": (2, "mgauss"),
    "HIGHRES_IMU": (None, "gauss"), "RAW_IMU": (None, None)}

#: HIGHRES_IMU ``fields_updated`` bits of xmag, ymag, zmag.
_HIGHRES_MAG_BITS = 0b111 << 6


def mavlink_sample(msg: object, instance: int = 0) -> tuple[Sample, str, str | None] | None:
    """The magnetometer sample in a MAVLink message, if it carries compass ``instance``.

    Parameters
    ----------
    msg : pymavlink message
        Any message (only ``get_type()`` and the fields named in the module notes are read).
    instance : int
        The compass wanted (0, 1 or 2).

    Returns
    -------
    (Sample, str, str or None) or None
        The sample (time in seconds since the vehicle booted), the message type and its unit;
        None for another message, another compass, or a compass that is absent (all zero).
    """
    mtype = msg.get_type()  # type: ignore[attr-defined]
    if mtype not in MAVLINK_TYPES:
        return None
    carries, unit = MAVLINK_TYPES[mtype]
    if carries is None:
        carries = int(getattr(msg, "id", 0) or 0)
    if carries != instance:
        return None
    if mtype == "HIGHRES_IMU":
        updated = int(getattr(msg, "fields_updated", 0) or 0)
        if updated and not updated & _HIGHRES_MAG_BITS:
            return None
    m = (float(msg.xmag), float(msg.ymag), float(msg.zmag))  # type: ignore[attr-defined]
    if m == (0.0, 0.0, 0.0) or not all(math.isfinite(v) for v in m):
        return None
    if hasattr(msg, "time_usec"):
        t = float(msg.time_usec) * 1e-6
    else:
        t = float(getattr(msg, "time_boot_ms", 0)) * 1e-3
    return Sample(t, m), mtype, unit
