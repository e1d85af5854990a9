"""``capture`` against simulated devices: a pseudo-terminal fed by a player process, a MAVLink
stream over UDP from pymavlink's own encoder, standard input, and the view in tmux.

The played recording is synthetic (a slow spiral over the whole sphere with an offset and soft
iron, so the first part covers a cap and "enough" comes part-way through); with
``MAGBENCH_DATA`` set, one test plays the shared HMC5883L recording too.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from magbench.cli import capture as capture_module
from magbench.cli.live import live_status
from magbench.cli.main import main

#: A stand-alone player (standard library only, so it starts fast): once the capture opened
#: the port, writes the lines of a file to a file descriptor at ``rate`` lines per second,
#: then keeps the descriptor open (``hold``) or closes it half a second later (unplugged).
PLAYER = r"""
import os, sys, termios, time
fd, port, path, rate, hold = (int(sys.argv[1]), sys.argv[2], sys.argv[3], float(sys.argv[4]),
                              sys.argv[5] == "1")
lines = open(path, "rb").read().splitlines(keepends=True)
# Like a board that starts printing when the host opens its port: wait until the capture has
# put the port in raw mode (pyserial then flushes what arrived before it opened the port).
probe = os.open(port, os.O_RDONLY | os.O_NOCTTY)
deadline = time.monotonic() + 30
while termios.tcgetattr(probe)[3] & termios.ICANON and time.monotonic() < deadline:
    time.sleep(0.01)
os.close(probe)
time.sleep(0.2)
start = time.monotonic()
i = 0
while i < len(lines):
    due = int((time.monotonic() - start) * rate) + 1
    chunk = b"".join(lines[i:due])
    i = max(i, due)
    while chunk:
        chunk = chunk[os.write(fd, chunk):]
    time.sleep(0.005)
# a pty's hangup drops what the reader has not read yet: unplug after the last line is read
time.sleep(60 if hold else 0.5)
os.close(fd)
"""

def spiral(n: int = 2000, turns: float = 8.0, seed: int = 0) -> np.ndarray:
    """Samples in uT of a sensor turned along a spiral from the field along +Z to -Z."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)
    z = 1.0 - 2.0 * s
    phi = 2.0 * np.pi * turns * s
    r = np.sqrt(1.0 - z ** 2)
    m = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    T = 48.0 * np.array([[1.05, 0.03, 0.01], [0.03, 0.95, -0.02], [0.01, -0.02, 1.0]])
    return m @ T.T + np.array([12.0, -7.0, 20.0]) + rng.normal(0.0, 0.2, (n, 3))


def raw_lines(y_tenths: np.ndarray, garbage_every: int = 0) -> tuple[list[str], int]:
    """MotionCal ``Raw:`` lines of integer samples (0.1 uT), with garbage lines mixed in."""
    lines, bad = ["ield broken first line 12,3"], 1        # a port opened mid-line
    for i, (x, y, z) in enumerate(y_tenths):
        if garbage_every and i % garbage_every == garbage_every - 1:
            lines.append("Raw:1,2,3,##,5")
            bad += 1
        lines.append(f"Raw:12,-40,8190,3,-2,1,{x},{y},{z}")
    return lines, bad


class Player:
    """A pseudo-terminal whose device end a player process writes to."""

    def __init__(self, lines: list[str], tmp: Path, rate: float, hold: bool = True) -> None:
        master, slave = os.openpty()
        self.port = os.ttyname(slave)
        self._slave = slave             # kept open so the port exists until the capture opens it
        path = tmp / "played.txt"
        path.write_text("\r\n".join(lines) + "\r\n")
        self.proc = subprocess.Popen([sys.executable, "-c", PLAYER, str(master), self.port,
                                      str(path), str(rate), "1" if hold else "0"],
                                     pass_fds=[master])
        os.close(master)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        os.close(self._slave)


def read_capture(out: Path) -> tuple[np.ndarray, dict]:
    data = np.loadtxt(out / "capture.csv", delimiter=",", skiprows=1, ndmin=2)
    return data, json.loads((out / "capture.json").read_text())


def same_calibration(a: Path, b: Path) -> None:
    ja = json.loads((a / "calibration.json").read_text())
    jb = json.loads((b / "calibration.json").read_text())
    assert ja["status"] == jb["status"] and ja["method"] == jb["method"]
    np.testing.assert_array_equal(ja["A"], jb["A"])
    np.testing.assert_array_equal(ja["b"], jb["b"])
    assert ja["units"] == jb["units"]


FAST = ["picture=false", "bootstrap=0"]
#: Fewer candidates where the test is not about calibrate's choice (a recording stopped right
#: at the gate's gap can make calibrate fit every method, several seconds).
FEWER = [*FAST, "candidates=[sphere,ellipsoid,fang]"]


