"""Formatting shared by every report section: numbers, labels, Markdown tables, templates."""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import cache
from importlib import resources

import numpy as np
import pandas as pd

from magbench.methods.registry import method_label

__all__ = ["HTML_ONLY", "compact_number", "format_number", "html_only", "md_table", "names",
           "render", "shorten_for_markdown"]

#: Markers of a block only ``report.html`` shows (the Markdown report names it instead).
HTML_ONLY = ("<!-- html-only: ", " -->", "<!-- /html-only -->")
#: Tables longer than this many rows are left to ``report.html`` in the Markdown report.
MD_MAX_ROWS = 20


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


def html_only(markdown: str, what: str) -> str:
    """``markdown`` shown only in ``report.html``; the Markdown report says ``what`` is
    there instead (:func:`shorten_for_markdown`)."""
    start, close, end = HTML_ONLY
    return f"{start}{what}{close}\n{markdown}\n{end}"


def shorten_for_markdown(markdown: str) -> str:
    """The Markdown report's text: :func:`html_only` blocks and tables over
    :data:`MD_MAX_ROWS` rows replaced by one line naming what ``report.html`` holds."""
    start, close, end = HTML_ONLY
    pattern = re.escape(start) + r"(.*?)" + re.escape(close) + r"\n.*?\n" + re.escape(end)
    text = re.sub(pattern, lambda m: f"*{m[1]}: in `report.html`.*", markdown,
                  flags=re.DOTALL)
    out, table = [], []
    for line in [*text.split("\n"), ""]:
        if line.startswith("|"):
            table.append(line)
            continue
        if table:
            if len(table) - 2 > MD_MAX_ROWS:
                head = [c.strip() for c in table[0].strip().strip("|").split("|")]
                out.append(f"*A table of {len(table) - 2} rows ({', '.join(head[:4])}, ...): "
                           "in `report.html`.*")
            else:
                out += table
            table = []
        out.append(line)
    return "\n".join(out[:-1])


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
