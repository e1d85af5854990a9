"""``python -m magbench capture port=/dev/ttyACM0 [out=DIR]``: record a live stream with a view
of the directions covered, stop when the data suffice, and calibrate the recording.

The stream (``port``): a serial port (pyserial, the ``capture`` extra) or standard input
(``port=-``) carrying text lines (:class:`magbench.sources.stream.LineParser`: three or four
numbers, a CSV header, MotionCal's ``Raw:``/``Uni:`` lines), or a MAVLink connection
(pymavlink: ``udpin:127.0.0.1:14550``, ``tcp:host:5760``, or a serial port with
``format=mavlink``; :func:`magbench.sources.stream.mavlink_sample`, compass ``instance``).

A reader thread parses the stream; the main loop saves every sample to ``<out>/capture.csv``
(``t,mx,my,mz``, flushed at every tick of :data:`TICK_S`, so a disconnect, Ctrl-C or a kill
loses at most that much), recomputes the live figures (:func:`magbench.cli.live.live_status`)
a few times a second and draws the view: in place with ANSI codes on a terminal (it works over
SSH and in tmux; no curses, no browser, no port to open), one line every
:data:`LINE_EVERY_S` otherwise. It stops on "enough" (``stop=enough``, the default), on Enter
(or ``q``), after ``stop=SECONDS``, or at the end of the stream; then it writes
``capture.json`` (the stream, the reason for stopping, the final live figures) and runs
``calibrate`` (:func:`magbench.cli.calibrate.run_calibrate`) on ``capture.csv`` with the same
configuration, writing its files into the same folder. Ctrl-C or a kill stops without
calibrating; the recording is kept and the line printed says how to calibrate it.

Bad input never stops it: unparseable lines are counted and skipped; a port that goes away
ends the recording with one line (the samples are kept and calibrated); a stream that carries
no magnetometer for :data:`NO_DATA_S` seconds ends it with one line and exit status 2.
"""

from __future__ import annotations

import collections
import json
import math
import os
import re
import select
import shutil
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import IO

import numpy as np
from omegaconf import DictConfig, OmegaConf, open_dict

from magbench.cli.config import (
    UsageError,
    check_integer,
    check_number,
    check_units,
    plain,
    writable_folder,
)
from magbench.cli.live import BANDS, LiveStatus, live_status, map_rows
from magbench.core.files import write_text_atomic
from magbench.core.verdict import Gate
from magbench.sources.stream import LineParser, Sample, mavlink_sample

__all__ = ["LINE_EVERY_S", "NO_DATA_S", "TICK_S", "render", "run_capture"]

#: The main loop's period: samples are written and flushed, keys read, this often.
TICK_S = 0.1
#: The view is redrawn at most this often (the figures are recomputed as their cost allows).
DRAW_S = 0.25
#: Without a terminal, one status line this often.
LINE_EVERY_S = 2.0
#: A stream that gives no magnetometer sample for this long is reported and ended.
NO_DATA_S = 5.0
#: The file name of the recording inside ``out``.
RECORDING = "capture.csv"
#: Fewer samples than this are not calibrated (calibrate needs a few per parameter).
MIN_CALIBRATE = 10

_NETWORK = re.compile(r"^(udp|udpin|udpout|udpbcast|tcp|tcpin):", re.IGNORECASE)


@dataclass(frozen=True)
class _Settings:
    port: str
    baud: int
    form: str
    rate: float | None
    stop: str | float
    out: Path
    units: str | None
    columns: list[int] | None
    instance: int
    gate: Gate


def _gate(cfg: DictConfig) -> Gate:
    """The ``gate.*`` thresholds (checked again, with the same messages, by calibrate)."""
    given = plain(cfg.get("gate")) or {}
    values = {}
    for key, default in Gate().__dict__.items():
        value = given.get(key, default)
        values[key] = (check_integer(value, f"gate.{key}", 0) if isinstance(default, int)
                       else check_number(value, f"gate.{key}", lambda x: x >= 0, ">= 0"))
    return Gate(**values)