def test_pty_raw_lines_stop_on_enough_and_match_calibrate(tmp_path, capsys):
    y = np.round(spiral() * 10).astype(int)
    lines, _ = raw_lines(y, garbage_every=50)
    player = Player(lines, tmp_path, rate=2000)
    try:
        rc = main(["capture", f"port={player.port}", f"out={tmp_path / 'cap'}", *FEWER])
    finally:
        player.close()
    data, info = read_capture(tmp_path / "cap")
    n = data.shape[0]
    assert rc == 0 and info["stopped"] == "enough" and info["units"] == "0.1uT"
    # the saved samples are the played ones, in order, none lost or doubled
    assert 30 <= n <= len(y)
    np.testing.assert_array_equal(data[:, 1:], y[:n])
    # the garbage lines played before the last saved sample were all counted
    assert info["skipped_lines"] >= 1 + n // 50
    # the live figures are the offline figures of the saved file, and they meet the gate
    offline = live_status(data[:, 1:])
    assert info["live"]["coverage"] == offline.coverage
    assert info["live"]["gap_deg"] == offline.gap_deg
    assert info["live"]["directions"] == offline.directions
    assert offline.enough and offline.gap_deg <= 100 and offline.error_p95_pct <= 6
    # ... and agree with calibrate's own coverage of the same file
    cal = json.loads((tmp_path / "cap" / "calibration.json").read_text())
    assert abs(cal["coverage"]["largest_gap_deg"] - offline.gap_deg) < 5
    assert abs(cal["coverage"]["coverage"] - offline.coverage) < 0.05
    # the calibration is calibrate's on the saved file
    assert main(["calibrate", f"file={tmp_path / 'cap' / 'capture.csv'}", "units=0.1uT",
                 f"out={tmp_path / 'again'}", *FEWER]) == 0
    same_calibration(tmp_path / "cap", tmp_path / "again")
    shown = capsys.readouterr().out
    assert "ENOUGH" in shown and "PASS" in shown


def test_port_that_disappears_is_one_line_and_the_recording_is_kept(tmp_path, capsys):
    y = np.round(spiral(1200) * 10).astype(int)
    lines, _ = raw_lines(y)
    player = Player(lines, tmp_path, rate=4000, hold=False)
    try:
        rc = main(["capture", f"port={player.port}", f"out={tmp_path / 'cap'}", "stop=manual",
                   *FAST])
    finally:
        player.close()
    data, info = read_capture(tmp_path / "cap")
    np.testing.assert_array_equal(data[:, 1:], y)
    assert info["stopped"].startswith("the port went away")
    err = capsys.readouterr().err
    went = [line for line in err.splitlines() if "went away" in line]
    assert len(went) == 1 and "1200 samples" in went[0] and "capture.csv" in went[0]
    # what was recorded is still calibrated
    assert rc == 0
    assert json.loads((tmp_path / "cap" / "calibration.json").read_text())["status"] == "PASS"


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _bound(port: int) -> bool:
    """Whether a socket listens on UDP ``port``, read from /proc/net/udp: probing by binding
    the port would race the capture's own bind (EADDRINUSE now and then)."""
    table = Path("/proc/net/udp")
    if not table.exists():
        time.sleep(0.5)
        return True
    return any(line.split()[1].endswith(f":{port:04X}")
               for line in table.read_text().splitlines()[1:] if len(line.split()) > 1)


