"""``python -m magbench sweep=gamma``: see :mod:`magbench.cli` (the process settings, one BLAS
thread and glibc's malloc thresholds, are made by :func:`magbench.cli.main.main`)."""

from magbench.cli import main

raise SystemExit(main())