def _settings(cfg: DictConfig) -> _Settings:
    """Every key ``capture`` reads, checked before the port is opened."""
    port = plain(cfg.get("port"))
    if not isinstance(port, str) or not port:
        raise UsageError("capture needs port=PORT: a serial port (port=/dev/ttyACM0, "
                         "port=COM3), a MAVLink address (port=udpin:127.0.0.1:14550) or - for "
                         "standard input")
    baud = check_integer(plain(cfg.get("baud", 115200)), "baud", 1)
    form = str(plain(cfg.get("format", "auto")))
    if form not in ("auto", "text", "mavlink"):
        raise UsageError(f"format must be auto, text or mavlink, got {form!r}")
    if form == "auto":
        form = "mavlink" if _NETWORK.match(port) else "text"
    if form == "mavlink" and port == "-":
        raise UsageError("format=mavlink needs a port or an address, not standard input")
    rate = plain(cfg.get("rate"))
    if rate is not None:
        rate = check_number(rate, "rate", lambda r: 0 < r <= 1e6, "in (0, 1e6] samples/s")
    stop = plain(cfg.get("stop", "enough"))
    if stop not in ("enough", "manual"):
        stop = check_number(stop, "stop", lambda s: s > 0,
                            "enough, manual, or a positive number of seconds")
    units = check_units(cfg)
    columns = plain(cfg.get("columns"))
    if columns is not None and (not isinstance(columns, list) or len(columns) != 3 or not all(
            isinstance(c, int) and not isinstance(c, bool) and c >= 0 for c in columns)):
        raise UsageError(f"capture's columns must be three 0-based positions of mx,my,mz in a "
                         f"line, e.g. columns=[6,7,8], got {columns!r}")
    instance = plain(cfg.get("instance"))
    instance = 0 if instance is None else check_integer(instance, "instance", 0, 2)
    out = Path(str(cfg.out)) if cfg.get("out") else Path(
        time.strftime("capture-%Y%m%d-%H%M%S"))
    overwrite = plain(cfg.get("overwrite", False))
    if not isinstance(overwrite, bool):
        raise UsageError(f"overwrite must be true or false, got {overwrite!r}")
    if not overwrite:
        for name in (RECORDING, "calibration.json"):
            if (out.expanduser() / name).exists():
                raise UsageError(f"out={out} already holds {name}; pass overwrite=true to "
                                 "replace it, or choose another out=")
    return _Settings(port, baud, form, rate, stop, out,
                     str(plain(cfg.units)) if units.known or units.counts else None, columns,
                     instance, _gate(cfg))


