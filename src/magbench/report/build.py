"""``results/report.md``: the sections in order, each a function of the results folder.

Nothing here simulates: every section reads the CSV files under the results folder and
returns its Markdown ('' when its files are absent).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

from magbench.core.files import write_text_atomic
from magbench.report.advice import advice_section
from magbench.report.baseline import baseline_section
from magbench.report.claims import claims_section
from magbench.report.efficiency import efficiency_section
from magbench.report.format import render
from magbench.report.speed import bench_report_section
from magbench.report.sweeps import SWEEP_SECTIONS, sweep_section
from magbench.report.table2 import write_sweep_tables

__all__ = ["REVIEW_SECTIONS", "Section", "build_report", "header_section", "write_report",
           "write_sweep_tables"]

#: A report section: the results folder -> its Markdown ('' when it has nothing to say).
Section = Callable[[Path], str]


def header_section(results_dir: Path) -> str:
    """The report's title and what it compares."""
    return render("header.header")


#: The review's sections, in report order: title, advice, Table 2, Figures 2-5 and
#: coverage, large K, the claims.
REVIEW_SECTIONS: tuple[Section, ...] = (
    header_section, advice_section, baseline_section,
    *(partial(sweep_section, sweep=s) for s in SWEEP_SECTIONS), efficiency_section,
    claims_section)
def build_report(results_dir: Path | str, sections: Sequence[Section] = ()) -> str:
    """The Markdown of ``results/report.md``, from the CSV files under ``results_dir``:
    :data:`REVIEW_SECTIONS`, then ``sections`` (the study kinds' own parts, in the registry's
    order), then the benchmark's, each ending with a blank line; empty sections are left
    out."""
    results_dir = Path(results_dir)
    parts = (section(results_dir) for section in (*REVIEW_SECTIONS, *sections,
                                                   bench_report_section))
    return "\n".join(part.strip() + "\n" for part in parts if part)


def write_report(results_dir: Path | str, sections: Sequence[Section] = ()) -> Path:
    """Write ``<results_dir>/report.md`` from the CSV files (figures are drawn separately);
    ``sections`` as in :func:`build_report`."""
    results_dir = Path(results_dir)
    path = results_dir / "report.md"
    write_text_atomic(build_report(results_dir, sections), path)
    return path
