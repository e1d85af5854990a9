"""Report section of the gyro sweep, from ``<results_dir>/gyro`` CSV files alone."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from magbench.methods.registry import find_method
from magbench.report.intervals import rb_interval, run_note

__all__ = ["gyro_report_section"]


def gyro_report_section(results_dir: Path | str) -> str:
    """Markdown for the report: median J (RB %) per method and coverage at the lowest non-zero
    gyro noise, median gyro-bias error, and the figure. Reads only ``<results_dir>/gyro``."""
    path = Path(results_dir) / "gyro" / "summary.csv"
    if not path.exists():
        return "## Gyro-aided calibration\n\nNo results yet: run `python -m magbench sweep=gyro`.\n"
    s = pd.read_csv(path)
    levels = sorted(s["gyro_noise"].unique())
    level = next((g for g in levels if g > 0), levels[0])
    sub = s[s["gyro_noise"] == level]
    coverages = list(dict.fromkeys(sub["coverage"]))
    order = list(dict.fromkeys(sub["algorithm"]))
    lines = ["## Gyro-aided calibration (simulated manoeuvres)", "",
             f"Median J (eq. 74) and, in brackets, RB % (eq. 77) at gyro noise {level:g} rad/s "
             f"and magnetometer noise {sub['sigma'].iloc[0]:g}; gyro-bias error |d - d_true| "
             "(rad/s, median) for the methods that estimate it. Gyro-aided methods are marked *."
             " SAR methods and MagFactor3 estimate no soft iron (T = I, T = s I), so their J "
             "includes the whole soft-iron error; MAGYC-LS and SAR assume an unbiased gyro. "
             "RB % carries its 95 % Wilson interval.", "",
             run_note(Path(results_dir) / "gyro", "manoeuvres per point"), "",
             "| method | " + " | ".join(coverages) + " | gyro bias error |",
             "|---|" + "---|" * (len(coverages) + 1)]
    for name in order:
        cells = []
        for cov in coverages:
            r = sub[(sub["algorithm"] == name) & (sub["coverage"] == cov)]
            if len(r):
                lo, hi = rb_interval(r.iloc[0])
                cells.append(f"{r['median_J'].iloc[0]:.2e} ({r['RB_pct'].iloc[0]:.0f} "
                             f"[{lo:.0f}, {hi:.0f}])")
            else:
                cells.append("-")
        wb = sub[sub["algorithm"] == name]["median_J_wb"]
        wb_text = f"{wb.median():.1e}" if wb.notna().any() else "-"
        spec = find_method(name)
        label = name if spec is None else spec.label + (" *" if spec.needs_gyro else "")
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {wb_text} |")
    lines += ["", "![median J against gyro noise](gyro/gyro_J.png) "
              "(numbers: `gyro/gyro_J.csv`)", ""]
    return "\n".join(lines)
