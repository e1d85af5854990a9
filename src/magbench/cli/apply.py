"""``python -m magbench apply calibration=JSON file=CSV [out=CSV] [columns=[...]]``.

Corrects a recording with a saved calibration: reads the ``calibration.json`` that ``calibrate``
wrote (schema of :func:`magbench.core.exports.from_json_dict`, the correction
``m = A (y - b)``), reads the samples (:func:`magbench.sources.recordings.read_samples`; no
coverage check, since a calibration applies to any sample, even one) and writes the corrected
samples to ``out`` under the same column names (a unit suffix such as ``(µT)`` replaced by
``(1 = calibrated field)``, the corrected samples' unit), after the time column ``t`` when the
file has one. The columns are ``columns=[...]`` if given, else those the calibration was
fitted on (the JSON's ``columns``), else ``mx, my, mz``. Rows with a missing value are
dropped with a warning line, as in ``calibrate``.

The median field magnitude after correction is checked: the Earth's field strength differs by
at most about 3x between sites (22-67 uT), so a median beyond 3x or below 1/3 of the
calibrated field means the calibration does not fit the recording (another sensor or another
unit): FAIL, exit 3, nothing written. Beyond 25 % it warns (another site, or a poor fit).
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig

from magbench.cli.config import UsageError, check_columns, check_instance, writable_folder
from magbench.core.exports import from_json_dict
from magbench.core.files import write_csv_atomic
from magbench.core.model import Calibration
from magbench.sources.recordings import Recording, read_samples, without_unit

__all__ = ["CORRECTED_UNIT", "corrected_frame", "corrected_names", "load_calibration", "output_csv",
           "run_apply"]

#: The Earth's field strength spans about 22-67 uT: no site changes it by more than this factor.
FIELD_RATIO_FAIL = 3.0
#: A median magnitude this far (%) from the calibrated field warns.
FIELD_WARN_PCT = 25.0


def load_calibration(path: Path) -> tuple[Calibration, list | None]:
    """The calibration in a written JSON file and the columns it records (None if absent).

    Raises
    ------
    UsageError
        Missing file, invalid JSON or a file that is not a magbench calibration; one line.
    """
    if not path.is_file():
        raise UsageError(f"calibration file {path} not found; expected the calibration.json "
                         "written by python -m magbench calibrate")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"calibration file {path} is not valid JSON ({exc}); expected the "
                         "calibration.json written by python -m magbench calibrate") from None
    if isinstance(data, dict) and data.get("status") == "FAIL":
        reasons = "; ".join(data.get("fitness", {}).get("reasons", [])) or "see the file"
        raise UsageError(f"{path}: calibrate judged this recording FAIL ({reasons}); it holds "
                         "no correction to apply")
    try:
        cal = from_json_dict(data)
    except ValueError as exc:
        raise UsageError(f"{path}: {exc}") from None
    columns = data.get("columns")
    if columns is not None and (not isinstance(columns, list) or len(columns) != 3):
        raise UsageError(f"{path}: columns must list the three input columns, got {columns!r}")
    return cal, columns


def output_csv(cfg: DictConfig, source: Path, default: Path, example: str) -> Path:
    """The CSV file to write: ``out``, else ``default``; refuses a folder (suggesting
    ``example`` inside it), the input file itself, or an existing file without
    ``overwrite=true``, and checks its folder can be written."""
    out = Path(str(cfg.out)) if cfg.get("out") else default
    if out.is_dir():
        raise UsageError(f"out={out} is a folder; expected the name of the CSV file to write, "
                         f"e.g. out={out / example}")
    if out.exists() and out.resolve() == source.resolve():
        raise UsageError(f"out={out} is the input file; choose another name")
    if out.exists() and cfg.get("overwrite") is not True:
        raise UsageError(f"out={out} exists; choose another name or pass overwrite=true to "
                         "replace it")
    writable_folder(out.parent, "the folder of out")
    return out


#: What a corrected column holds, in place of the unit it was recorded in.
CORRECTED_UNIT = "1 = calibrated field"


def corrected_names(columns: list[str]) -> list[str]:
    """The output's column names: the input's, with a unit suffix replaced by
    :data:`CORRECTED_UNIT` (the corrected field is no longer in uT or counts); ``mx, my, mz``
    for a file without a header, which has no names to keep."""
    names = []
    for axis, column in zip("xyz", columns, strict=True):
        if column.startswith("column "):
            names.append(f"m{axis}")
            continue
        bare, had_unit = without_unit(column)
        names.append(f"{bare} ({CORRECTED_UNIT})" if had_unit else column)
    return names


def corrected_frame(rec: Recording, cal: Calibration, names: list[str]) -> pd.DataFrame:
    """``t`` (if recorded) and the corrected samples ``A (y - b)`` under ``names``."""
    m = cal.apply(rec.y)
    frame = pd.DataFrame(m, columns=names)
    if rec.t is not None:
        frame.insert(0, "t", rec.t)
    return frame


def run_apply(cfg: DictConfig) -> int:
    """The ``apply`` command; a bad file or value raises :class:`UsageError`."""
    if not cfg.get("calibration"):
        raise UsageError("apply needs calibration=PATH, the calibration.json written by "
                         "python -m magbench calibrate")
    if not cfg.get("file"):
        raise UsageError("apply needs file=PATH, a CSV of magnetometer samples to correct")
    where = Path(str(cfg.calibration))
    from magbench.cli.outfolder import check_manifest

    problem = check_manifest(where.parent) if where.name == "calibration.json" else ""
    if problem:
        raise UsageError(f"{problem}; rerun calibrate, or copy calibration.json out alone "
                         "if you changed it on purpose")
    cal, recorded = load_calibration(where)
    path = Path(str(cfg.file))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            rec = read_samples(path, check_columns(cfg, recorded), min_samples=1, check=False,
                               instance=check_instance(cfg))
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    for w in caught:
        print(f"magbench: warning: {w.message}", file=sys.stderr)
    out = output_csv(cfg, path, Path(f"{rec.name}-corrected.csv"), "corrected.csv")
    names = corrected_names(rec.columns)
    frame = corrected_frame(rec, cal, names)
    median = float(np.median(np.linalg.norm(frame[names].to_numpy(), axis=1)))
    if not 1 / FIELD_RATIO_FAIL <= median <= FIELD_RATIO_FAIL:
        print(f"FAIL  field magnitude {median:.4g} (median, 1 = calibrated field) after "
              f"correcting {path.name}: no site's field differs by more than "
              f"{FIELD_RATIO_FAIL:g}x, so this calibration does not fit the recording (another "
              "sensor, or another unit); nothing written")
        return 3
    write_csv_atomic(frame, out)
    print(f"{path.name}: corrected {rec.K} samples (columns {', '.join(rec.columns)}) with "
          f"m = A (y - b); field magnitude {median:.4f} (median, 1 = calibrated field); wrote "
          f"{out}")
    if abs(median - 1) * 100 > FIELD_WARN_PCT:
        print(f"magbench: warning: the median field magnitude is {abs(median - 1) * 100:.0f} % "
              "from the calibrated field: expected at a site with another field strength, "
              "else the calibration does not fit this sensor", file=sys.stderr)
    return 0