class _Reader(threading.Thread):
    """Reads the stream in the background: samples with their arrival time go to ``queue``;
    ``ended`` says why it stopped ("" while running)."""

    def __init__(self, settings: _Settings) -> None:
        super().__init__(daemon=True)
        self.settings = settings
        self.queue: collections.deque[tuple[Sample, float]] = collections.deque()
        self.parser = LineParser(settings.columns)
        self.units: str | None = None
        self.form = ""
        self.received = 0          # bytes (text) or messages (MAVLink)
        self.types: collections.Counter[str] = collections.Counter()
        self.ended = ""
        self.lost = False          # the port went away (as opposed to an end of input)
        self._halt = threading.Event()
        self._close: Callable[[], None] = lambda: None
        self._read: Callable[[], bytes | None] = lambda: b""
        self._conn: object = None

    def stop(self) -> None:
        self._halt.set()
        try:
            self._close()
        except Exception:          # closing a port that already failed: nothing to keep
            pass

    def open(self) -> None:
        """Open the port (in the caller's thread, so that a bad port is one line, exit 2)."""
        if self.settings.form == "mavlink":
            from pymavlink import mavutil

            try:
                self._conn = mavutil.mavlink_connection(
                    self.settings.port, baud=self.settings.baud, source_system=255,
                    autoreconnect=False)
            except Exception as exc:   # pymavlink raises several kinds for a bad address
                raise UsageError(f"port={self.settings.port} cannot be opened as MAVLink "
                                 f"({' '.join(str(exc).split())}); expected an address such "
                                 "as udpin:127.0.0.1:14550 or tcp:host:5760, or a serial "
                                 "port") from None
            self._close = self._conn.close
        else:
            self._read = self._open_text()

    def run(self) -> None:
        try:
            if self.settings.form == "mavlink":
                self._mavlink()
            else:
                self._text()
        except Exception as exc:   # a port error of any kind ends the stream with its text
            if not self._halt.is_set():
                self.lost = True
                text = " ".join(str(exc).split()) or type(exc).__name__
                self.ended = f"the port went away ({text})"
        if not self.ended:
            self.ended = "stopped"

    def _text(self) -> None:
        pending = b""
        while not self._halt.is_set():
            chunk = self._read()
            if chunk is None:
                continue
            if not chunk:
                self.ended = "end of input"
                break
            self.received += len(chunk)
            *lines, pending = re.split(rb"[\r\n]+", pending + chunk)
            for line in lines:
                self._push(self.parser.parse(line))
            self.form = self.parser.form
            self.units = self.parser.units
        if pending and not self._halt.is_set():
            self._push(self.parser.parse(pending))

    def _open_text(self) -> Callable[[], bytes | None]:
        """A function giving the next bytes, b"" at the end, None when none came yet."""
        if self.settings.port == "-":
            fd = sys.stdin.fileno()

            def read_stdin() -> bytes | None:
                ready, _, _ = select.select([fd], [], [], 0.2)
                return os.read(fd, 65536) if ready else None

            return read_stdin
        serial = _need_serial()
        try:
            port = serial.serial_for_url(self.settings.port, baudrate=self.settings.baud,
                                         timeout=0.2)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise UsageError(f"port={self.settings.port} cannot be opened "
                             f"({' '.join(str(exc).split())}); check the name (python -m "
                             "serial.tools.list_ports lists them) and that no other program "
                             "holds it") from None
        self._close = port.close

        def read_serial() -> bytes | None:
            chunk = port.read(max(1, port.in_waiting))
            return chunk or None    # a serial port has no end: a timeout is no data yet

        return read_serial

    def _mavlink(self) -> None:
        from pymavlink import mavutil

        conn = self._conn
        locked, asked = None, False
        while not self._halt.is_set():
            msg = conn.recv_match(blocking=True, timeout=0.2)
            if msg is None:
                continue
            self.received += 1
            mtype = msg.get_type()
            self.types[mtype] += 1
            if mtype == "BAD_DATA":
                self.parser.garbage += 1
                continue
            if mtype == "HEARTBEAT" and not asked:
                asked = True        # ask for the raw sensors (ArduPilot streams them on request)
                conn.mav.request_data_stream_send(msg.get_srcSystem(), msg.get_srcComponent(),
                                                  mavutil.mavlink.MAV_DATA_STREAM_RAW_SENSORS,
                                                  50, 1)
            found = mavlink_sample(msg, self.settings.instance)
            if found is None or locked not in (None, found[1]):
                continue            # one message type only: two would record samples twice
            sample, locked, self.units = found
            self.form = f"MAVLink {locked}, compass {self.settings.instance}"
            self._push(sample)

    def _push(self, sample: Sample | None) -> None:
        if sample is not None:
            self.queue.append((sample, time.monotonic()))


def _need_serial() -> ModuleType:
    """pyserial, or one line saying how to install it."""
    try:
        import serial
    except ImportError:
        raise UsageError("a serial port needs pyserial: pip install 'magbench[capture]' (or "
                         "pip install pyserial); port=- reads standard input without it") \
            from None
    return serial


class _Recording:
    """``capture.csv``, written as samples arrive and flushed at every tick."""

    def __init__(self, path: Path, rate: float | None) -> None:
        self.path = path
        self.rate = rate
        self.file: IO[str] = path.open("w", encoding="ascii", newline="")
        self.file.write("t,mx,my,mz\n")
        self.y: list[tuple[float, float, float]] = []
        self.t: list[float] = []
        self.host: list[float] = []
        self.device_time = False

    def add(self, sample: Sample, host_s: float) -> None:
        if sample.t is not None:
            self.device_time = True
        t = (sample.t if sample.t is not None else
             len(self.y) / self.rate if self.rate else host_s)
        self.file.write(f"{t!r},{sample.m[0]!r},{sample.m[1]!r},{sample.m[2]!r}\n")
        self.y.append(sample.m)
        self.t.append(t)
        self.host.append(host_s)

    def flush(self) -> None:
        self.file.flush()

    def close(self) -> None:
        self.file.close()

    def rate_text(self) -> str:
        """The sample rate and where it comes from."""
        if self.rate:
            return f"{self.rate:g} Hz (given)"
        times = self.t if self.device_time else self.host
        if len(times) < 3:
            return "rate: -"
        span = times[-1] - times[max(0, len(times) - 500)]
        n = min(len(times), 500) - 1
        if not span > 0:
            return "rate: -"
        return f"{n / span:.0f} Hz ({'device time' if self.device_time else 'arrival'})"


#: Rows of the view besides the map's rows (:meth:`_Screen.map_style`): 24 rows show the map
#: in half blocks, 31 in full.
_FIGURE_LINES = 16


