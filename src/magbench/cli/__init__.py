"""Command line: ``python -m magbench [COMMAND] [key=value ...]``.

The configuration is composed with Hydra's compose API from ``conf/`` and checked once
(:mod:`magbench.cli.config`), so a bad value gives one line and exit status 2 before any result
is touched. ``python -m magbench --help`` lists the commands.
"""

from magbench.cli.main import main

__all__ = ["main"]
