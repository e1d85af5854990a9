"""Formatting shared by every report section: numbers, labels, Markdown tables, templates."""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import cache
from importlib import resources

import numpy as np
import pandas as pd

from magbench.methods.registry import method_label

__all__ = ["compact_number", "format_number", "md_table", "names", "render"]


def format_number(x: float, digits: int = 3) -> str:
    """Compact significant-figure formatting for tables; blank-safe for NaN."""
    if x is None or not np.isfinite(x):
        return "-"
    return f"{x:.{digits}g}"


def compact_number(x: float, digits: int = 3) -> str:
    """:func:`format_number` with the exponent written as papers print it (``2.28e5``,
    ``4.4e-6``), for numbers set into sentences."""
    return re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m[1] == "-" else "") + m[2],
                  format_number(x, digits))


def names(methods: Iterable[str]) -> str:
    """The methods' labels, comma-separated."""
    return ", ".join(method_label(n) for n in methods)


def md_table(frame: pd.DataFrame, digits: int = 3) -> str:
    """A Markdown table of ``frame``; floats to ``digits`` significant figures."""
    cols = list(frame.columns)
    lines = ["| " + " | ".join(map(str, cols)) + " |", "|" + "---|" * len(cols)]
    for row in frame.itertuples(index=False):
        cells = [format_number(v, digits) if isinstance(v, float | np.floating) else str(v)
                 for v in row]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


@cache
def _templates(section: str) -> dict[str, str]:
    """The named blocks of ``report/templates/<section>.md``: a line ``@@ name`` opens a
    block; within one, blank lines separate paragraphs and single line breaks are only for
    reading the file (they become spaces)."""
    text = resources.files("magbench.report").joinpath(f"templates/{section}.md").read_text()
    blocks = {}
    for chunk in re.split(r"^@@ ", text, flags=re.MULTILINE)[1:]:
        name, _, body = chunk.partition("\n")
        paragraphs = [" ".join(line.strip() for line in p.strip().split("\n"))
                      for p in body.strip().split("\n\n")]
        blocks[name.strip()] = "\n\n".join(paragraphs)
    return blocks


def render(name: str, **context: object) -> str:
    """The prose block ``<section>.<block>`` of ``report/templates/<section>.md`` filled from
    ``context`` (``str.format`` fields)."""
    section, _, block = name.partition(".")
    return _templates(section)[block].format(**context)
