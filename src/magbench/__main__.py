"""``python -m magbench sweep=gamma``: see :mod:`magbench.cli` (the process settings, one BLAS
thread and glibc's malloc thresholds, are made by :func:`magbench.cli.main.main`)."""

import os
import signal
import sys


def _interrupted_at_start(signum: int, frame: object) -> None:
    # A Ctrl-C while the command line's modules load: one line, as at any other moment.
    sys.stderr.write("magbench: interrupted; finished chunks are kept and a rerun completes "
                     "the rest\n")
    os._exit(130)


_previous = signal.signal(signal.SIGINT, _interrupted_at_start)
from magbench.cli import main  # noqa: E402  (after the handler: the import takes a while)

signal.signal(signal.SIGINT, _previous)
raise SystemExit(main())
