"""Markdown tables from the result CSV files, with the paper's numbers side by side.

Nothing here simulates: every table is computed from ``summary.csv`` (or ``trials.csv``).
"""

from __future__ import annotations

from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from magbench.api import get_method

__all__ = ["format_number", "paper_values", "table2", "table2_markdown", "write_sweep_tables"]


@cache
def paper_values() -> dict:
    """The published numbers (copied from the source documents into the package)."""
    text = resources.files("magbench").joinpath("reference/paper_values.yaml").read_text()
    return _numbers(yaml.safe_load(text))


def _numbers(node: object) -> object:
    # PyYAML follows YAML 1.1, which reads exponent floats without a sign ("3.31e3") as strings.
    if isinstance(node, dict):
        return {k: _numbers(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_numbers(v) for v in node]
    if isinstance(node, str):
        try:
            return float(node)
        except ValueError:
            return node
    return node


def format_number(x: float, digits: int = 3) -> str:
    """Compact significant-figure formatting for tables; blank-safe for NaN."""
    if x is None or not np.isfinite(x):
        return "-"
    return f"{x:.{digits}g}"


def _label(name: str) -> str:
    try:
        return get_method(name).label
    except ValueError:
        return name


def table2(summary: pd.DataFrame) -> pd.DataFrame:
    """The baseline summary beside the review's Table 2, one row per method.

    Columns: method, accuracy (1/rho) here and in the paper, their ratio, RB % here and in the
    paper, speed (1/tau) here and in the paper, and the speed ratio.
    """
    paper = paper_values()["review"]["table2"]
    rows = []
    for rec in summary.itertuples(index=False):
        key = None
        try:
            key = get_method(rec.algorithm).paper_key
        except ValueError:
            pass
        ref = paper.get(key, {}) if key else {}
        rows.append({
            "method": _label(rec.algorithm),
            "accuracy": rec.accuracy, "accuracy_paper": ref.get("accuracy", np.nan),
            "RB_pct": rec.RB_pct, "RB_pct_paper": ref.get("robustness_pct", np.nan),
            "speed_hz": rec.speed_hz, "speed_hz_paper": ref.get("speed_hz", np.nan),
        })
    out = pd.DataFrame(rows)
    out["accuracy_ratio"] = out["accuracy"] / out["accuracy_paper"]
    out["speed_ratio"] = out["speed_hz"] / out["speed_hz_paper"]
    return out


def table2_markdown(summary: pd.DataFrame, delta: float) -> str:
    """Markdown of :func:`table2` with a short legend."""
    t = table2(summary)
    n = int(summary["n"].max())
    lines = [
        "| method | accuracy 1/rho | paper | ratio | RB % | paper | speed 1/tau (1/s) | paper "
        "| ratio |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in t.itertuples(index=False):
        lines.append(
            f"| {r.method} | {format_number(r.accuracy)} | {format_number(r.accuracy_paper)} | "
            f"{format_number(r.accuracy_ratio, 2)} | {format_number(r.RB_pct)} | "
            f"{format_number(r.RB_pct_paper)} | {format_number(r.speed_hz)} | "
            f"{format_number(r.speed_hz_paper)} | {format_number(r.speed_ratio, 2)} |")
    legend = (f"\n{n} trials at the nominal point of eq. (80), delta = {delta} in eq. (76). "
              "Accuracy is 1/rho with rho the mean J (74) over meaningful runs (78); speed is "
              "1/tau, tau the mean time of one calibration call over meaningful runs (79); "
              "'paper' is the review's Table 2 (MATLAB timings); ratio = here / paper.\n")
    return "\n".join(lines) + "\n" + legend


def write_sweep_tables(name: str, summary: pd.DataFrame, out_dir: Path, delta: float) -> None:
    """Tables a finished sweep writes beside its CSV files (``table2.md`` for the baseline)."""
    from magbench.runner import write_text_atomic

    if name == "baseline":
        write_text_atomic("# Baseline (Table 2)\n\n" + table2_markdown(summary, delta),
                          Path(out_dir) / "table2.md")
