"""Report section of the speed study, from ``<results_dir>/bench`` CSV files alone."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.methods.registry import method_label
from magbench.report.format import format_number, render
from magbench.report.peer_accuracy import peer_accuracy_lines, peer_agreement_lines
from magbench.report.scale import scale_lines

__all__ = ["bench_report_section"]


def bench_report_section(results_dir: Path | str) -> str:
    """Markdown for results/report.md from ``<results_dir>/bench/*.csv`` (empty if absent)."""
    folder = Path(results_dir) / "bench"
    if (folder / "calls.csv").exists():
        lines = _calls_lines(pd.read_csv(folder / "calls.csv"))
    elif (folder / "scale.csv").exists():
        lines = ["## Speed (benchmark)"]
    else:
        return ""
    if (folder / "first_calls.csv").exists():
        lines += _first_call_lines(pd.read_csv(folder / "first_calls.csv"))
    if (folder / "peers.csv").exists():
        lines += _peer_lines(pd.read_csv(folder / "peers.csv"))
    if (folder / "peer_accuracy_summary.csv").exists():
        lines += peer_accuracy_lines(pd.read_csv(folder / "peer_accuracy_summary.csv"))
    if (folder / "peer_agreement_summary.csv").exists():
        lines += peer_agreement_lines(pd.read_csv(folder / "peer_agreement_summary.csv"))
    if (folder / "calibrate.csv").exists():
        lines += calibrate_lines(pd.read_csv(folder / "calibrate.csv"))
    if (folder / "parallel.csv").exists():
        lines += _parallel_lines(pd.read_csv(folder / "parallel.csv"))
    if (folder / "reproduce_cases.csv").exists():
        lines += reproduce_case_lines(pd.read_csv(folder / "reproduce_cases.csv"))
    if (folder / "scale.csv").exists():
        lines += scale_lines(pd.read_csv(folder / "scale.csv"))
    return "\n".join(lines) + "\n"


def _calls_lines(calls: pd.DataFrame) -> list[str]:
    at300 = calls[calls["K"] == 300]
    lines = ["## Speed (benchmark)", "", render("bench.intro"), "",
             render("bench.note", n=int(at300["n"].max()) if len(at300) else 0), "",
             "| method | median (ms) | quartiles (ms) | K=10000 / K=1000 |",
             "|---|---:|---:|---:|"]
    for r in at300.itertuples(index=False):
        big = calls[(calls["algorithm"] == r.algorithm) & (calls["K"] == 10000)]["median_s"]
        small = calls[(calls["algorithm"] == r.algorithm) & (calls["K"] == 1000)]["median_s"]
        ratio = float(big.iloc[0] / small.iloc[0]) if len(big) and len(small) else np.nan
        lines.append(f"| {method_label(r.algorithm)} | {format_number(r.median_s * 1e3)} | "
                     f"{format_number(r.q25_s * 1e3)}-{format_number(r.q75_s * 1e3)} | "
                     f"{format_number(ratio, 2)} |")
    return lines


def _first_call_lines(first: pd.DataFrame) -> list[str]:
    lines = ["", "First call in a fresh process (not in the medians above): with an empty "
             "numba cache the method's loops are compiled; with the on-disk cache they are "
             "loaded, which every sweep worker pays once. Both include importing numba, "
             "which the first compiled loop called in a process does.", "",
             "| method | compile (ms) | cached first call (ms) | next call (ms) |",
             "|---|---:|---:|---:|"]
    for r in first.itertuples(index=False):
        lines.append(f"| {method_label(r.algorithm)} | {format_number(r.compile_s * 1e3)} | "
                     f"{format_number(r.cached_first_s * 1e3)} | "
                     f"{format_number(r.second_s * 1e3)} |")
    return lines


def _peer_lines(peers: pd.DataFrame) -> list[str]:
    lines = ["", "Peers on the same nominal datasets (speed-up = peer time / magbench "
             "time; J = eq. 74 after converting conventions):", "",
             "| peer | K | magbench | speed-up | peer mean J | magbench mean J | note |",
             "|---|---:|---|---:|---:|---:|---|"]
    for r in peers.itertuples(index=False):
        K = getattr(r, "K", 300)
        lines.append(f"| {r.peer} | {'-' if pd.isna(K) else int(K)} | {r.magbench} | "
                     f"{format_number(getattr(r, 'speedup', np.nan), 3)} | "
                     f"{format_number(getattr(r, 'peer_mean_J', np.nan))} | "
                     f"{format_number(getattr(r, 'magbench_mean_J', np.nan))} | "
                     f"{'' if pd.isna(r.note) else r.note} |")
    return lines


def _parallel_lines(par: pd.DataFrame) -> list[str]:
    two = par[par["n_jobs"] == 2].iloc[0]
    return ["", f"Parallel: one baseline sweep of {int(two.trials)} trials x "
            f"{int(two.methods)} methods took {format_number(par['wall_s'].iloc[0])} s "
            f"with 1 worker and {format_number(two.wall_s)} s with 2 "
            f"(speed-up {format_number(two.speedup, 3)}x on {os.cpu_count()} cores)."]


def reproduce_case_lines(cases: pd.DataFrame) -> list[str]:
    """The table of ``reproduce_cases.csv`` (markdown lines): the first run's compilation,
    a whole ``make reproduce`` and one method added to a finished one, each with its wall and
    CPU time and, for a method added, the time in its own calls and beyond them."""
    if cases.empty:
        return []
    first = cases.iloc[0]
    lines = ["", f"`make reproduce` on this machine ({first.cpu_model}, {int(first.cpu_count)} "
             f"CPUs, load {format_number(first.load_1min, 2)} at the start; "
             "`reproduce_cases.csv`):", "",
             "| case | wall (s) | CPU (s) | in the method's calls (s) | beyond them (s) |",
             "|---|---:|---:|---:|---:|"]
    for r in cases.itertuples(index=False):
        lines.append(f"| {r.case} | {format_number(r.wall_s, 3)} | {format_number(r.cpu_s, 3)} "
                     f"| {format_number(r.method_s, 2)} | {format_number(r.beyond_method_s, 3)} |")
    return lines


def calibrate_lines(cal: pd.DataFrame) -> list[str]:
    """The file-to-correction tables of ``calibrate.csv`` (markdown lines), one per recording,
    with the rounds in which ``magbench calibrate`` took less time than each peer (the tools
    take turns, so a round is a side-by-side comparison; :func:`magbench.studies.speed.\
rounds_won`) and the machine and load they ran on, where recorded."""
    from magbench.studies.speed import MAGBENCH_TOOL, rounds_won

    if "tool" not in cal:                      # written before the peers were timed
        cal = cal.assign(tool=MAGBENCH_TOOL)
    if "file" not in cal:                      # written before the real recording was timed
        cal = cal.assign(file="synthetic")
    won: dict = {}
    for r in rounds_won(cal).itertuples(index=False):
        won.setdefault((r.file, r.K, r.peer), []).append(
            f"{r.won} of {r.rounds}" + ("" if r.magbench == MAGBENCH_TOOL else
                                        " (picture=false)"))
    lines = ["", "From file to correction: each tool in a fresh interpreter, one warm-up run "
             "each, then the tools take turns; median of the runs (`calibrate.csv`). "
             "`magbench calibrate` runs its default settings: outlier screen, candidates "
             "fitted on all samples and on interleaved time blocks, the choice, the intervals "
             "with their bootstrap check, JSON, C header, ranking and the picture "
             "(`picture=false`: all but the picture). "
             "A peer's process is the least a user of it runs: read the file, one fit, save "
             "the matrix and offset."]
    for (name, K), table in cal.groupby(["file", "K"], sort=False):
        lines += ["", f"{name}, {K} samples:", "",
                  "| tool | runs | whole process (s) | inside the command (s) | "
                  "rounds magbench was faster |",
                  "|---|---:|---:|---:|---:|"]
        for tool, runs in table.groupby("tool", sort=False):
            inside = runs["command_s"].median()
            faster = "; ".join(won.get((name, K, tool), ["-"])) if "run" in runs else "-"
            lines.append(f"| {tool} | {len(runs)} | "
                         f"{format_number(runs['process_s'].median(), 3)} "
                         f"| {'-' if pd.isna(inside) else format_number(inside, 3)} "
                         f"| {faster} |")
        if "cpu_model" in table and "load_1min" in table:
            lines += ["", f"Machine: {table['cpu_model'].iloc[0]}, "
                      f"{int(table['cpu_count'].iloc[0])} CPUs; 1-minute load average "
                      f"{format_number(table['load_1min'].min(), 2)} to "
                      f"{format_number(table['load_1min'].max(), 2)} as the rounds started."]
    return lines
