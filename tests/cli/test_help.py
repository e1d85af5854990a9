"""The CLI explains itself: every command's --help, `methods` and --version, in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from magbench.cli.main import COMMANDS
from magbench.methods.registry import get_method, methods

SRC = Path(__file__).resolve().parents[2] / "src"
SWEEPS = sorted(p.stem for p in (SRC.parent / "conf" / "sweep").glob("*.yaml"))


def magbench(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    return subprocess.run([sys.executable, "-m", "magbench", *args], capture_output=True,
                          text=True, env=env, timeout=120)


def test_the_sweep_list_is_found():
    assert {"baseline", "gamma", "real", "wushi", "gyro"} <= set(SWEEPS)


def test_general_help_names_every_command_and_sweep():
    out = magbench("--help")
    assert out.returncode == 0, out.stderr
    for command in COMMANDS:
        assert f"\n  {command} " in out.stdout, command
    for sweep in SWEEPS:
        assert f"\n  {sweep} " in out.stdout, sweep


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_each_command_help_lists_its_keys_and_the_methods(command):
    out = magbench(command, "--help")
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"python -m magbench {command} ")
    for key in COMMANDS[command][3]:
        assert f"\n  {key} " in out.stdout, key
    if "algorithms" in COMMANDS[command][3] or "method" in COMMANDS[command][3]:
        for name in methods():
            assert name in out.stdout, name
    if "sweep" in COMMANDS[command][3]:
        for sweep in SWEEPS:
            assert sweep in out.stdout, sweep


def test_methods_prints_the_registry():
    out = magbench("methods")
    assert out.returncode == 0, out.stderr
    rows = {line.split()[0]: line for line in out.stdout.splitlines()[1:] if line.strip()}
    for name in methods():
        spec = get_method(name)
        assert name in rows, name
        assert spec.label in rows[name] and spec.family in rows[name]
        # angular_rate, time and acceleration are the inertial data, not tuning options.
        for option in set(spec.option_names()) - {"angular_rate", "time", "acceleration"}:
            assert option in rows[name], (name, option)
        assert ("needs an accelerometer" in rows[name]) == spec.needs_accel


def test_version_and_a_closed_pipe():
    from magbench import __version__

    out = magbench("--version")
    assert (out.returncode, out.stdout.strip()) == (0, f"magbench {__version__}")
    # `magbench methods | head -1`: the reader leaves early; no traceback.
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    piped = subprocess.run(f"{sys.executable} -m magbench methods | head -1", shell=True,
                           capture_output=True, text=True, env=env, timeout=120)
    assert piped.stdout.startswith("name")
    assert "Traceback" not in piped.stderr