def _bar(fraction: float, width: int = 30) -> str:
    full = round(max(0.0, min(1.0, fraction)) * width)
    return "[" + "#" * full + "-" * (width - full) + "]"


def _half_blocks(rows: list[str]) -> list[str]:
    """Two bands of the map per text row (Unicode half blocks): the map in half the rows."""
    out = []
    for upper, lower in zip(rows[0::2], rows[1::2], strict=False):
        line = ""
        for a, b in zip(upper, lower, strict=True):
            marks = [c for c in (a, b) if c in "O@"]
            line += marks[0] if marks else _HALF[(a == "#", b == "#")]
        out.append(line)
    return out


_HALF = {(True, True): "\u2588", (True, False): "\u2580", (False, True): "\u2584",
         (False, False): "."}


def render(status: LiveStatus, *, head: list[str], gate: Gate, stop: str | float,
           keys: bool, map_style: str = "full") -> list[str]:
    """The view's lines: the stream, the map of the directions covered (``map_style``
    ``full``: one text row per band, 34 rows in all; ``half``: two bands per row in Unicode
    half blocks, 24 rows; ``none``), the figures against the gate, a quality bar and what to
    do next."""
    lines = [*head]
    if map_style != "none":
        rows = map_rows(status.cells, status.gap_centre if status.samples else None,
                        status.now)
        seen = "#" if map_style == "full" else _HALF[(True, True)]
        if map_style == "half":
            rows = _half_blocks(rows)
        lines += ["", f"  field directions seen (equal-area cells: {seen} seen  . not yet  "
                  "O gap  @ now)"]
        for i, row in enumerate(rows):
            label = "+Z" if i == 0 else "-Z" if i == len(rows) - 1 else "  "
            lines.append(f"  {label} |{''.join(ch * 2 for ch in row)}|")
        lines.append("       longitude of the field in the XY plane, -180 to +180 deg")
    err = status.error_p95_pct
    lines += [
        "",
        f"  covered      {100 * status.coverage:3.0f} % of the sphere, {status.directions} "
        f"directions (gate >= {gate.warn_directions})",
        f"  largest gap  {status.gap_deg:3.0f} deg (gate <= {gate.warn_gap_deg:g})",
        "  field error  " + ("  - (too few samples)" if err is None else
                             f"{err:4.1f} % p95, held out ({status.fit} fit; gate <= "
                             f"{gate.warn_error_pct:g} %)"),
        f"  quality      {_bar(status.quality)} {100 * status.quality:3.0f} %",
        "",
    ]
    if status.enough:
        lines.append("  >>> ENOUGH: coverage and error meet the gate <<<"
                     + ("" if stop == "enough" else "  press Enter to calibrate"))
    else:
        lines.append(f"  next: {status.prompt}")
        if "turn it" in status.prompt:
            lines.append("        (words for X forward, Y right, Z down)")
    if keys:
        lines.append("  Enter: stop and calibrate    Ctrl-C: stop, keep the recording")
    return lines


class _Screen:
    """Draws the view in place on a terminal; one line every so often elsewhere."""

    def __init__(self, out: IO[str]) -> None:
        self.out = out
        self.tty = out.isatty()
        self.last_line = -math.inf
        if self.tty:
            out.write("\x1b[?25l\x1b[2J")      # hide the cursor, clear once

    def map_style(self) -> str:
        """The map the terminal has rows for: one row per band, half blocks (a UTF-8
        terminal), or none (the figures matter more); one row per band without a terminal."""
        if not self.tty:
            return "full"
        try:                 # the terminal's own size (LINES in the environment may be stale)
            rows = os.get_terminal_size(self.out.fileno()).lines
        except (OSError, ValueError):
            rows = shutil.get_terminal_size((80, 40)).lines
        if rows > _FIGURE_LINES + BANDS:
            return "full"
        utf8 = "utf" in (getattr(self.out, "encoding", "") or "").lower()
        return "half" if utf8 and rows > _FIGURE_LINES + BANDS // 2 else "none"

    def draw(self, lines: list[str], line: str, force: bool = False) -> None:
        if self.tty:
            self.out.write("\x1b[H" + "".join(f"{text}\x1b[K\n" for text in lines) + "\x1b[J")
            self.out.flush()
        elif force or time.monotonic() - self.last_line >= LINE_EVERY_S:
            self.last_line = time.monotonic()
            print(line, file=self.out, flush=True)

    def close(self) -> None:
        if self.tty:
            self.out.write("\x1b[?25h")
            self.out.flush()


