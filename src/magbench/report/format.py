"""Formatting shared by every report section: numbers, labels, Markdown tables."""

from __future__ import annotations

import numpy as np
import pandas as pd

from magbench.methods.registry import get_method

__all__ = ["format_number", "label", "md_table"]


def format_number(x: float, digits: int = 3) -> str:
    """Compact significant-figure formatting for tables; blank-safe for NaN."""
    if x is None or not np.isfinite(x):
        return "-"
    return f"{x:.{digits}g}"


def label(name: str) -> str:
    try:
        return get_method(name).label
    except ValueError:
        return name


def md_table(frame: pd.DataFrame, digits: int = 3) -> str:
    """A Markdown table of ``frame``; floats to ``digits`` significant figures."""
    cols = list(frame.columns)
    lines = ["| " + " | ".join(map(str, cols)) + " |", "|" + "---|" * len(cols)]
    for row in frame.itertuples(index=False):
        cells = [format_number(v, digits) if isinstance(v, float | np.floating) else str(v)
                 for v in row]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