def test_mavlink_over_udp_one_compass(tmp_path):
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    port = _free_udp_port()
    y = np.round(spiral(1500) * 10).astype(int)     # mgauss (1 uT = 10 mgauss)
    result: dict = {}
    worker = threading.Thread(target=lambda: result.setdefault("rc", main(
        ["capture", f"port=udpin:127.0.0.1:{port}", "instance=1", f"out={tmp_path / 'cap'}",
         *FEWER])))
    worker.start()
    deadline = time.monotonic() + 20
    while not _bound(port) and time.monotonic() < deadline:
        time.sleep(0.02)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender.connect(("127.0.0.1", port))

    class Out:
        def write(self, data: bytes) -> None:
            try:
                sender.send(data)
            except ConnectionRefusedError:      # the capture has stopped and closed its port
                pass

    mav = mavlink.MAVLink(Out(), srcSystem=1, srcComponent=1)
    try:
        mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                           0, 0, 0)
        for i, (x, yy, z) in enumerate(y):
            if not worker.is_alive():
                break
            # compass 0 and an attitude arrive too: only compass 1 may be recorded
            mav.scaled_imu_send(i * 2, 0, 0, 1000, 0, 0, 0, 111, 222, 333)
            mav.attitude_send(i * 2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            mav.scaled_imu2_send(i * 2, 0, 0, 1000, 0, 0, 0, int(x), int(yy), int(z))
            time.sleep(0.001)
        worker.join(30)
    finally:
        sender.close()
    assert not worker.is_alive() and result["rc"] == 0
    data, info = read_capture(tmp_path / "cap")
    n = data.shape[0]
    assert info["stopped"] == "enough" and info["units"] == "mgauss"
    assert info["format"] == "MAVLink SCALED_IMU2, compass 1"
    np.testing.assert_array_equal(data[:, 1:], y[:n])
    np.testing.assert_allclose(data[:, 0], np.arange(n) * 2e-3)     # time_boot_ms, in s


def _stdin_from(monkeypatch, text: str) -> None:
    read, write = os.pipe()

    def feed() -> None:
        with os.fdopen(write, "w") as f:
            f.write(text)

    threading.Thread(target=feed, daemon=True).start()
    monkeypatch.setattr(sys, "stdin", os.fdopen(read, "r"))


def test_stdin_csv_to_the_end_with_garbage(tmp_path, monkeypatch, capsys):
    y = spiral(600)
    rows = [f"{i / 50!r},{a!r},{b!r},{c!r}" for i, (a, b, c) in enumerate(y.tolist())]
    rows[100:100] = ["garbage", "1,2"]
    _stdin_from(monkeypatch, "t,mx,my,mz\n" + "\n".join(rows) + "\n")
    rc = main(["capture", "port=-", f"out={tmp_path / 'cap'}", "units=uT", "stop=manual",
               *FEWER])
    data, info = read_capture(tmp_path / "cap")
    np.testing.assert_array_equal(data[:, 1:], y)
    np.testing.assert_array_equal(data[:, 0], np.arange(600) / 50)
    assert info["stopped"] == "end of input" and info["skipped_lines"] == 2
    assert info["rate"] == "50 Hz (device time)"
    assert rc == 0
    assert "capture: stopped (end of input); 600 samples" in capsys.readouterr().out


@pytest.mark.parametrize(("text", "expect"), [
    ("hello\nworld\n" * 50, "none of three or four numbers"),
    ("1,2,3,4,5,6\n" * 50, "columns=[i,j,k]"),
])
def test_stream_without_magnetometer_is_one_line(tmp_path, monkeypatch, capsys, text, expect):
    monkeypatch.setattr(capture_module, "NO_DATA_S", 0.5)
    read, write = os.pipe()
    os.write(write, text.encode())          # and the pipe stays open: no end of input
    monkeypatch.setattr(sys, "stdin", os.fdopen(read, "r"))
    try:
        rc = main(["capture", "port=-", f"out={tmp_path / 'cap'}"])
    finally:
        os.close(write)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith("magbench: error: no magnetometer on port=- in 0.5 s")
    assert expect in err[0]
    assert not (tmp_path / "cap" / "capture.csv").exists()     # a rerun is not refused


@pytest.mark.parametrize(("args", "expect"), [
    ([], "capture needs port=PORT"),
    (["port=-", "stop=soon"], "stop must be a number enough, manual, or a positive"),
    (["port=-", "format=xml"], "format must be auto, text or mavlink"),
    (["port=-", "columns=[1,2]"], "columns must be three 0-based positions"),
    (["port=/dev/does-not-exist"], "port=/dev/does-not-exist cannot be opened"),
])
def test_bad_keys_are_one_line(tmp_path, capsys, args, expect):
    assert main(["capture", f"out={tmp_path / 'cap'}", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0], err


def test_kill_keeps_the_recording_up_to_the_last_second(tmp_path):
    y = np.round(spiral(3000) * 10).astype(int)
    lines = [f"{a} {b} {c}" for a, b, c in y]
    read, write = os.pipe()
    proc = subprocess.Popen([sys.executable, "-m", "magbench", "capture", "port=-",
                             f"out={tmp_path / 'cap'}", "stop=manual"], stdin=read,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    os.close(read)
    with os.fdopen(write, "w") as feed:
        for i in range(0, 1500, 100):          # 1500 samples, then the stream goes quiet
            feed.write("\n".join(lines[i:i + 100]) + "\n")
            feed.flush()
        time.sleep(1.5)                        # more than the one second it may lose
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143
    assert "capture terminated; the recording is kept" in err.decode()
    data = np.loadtxt(tmp_path / "cap" / "capture.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(data[:, 1:], y[:1500])


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_terminal_view_in_tmux(tmp_path):
    """What a person sees: coverage, the turn to make, ENOUGH, then Enter calibrates."""
    y = np.round(spiral() * 10).astype(int)
    lines, _ = raw_lines(y)
    player = Player(lines, tmp_path, rate=600)
    session = f"magbench-capture-{os.getpid()}"
    out = tmp_path / "cap"
    command = (f"{sys.executable} -m magbench capture port={player.port} out={out} "
               "stop=manual " + " ".join(FEWER) + "; sleep 30")
    seen: list[str] = []

    def pane() -> str:
        return subprocess.run(["tmux", "capture-pane", "-p", "-t", session],
                              capture_output=True, text=True).stdout

    def wait_for(word: str, timeout: float = 30) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = pane()
            seen.append(text)
            if word in text:
                return text
            time.sleep(0.1)
        raise AssertionError(f"{word!r} never shown; last screen:\n{seen[-1]}")

    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "100", "-y", "70",
                    command], check=True)
    try:
        early = wait_for("(toward the gap)")
        assert "covered" in early and "largest gap" in early and "quality      [#" in early
        enough = wait_for("ENOUGH")
        assert "press Enter to calibrate" in enough
        subprocess.run(["tmux", "send-keys", "-t", session, "Enter"], check=True)
        final = wait_for("wrote ")
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True)
        player.close()
    info = json.loads((out / "capture.json").read_text())
    assert info["stopped"] == "Enter pressed"
    shown = round(100 * info["live"]["coverage"])
    assert f"covered      {shown:3d} % of the sphere" in final
    assert "PASS" in final or "WARN" in final
    if os.environ.get("MAGBENCH_SCREENSHOT"):
        Path(os.environ["MAGBENCH_SCREENSHOT"]).write_text(early + "\n=====\n" + enough)


@pytest.mark.skipif(not os.environ.get("MAGBENCH_DATA"), reason="MAGBENCH_DATA not set")
def test_shared_recording_played_through_a_pty(tmp_path):
    path = Path(os.environ["MAGBENCH_DATA"]) / "hmc5883l_sphere" / "data.csv"
    table = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(0, 1, 2, 3))[:3000]
    lines = ["t,mx,my,mz"] + [",".join(repr(v) for v in row) for row in table.tolist()]
    player = Player(lines, tmp_path, rate=2000, hold=False)
    try:
        rc = main(["capture", f"port={player.port}", f"out={tmp_path / 'cap'}",
                   "stop=manual", *FEWER])
    finally:
        player.close()
    data, info = read_capture(tmp_path / "cap")
    np.testing.assert_array_equal(data, table)
    assert rc in (0, 3) and info["rate"].endswith("(device time)")


