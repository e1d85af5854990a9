"""A magbench process's settings: one BLAS thread and glibc's malloc thresholds, as defaults."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from magbench.cli.process import PROCESS_ENV

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"

# Each case runs in a fresh interpreter: mallopt changes the process for good.
_CONFIGURE = """
import os
from magbench.cli.process import configure_process
applied = configure_process()
print(applied, os.environ["OPENBLAS_NUM_THREADS"], os.environ["MALLOC_MMAP_THRESHOLD_"])
"""


def configure(**env: str) -> list[str]:
    clean = {k: v for k, v in os.environ.items() if k not in PROCESS_ENV}
    done = subprocess.run([sys.executable, "-c", _CONFIGURE], env={**clean, **env},
                          capture_output=True, text=True, timeout=60, check=True)
    return done.stdout.split()


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
def test_the_defaults_are_set_and_applied():
    assert configure() == ["True", "1", str(32 << 20)]


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
def test_values_in_the_environment_are_kept():
    assert configure(OPENBLAS_NUM_THREADS="2", MALLOC_MMAP_THRESHOLD_="65536") == [
        "True", "2", "65536"]


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
@pytest.mark.parametrize("value", ["lots", "-1", str(1 << 40)])
def test_a_threshold_mallopt_cannot_take_is_not_applied(value):
    # not a number, negative, or beyond mallopt's C int: the process starts all the same
    assert configure(MALLOC_MMAP_THRESHOLD_=value) == ["False", "1", value]


def test_a_command_passes_the_settings_to_the_processes_it_starts():
    script = ("import atexit, os, sys\n"
              "keys = sys.argv[1:]\n"
              "atexit.register(lambda: print(*(os.environ.get(k) for k in keys), flush=True))\n"
              "sys.argv = ['magbench', '--version']\n"
              "from magbench.cli.main import main\n"
              "raise SystemExit(main())\n")
    clean = {k: v for k, v in os.environ.items() if k not in PROCESS_ENV}
    done = subprocess.run([sys.executable, "-c", script, *PROCESS_ENV], env=clean,
                          capture_output=True, text=True, timeout=60, check=True)
    assert done.stdout.splitlines()[-1].split() == list(PROCESS_ENV.values())
