"""Step 1 of ``calibrate``, *read*: one recording from a CSV file or a flight log.

The readers are :func:`magbench.sources.recordings.read_samples` (columns, units, chunks) and
:mod:`magbench.sources.logs`; this step asks them for enough samples for the method (or the
fewest any method needs), refuses samples that cover too little of the sphere
(:data:`MIN_COVERAGE`), takes a log's compass unit when none is given, and checks the
regressors of the time-varying terms. The reader's warnings go to the caller's ``warn``, not
to the console: the command line (:mod:`magbench.cli.calibrate`) prints them, one line each.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

from magbench.core.units import Units, parse_units
from magbench.methods.registry import get_method, methods
from magbench.pipeline.flight import check_regressors
from magbench.sources.logs import is_log, log_units
from magbench.sources.recordings import Recording, read_samples

__all__ = ["MIN_COVERAGE", "read_recording", "recording_units"]

#: Coverage below which a recording is refused: lower than the sweeps' 0.3, because thin
#: coverage now falls back to the sphere model instead of a full fit (a hemisphere of real
#: data can measure 0.28).
MIN_COVERAGE = 0.2


def recording_units(path: Path, units: Units) -> Units:
    """``units`` as given, or a flight log's compass unit (the firmware's) when none is."""
    if not units.known and not units.counts and is_log(path):
        return parse_units(log_units(path))
    return units


def read_recording(path: Path, columns: list | None = None, *, method: str | None = None,
                   instance: str | None = None, compensate: Sequence[str] | None = None,
                   warn: Callable[[str], None] | None = None) -> Recording:
    """The recording at ``path``.

    Parameters
    ----------
    path : Path
        A CSV file or a flight log.
    columns : list, optional
        The magnetometer's columns (names or indices); by default the reader's choice.
    method : str, optional
        The one method to fit, whose least sample count is required; by default the least of
        any method's.
    instance : str, optional
        A log's compass.
    compensate : sequence of str, optional
        Time-varying terms whose regressors the recording must hold.
    warn : callable, optional
        Called with each of the reader's warnings, in order, once the file is read (before the
        regressors are checked); by default they are dropped.

    Returns
    -------
    Recording

    Raises
    ------
    ValueError
        Unreadable, too short, too little of the sphere, or without a regressor asked for; one
        line saying what was wrong.
    """
    need = get_method(method).min_samples if method else min(
        get_method(m).min_samples for m in methods())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rec = read_samples(path, columns, min_samples=need, min_coverage=MIN_COVERAGE,
                           instance=instance)
    for w in caught:
        if warn is not None:
            warn(str(w.message))
    if compensate:
        check_regressors(rec, compensate)
    return rec
