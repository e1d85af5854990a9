"""``report.md`` and ``report.html``: the sections in order, each a function of the results
folder.

Nothing here simulates: every section reads the CSV files under the results folder and
returns its Markdown ('' when its files are absent). A new section is one function
``results_dir -> Markdown`` added to :data:`REVIEW_SECTIONS` (or, for a study kind, the kind's
``report``); both the Markdown report and the page pick it up, with its ``##`` title in both
tables of contents. :data:`HTML_DETAILS` adds Markdown that only the page shows, folded under
a section (the Markdown report stays short).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

from magbench.core.files import write_text_atomic
from magbench.report.advice import advice_section
from magbench.report.baseline import baseline_section
from magbench.report.claims import claims_section
from magbench.report.decision import decision_section
from magbench.report.efficiency import efficiency_section
from magbench.report.format import render, shorten_for_markdown
from magbench.report.html import section_text, slug, write_html
from magbench.report.kept import kept_intervals
from magbench.report.speed import bench_report_section
from magbench.report.sweeps import SWEEP_SECTIONS, sweep_section
from magbench.report.table2 import write_sweep_tables
from magbench.report.table4 import table4_section

__all__ = ["HTML_DETAILS", "INTERVALS_FILE", "REVIEW_SECTIONS", "Section", "build_report",
           "contents", "header_section", "link_sections", "write_markdown_report", "write_report",
           "write_sweep_tables"]

#: Beside report.md: the bootstrap intervals its sections drew (:func:`kept_intervals`).
INTERVALS_FILE = "report_intervals.json"

#: A report section: the results folder -> its Markdown ('' when it has nothing to say).
Section = Callable[[Path], str]


def header_section(results_dir: Path) -> str:
    """The report's title and what it compares."""
    return render("header.header")


#: The review's sections, in report order: title, the answer (decision table), Table 2,
#: Figures 2-5 and coverage, large K, the claims, Table 4 and the conclusions.
REVIEW_SECTIONS: tuple[Section, ...] = (
    header_section, decision_section, baseline_section,
    *(partial(sweep_section, sweep=s) for s in SWEEP_SECTIONS), efficiency_section,
    claims_section, table4_section)
#: Section -> Markdown only the page shows, folded under it: the advice's reasoning in full.
HTML_DETAILS: dict[Section, Section] = {decision_section: advice_section}


def contents(markdown: str) -> str:
    """A Markdown table of contents of the report's ``##`` sections (GitHub's anchors)."""
    titles = [line[3:].strip() for line in markdown.split("\n") if line.startswith("## ")]
    return "\n".join(f"- [{t.replace('`', '')}](#{slug(t)})" for t in titles)


_SECTION_REF = re.compile(r"the section '([^']+)'")


def link_sections(markdown: str) -> str:
    """References to another section (``the section 'Title'``) as links when the report has
    a section of that title, and, when it has not, the parenthesis holding the reference left
    out: a report built from other results never points to a section it does not have."""
    titles = {re.sub(r"[`*]", "", line[3:].split(":")[0]).strip(): slug(line[3:])
              for line in markdown.split("\n") if line.startswith("## ")}

    def link(m: re.Match) -> str:
        anchor = titles.get(m[1])
        return f"[the section '{m[1]}'](#{anchor})" if anchor else m[0]

    markdown = re.sub(r" ?\([^()]*the section '([^']+)'[^()]*\)",
                      lambda m: m[0] if m[1] in titles else "", markdown)
    return _SECTION_REF.sub(link, markdown)


def build_report(results_dir: Path | str, sections: Sequence[Section] = (),
                 texts: dict | None = None) -> str:
    """The Markdown of ``results/report.md``, from the CSV files under ``results_dir``:
    :data:`REVIEW_SECTIONS`, then ``sections`` (the study kinds' own parts, in the registry's
    order), then the benchmark's, each ending with a blank line; empty sections are left
    out. ``texts``: a store of section texts the page reuses
    (:func:`~magbench.report.html.section_text`)."""
    results_dir = Path(results_dir)
    parts = [section_text(section, results_dir, texts)
             for section in (*REVIEW_SECTIONS, *sections, bench_report_section)]
    text = link_sections(shorten_for_markdown(
        "\n".join(part.strip() + "\n" for part in parts if part)))
    toc = contents(text)
    if not toc:
        return text
    head, _, rest = text.partition("\n## ")
    return head + "\n**Contents**\n\n" + toc + "\n\n## " + rest


def write_markdown_report(results_dir: Path | str, sections: Sequence[Section] = (),
                          texts: dict | None = None) -> Path:
    """Write ``<results_dir>/report.md`` from the CSV files (it links the figures, so it may
    be written while they are drawn); ``sections`` and ``texts`` as in :func:`build_report`.
    Returns its path."""
    path = Path(results_dir) / "report.md"
    # The bootstrap intervals of rows that did not change (every method but one added) are
    # the last report's: each is keyed by a digest of its inputs.
    with kept_intervals(Path(results_dir) / INTERVALS_FILE):
        text = build_report(results_dir, sections, texts)
        if texts is not None:      # the page's folded details too, while the figures are drawn
            for extra in HTML_DETAILS.values():
                section_text(extra, results_dir, texts)
    write_text_atomic(text, path)
    return path


def write_report(results_dir: Path | str, sections: Sequence[Section] = (), *,
                 markdown: bool = True, texts: dict | None = None) -> Path:
    """Write ``<results_dir>/report.md`` (unless ``markdown`` is False: written already, by
    :func:`write_markdown_report`) and ``report.html`` from the CSV files (figures are drawn
    separately, before: the page embeds them); ``sections`` as in :func:`build_report`.
    Each section is computed once for both (``texts``: the store of a Markdown report
    written before). Returns the Markdown report's path."""
    results_dir = Path(results_dir)
    path = results_dir / "report.md"
    texts = {} if texts is None else texts
    if markdown:
        write_markdown_report(results_dir, sections, texts)
    write_html(results_dir, (*REVIEW_SECTIONS, *sections, bench_report_section), HTML_DETAILS,
               texts)
    return path
