"""The bench section's scale paragraph, from ``bench/scale.csv`` (:mod:`magbench.studies.scale`).

Growth exponents between the smallest and the largest run: ``log(y1 / y0) / log(n1 / n0)``,
1 for a cost linear in the trials, 0 for a constant one.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magbench.report.format import compact_number, render

__all__ = ["PHASES", "growth_exponent", "scale_lines"]

#: The timed phases of one size, summed into its whole run.
PHASES = ("run_s", "summarize_s", "intervals_s")


def growth_exponent(scale: pd.DataFrame, column: str) -> float:
    """The log-log slope of ``column`` between the smallest and the largest ``trials``."""
    ends = scale.sort_values("trials").iloc[[0, -1]]
    n0, n1 = ends["trials"].to_numpy(float)
    y0, y1 = ends[column].to_numpy(float)
    return float(np.log(y1 / y0) / np.log(n1 / n0))


def _exponent(scale: pd.DataFrame, column: str) -> str:
    """:func:`growth_exponent` to two decimals, a rounded-away negative zero as 0.00."""
    text = f"{growth_exponent(scale, column):.2f}"
    return "0.00" if text == "-0.00" else text


def scale_lines(scale: pd.DataFrame) -> list[str]:
    """Markdown lines: the paragraph on how the time and the memory grow with the trials
    (none with fewer than two sizes)."""
    if scale["trials"].nunique() < 2:
        return []
    scale = scale.assign(total_s=scale[list(PHASES)].sum(axis=1))
    small, large = (scale.sort_values("trials").iloc[i] for i in (0, -1))
    return ["", render(
        "bench.scale", methods=int(small["methods"]), n0=int(small["trials"]),
        n1=int(large["trials"]), time0=compact_number(small["total_s"]),
        time1=compact_number(large["total_s"]),
        time_exp=_exponent(scale, "total_s"),
        mem0=f"{small['peak_rss_mb']:.0f}", mem1=f"{large['peak_rss_mb']:.0f}",
        mem_exp=_exponent(scale, "peak_rss_mb"),
        worker1=f"{large['worker_peak_rss_mb']:.0f}",
        worker_exp=_exponent(scale, "worker_peak_rss_mb"))]
