"""Report: Markdown from the result CSV files, with the paper's numbers side by side.

Nothing here runs a study or draws a figure: every table and verdict is computed from CSV files.
"""

from magbench.report.build import build_report, write_report

__all__ = ["build_report", "write_report"]