def test_turn_words_follow_the_vehicle_axes():
    from magbench.cli.live import turn_words

    # field ahead (+X) to be seen along -Z (up): the nose goes down a quarter turn
    assert turn_words([1, 0, 0], [0, 0, -1]) == "turn it nose down about 90 deg"
    assert turn_words([1, 0, 0], [0, 0, 1]) == "turn it nose up about 90 deg"
    # field to the right (+Y) to be seen along -Z: the right side goes down (roll right)
    assert turn_words([0, 1, 0], [0, 0, -1]) == "turn it roll right about 90 deg"
    # field ahead to be seen on the right: the nose turns left (yaw left)
    assert turn_words([1, 0, 0], [0, 1, 0]) == "turn it yaw left about 90 deg"
    assert turn_words([1, 0, 0], [0, 1, -1]) == "turn it nose down and yaw left about 90 deg"


def test_live_status_on_a_cap_and_on_the_sphere():
    cap = live_status(spiral()[:500])
    assert not cap.enough and cap.gap_deg > 100 and "turn it" in cap.prompt
    assert cap.fit == "sphere"                  # a full model only once the gap is small
    full = live_status(spiral())
    assert full.enough and full.quality == 1.0 and full.fit == "ellipsoid"
    assert full.error_p95_pct < 1.5 and full.coverage == 1.0
    assert live_status(spiral()[:10]).prompt == "waiting for samples"


def test_view_fits_80_by_24_with_half_blocks():
    from magbench.cli.capture import _half_blocks, render
    from magbench.cli.live import map_rows
    from magbench.core.verdict import Gate

    status = live_status(spiral()[:700])
    head = ["magbench capture   port /dev/ttyACM0   Raw: lines (MotionCal)", "  units 0.1uT",
            "  recording cal/capture.csv", "  700 samples   3.5 s   0 lines skipped"]
    half = render(status, head=head, gate=Gate(), stop="enough", keys=True, map_style="half")
    full = render(status, head=head, gate=Gate(), stop="enough", keys=True)
    assert len(half) <= 23 and max(map(len, half)) <= 80
    assert len(full) <= 30 and max(map(len, full)) <= 80
    # the half-block map holds the same cells, two bands per row
    rows = map_rows(status.cells)
    halves = _half_blocks(rows)
    assert len(halves) == len(rows) // 2
    assert sum(r.count("#") for r in rows) == len(status.cells) == sum(
        2 * r.count("\u2588") + r.count("\u2580") + r.count("\u2584") for r in halves)
