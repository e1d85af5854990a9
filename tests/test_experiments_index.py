"""experiments/README.md is true, command by command: each sweep's command writes the files the
index names (a tiny run of each, one trial and one cheap method)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from magbench.cli import main

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.usefixtures("blank_figures")

#: Overrides that shrink a sweep of each kind to seconds; the files it writes do not change.
TINY = {
    "gyro": ["sweep.coverage=[wide]", "sweep.gyro_noise=[0.01]", "sweep.duration_s=6"],
    "heading": ["sweep.parts=[mc]", "sweep.duration_s=6"],
    "wushi": ["sweep.N=40", "sweep.time_N=[40]", "sweep.time_repeats=1", "sweep.time_calls=1",
              "sweep.control_runs=0", "sweep.alphas_pct=[0]"],
}


#: Sweeps that read recordings from data_dir (run at a tiny size in test_every_study).
NEED_DATA = ("real", "generalisation")


def index_rows() -> list[tuple[str, list[str]]]:
    """(sweep, files it is said to write) for every ``sweep=NAME`` row of the index."""
    rows = []
    for line in (REPO / "experiments" / "README.md").read_text().splitlines():
        found = re.search(r"`python -m magbench sweep=(\w+)`[^|]*\|\s*(.+?)\s*\|\s*$", line)
        # real and generalisation need recordings: tests/engine/test_every_study.py
        if found and found.group(1) not in NEED_DATA:
            folder_and_files = re.findall(r"`([^`]+)`", found.group(2))
            first = Path(folder_and_files[0])
            files = [first.name] + [Path(f).name for f in folder_and_files[1:]]
            rows.append((found.group(1), files))
    return rows


def test_the_index_lists_every_sweep():
    listed = {name for name, _ in index_rows()} | set(NEED_DATA)
    assert listed == {p.stem for p in (REPO / "conf" / "sweep").glob("*.yaml")}


@pytest.mark.parametrize(("sweep", "files"), index_rows(), ids=[r[0] for r in index_rows()])
def test_each_sweep_writes_what_the_index_says(sweep, files, tmp_path):
    args = [f"sweep={sweep}", "trials=1", "algorithms=[sphere]", "n_jobs=1", "progress=false",
            f"results_dir={tmp_path}", *TINY.get(sweep, ["nominal.K=30"])]
    if sweep == "K":
        args[-1] = "sweep.values=[30,40]"
    if sweep == "p0":          # an option axis needs its method: the EKF instead of sphere
        args[2], args[-1] = "algorithms=[crassidis]", "sweep.values=[1e-3]"
    assert main(args) == 0
    for name in files:
        assert (tmp_path / sweep / name).is_file(), f"sweep={sweep} did not write {name}"
    assert (tmp_path / sweep / "run.json").is_file()