class _Keys:
    """Enter or q on the controlling terminal (when standard input is one and is not the
    stream): read without echo, restored at the end."""

    def __init__(self, enabled: bool) -> None:
        self.fd = sys.stdin.fileno() if enabled else None
        self.saved = None
        if self.fd is not None:
            import termios
            import tty

            self.saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)

    def pressed(self) -> bool:
        if self.fd is None or not select.select([self.fd], [], [], 0)[0]:
            return False
        return any(ch in b"\r\nqQ" for ch in os.read(self.fd, 64))

    def close(self) -> None:
        if self.saved is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)


def _interactive() -> bool:
    try:
        return sys.stdin.isatty()
    except (AttributeError, ValueError):
        return False


def run_capture(cfg: DictConfig) -> int:
    """The ``capture`` command (module notes). Returns calibrate's status after a calibration
    (0 PASS or WARN, 3 FAIL), 130 / 143 on Ctrl-C / a kill; a bad key, a port that cannot be
    opened or a stream without a magnetometer raise :class:`UsageError` (exit 2)."""
    settings = _settings(cfg)
    out = writable_folder(settings.out, "out")
    reader = _Reader(settings)
    reader.open()
    recording = _Recording(out / RECORDING, settings.rate)
    keys = _Keys(settings.port != "-" and _interactive())
    screen = _Screen(sys.stdout)
    started = time.monotonic()
    reader.start()
    try:
        why = _loop(settings, reader, recording, screen, keys, started)
    except KeyboardInterrupt as stop:
        killed = type(stop).__name__ == "Terminated"
        _finish(reader, recording, screen, keys, started)
        print(f"magbench: capture {'terminated' if killed else 'interrupted'}; the recording "
              f"is kept in {recording.path} ({len(recording.y)} samples); calibrate it with "
              f"python -m magbench calibrate file={recording.path}", file=sys.stderr)
        return 143 if killed else 130
    except BaseException:
        _finish(reader, recording, screen, keys, started)
        if not recording.y:       # nothing recorded: no empty file to refuse a rerun with
            recording.path.unlink(missing_ok=True)
        raise
    _finish(reader, recording, screen, keys, started)
    y = np.array(recording.y, dtype=float).reshape(-1, 3)
    status = live_status(y, settings.gate)
    units = settings.units or reader.units
    screen.draw(render(status, head=_head(settings, reader, recording, started, units),
                       gate=settings.gate, stop=settings.stop, keys=False,
                       map_style=screen.map_style()),
                _line(status, recording), force=True)
    summary = {"port": settings.port, "format": reader.form, "units": units,
               "rate": recording.rate_text(), "samples": len(recording.y),
               "skipped_lines": reader.parser.garbage, "stopped": why,
               "recording": RECORDING, "live": status.as_dict()}
    write_text_atomic(json.dumps(summary, indent=2) + "\n", out / "capture.json")
    if reader.lost:
        print(f"magbench: {reader.ended} after {len(recording.y)} samples; the recording is "
              f"kept in {recording.path}", file=sys.stderr)
    print(f"capture: stopped ({why}); {len(recording.y)} samples in {recording.path}")
    if len(recording.y) < MIN_CALIBRATE:
        raise UsageError(f"only {len(recording.y)} samples were recorded ({why}); at least "
                         f"{MIN_CALIBRATE} are needed to calibrate")
    print("capture: calibrating it as python -m magbench calibrate would\n", flush=True)
    return _calibrate(cfg, recording.path, out, units)


def _finish(reader: _Reader, recording: _Recording, screen: _Screen, keys: _Keys,
            started: float) -> None:
    reader.stop()
    _drain(reader, recording, started)
    recording.close()
    keys.close()
    screen.close()


def _drain(reader: _Reader, recording: _Recording, started: float) -> int:
    """Write the samples the reader queued (arrival times from ``started``); how many."""
    n = 0
    while reader.queue:
        sample, host = reader.queue.popleft()
        recording.add(sample, host - started)
        n += 1
    return n


