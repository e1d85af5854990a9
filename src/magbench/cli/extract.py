"""``python -m magbench extract file=LOG [instance=N] [out=CSV]``: a flight log as CSV.

Reads one compass of a PX4 ULog or ArduPilot DataFlash log (:mod:`magbench.sources.logs`)
with every other stream interpolated onto its sample times, and writes the columns a CSV
recording has (``t, mx, my, mz``, then ``gx..gz``, ``ax..az``, ``qw..qz``, ``current``,
``throttle``, ``temperature`` as the log has them; a missing value is an empty cell, and so
is a value the log holds as infinite: the line printed counts the blank cells of each
column), so that ``calibrate`` and ``apply`` read the written file as they read the log.
What the reader left out (a cut file, compass lines dropped) is said in a warning line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from magbench.cli.apply import output_csv
from magbench.cli.config import UsageError, check_instance
from magbench.core.files import write_csv_atomic
from magbench.sources.logs import LOG_SUFFIXES, is_log, rate_hz, read_log

__all__ = ["run_extract"]


def run_extract(cfg: DictConfig) -> int:
    """The ``extract`` command; a bad file or value raises :class:`UsageError`."""
    if not cfg.get("file"):
        raise UsageError("extract needs file=PATH, a flight log (" + ", ".join(LOG_SUFFIXES)
                         + ")")
    path = Path(str(cfg.file))
    if not is_log(path):
        raise UsageError(f"extract reads flight logs ({', '.join(LOG_SUFFIXES)}); {path.name} "
                         "is not one (a CSV is read by calibrate and apply as it is)")
    instance = check_instance(cfg)
    out = output_csv(cfg, path, Path(f"{path.stem}.csv"), "data.csv")
    try:
        log = read_log(path)
        chosen = log.choose(instance)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    table = log.table(chosen)
    # A value the log holds as inf is no measurement: written as a blank cell and counted
    # with the blanks, never as "inf" (which calibrate and apply would refuse).
    values = table.to_numpy(dtype=float)
    infinite = {c: int(n) for c, n in zip(table.columns, np.isinf(values).sum(axis=0),
                                          strict=True) if n}
    table = table.mask(np.isinf(values))
    write_csv_atomic(table, out)
    t = table["t"].to_numpy()
    device = f"device {log.devices[chosen]}, " if chosen in log.devices else ""
    gaps = {c: int(table[c].isna().sum()) for c in table.columns if table[c].isna().any()}
    missing = ("; no value (outside the stream or in a gap"
               + (", or not finite in the log" if infinite else "") + "): "
               + ", ".join(f"{c} {n}" for c, n in gaps.items())) if gaps else ""
    for note in log.notes:
        print(f"warning: {note}")
    print(f"{path.name}: compass instance {chosen} ({device}{log.units}), {len(t)} samples at "
          f"{rate_hz(t):.3g} Hz from t = {np.nanmin(t):.3f} to {np.nanmax(t):.3f} s; columns "
          f"{', '.join(table.columns)}{missing}; wrote {out}")
    return 0
