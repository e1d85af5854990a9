"""run.json's machine helpers: the /proc parsing behind the CPU-time record."""

import os
import subprocess
import sys
import time

import pytest

from magbench.engine.record import _proc_cpu_ticks, cpu_seconds


def test_proc_stat_fields_are_counted_after_the_command_name():
    # A command name with spaces and parentheses must not shift the fields.
    stat = "4242 (a (b) c) S 17 4242 4242 0 -1 4194304 100 0 0 0 7 3 5 2 20 0 1 0 99 0 0"
    assert _proc_cpu_ticks(stat) == (17, 7 + 3 + 5 + 2)


@pytest.mark.skipif(not os.path.exists("/proc/self/stat"), reason="needs /proc (Linux)")
def test_a_live_childs_cpu_time_is_counted():
    # A child that burns CPU until killed: its CPU time is in cpu_seconds() while it runs,
    # before a wait() would move it into RUSAGE_CHILDREN. Our own CPU time is subtracted.
    def child_ticks() -> int:
        with open(f"/proc/{child.pid}/stat") as f:
            return _proc_cpu_ticks(f.read())[1]

    child = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        start = child_ticks()
        before, own = cpu_seconds(), time.process_time()
        while child_ticks() < start + 30:
            time.sleep(0.01)
        gained = cpu_seconds() - before - (time.process_time() - own)
        assert gained >= 25 / os.sysconf("SC_CLK_TCK")
    finally:
        child.kill()
        child.wait()