def _head(settings: _Settings, reader: _Reader, recording: _Recording, started: float,
          units: str | None) -> list[str]:
    return [f"magbench capture   port {settings.port}   {reader.form or 'waiting for data'}",
            f"  units {units or 'unknown (units= to give them)'}   {recording.rate_text()}",
            f"  recording {recording.path}",
            f"  {len(recording.y)} samples   {time.monotonic() - started:5.1f} s   "
            f"{reader.parser.garbage} lines skipped"]


def _line(status: LiveStatus, recording: _Recording) -> str:
    err = status.error_p95_pct
    return (f"capture: {len(recording.y)} samples, covered {100 * status.coverage:.0f} %, "
            f"largest gap {status.gap_deg:.0f} deg, {status.directions} directions, field error "
            + ("-" if err is None else f"{err:.1f} %") + f", quality {100 * status.quality:.0f} "
            + ("%; ENOUGH" if status.enough else f"%; next: {status.prompt}"))


def _loop(settings: _Settings, reader: _Reader, recording: _Recording, screen: _Screen,
          keys: _Keys, started: float) -> str:
    """Record, recompute and draw until a reason to stop; returns the reason."""
    status = LiveStatus(0)
    next_status = next_draw = started
    cost = 0.0
    while True:
        now = time.monotonic()
        new = _drain(reader, recording, started)
        recording.flush()
        if new and now >= next_status:
            y = np.array(recording.y, dtype=float)
            tic = time.monotonic()
            status = live_status(y, settings.gate)
            cost = time.monotonic() - tic
            # a few times a second, never more than a third of the time on the figures
            next_status = time.monotonic() + max(DRAW_S, 2.0 * cost)
        if now >= next_draw:
            next_draw = now + DRAW_S
            units = settings.units or reader.units
            screen.draw(render(status, head=_head(settings, reader, recording, started, units),
                               gate=settings.gate, stop=settings.stop, keys=keys.fd is not None,
                               map_style=screen.map_style()),
                        _line(status, recording))
        if status.enough and settings.stop == "enough" and status.samples == len(recording.y):
            return "enough"
        if keys.pressed():
            return "Enter pressed"
        if not isinstance(settings.stop, str) and now - started >= settings.stop:
            return f"{settings.stop:g} s recorded"
        if reader.ended and not reader.queue:
            if reader.ended.startswith("the port") and not recording.y:
                raise UsageError(f"port={settings.port}: {reader.ended} before any sample")
            return reader.ended
        if not recording.y and now - started >= NO_DATA_S:
            raise UsageError(_no_data(settings, reader))
        time.sleep(TICK_S)


def _no_data(settings: _Settings, reader: _Reader) -> str:
    """The one line for a stream that gave no magnetometer sample in :data:`NO_DATA_S`."""
    where = f"port={settings.port}"
    if settings.form == "mavlink":
        if not reader.received:
            return (f"no MAVLink message on {where} in {NO_DATA_S:g} s; check the address, "
                    "baud= and that the vehicle is sending")
        seen = ", ".join(f"{k} x{n}" for k, n in reader.types.most_common(6))
        return (f"no magnetometer on {where} in {NO_DATA_S:g} s: MAVLink messages arrived "
                f"({seen}) but none of RAW_IMU, SCALED_IMU, SCALED_IMU2/3 or HIGHRES_IMU with "
                f"compass {settings.instance} and non-zero fields; ask the vehicle to stream "
                "raw sensors (ArduPilot: SR0_RAW_SENS), or choose instance=")
    if not reader.received:
        return (f"nothing received on {where} in {NO_DATA_S:g} s; check the port, baud= and "
                "that the device is sending")
    hint = ""
    if reader.parser.lines == 0 or reader.parser.garbage >= reader.parser.lines:
        hint = "; if the device speaks MAVLink, pass format=mavlink"
    return (f"no magnetometer on {where} in {NO_DATA_S:g} s: {reader.parser.why_none()}"
            f"{hint if settings.port != '-' else ''}")


def _calibrate(cfg: DictConfig, path: Path, out: Path, units: str | None) -> int:
    """``calibrate`` on the recording with the same configuration, files into ``out``."""
    from magbench.cli.calibrate import run_calibrate

    cfg = OmegaConf.create(OmegaConf.to_container(cfg))
    OmegaConf.set_struct(cfg, True)
    with open_dict(cfg):
        cfg.file = str(path)
        cfg.out = str(out)
        cfg.units = units
        cfg.columns = None           # capture.csv has t,mx,my,mz
        cfg.instance = None
        cfg.overwrite = True         # capture checked out= before recording into it
    return run_calibrate(cfg)
