"""Provenance in every run note: a commit not in this history is flagged, and the timing
pass's machine and date are said."""

import json
import shutil
import subprocess

import pandas as pd
import pytest

from magbench.report.intervals import run_note

pytestmark = pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")


def _repo(tmp_path):
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "f").write_text("x")
    subprocess.run([*git, "add", "f"], check=True)
    subprocess.run([*git, "commit", "-qm", "c"], check=True)
    return subprocess.run([*git, "rev-parse", "HEAD"], check=True, capture_output=True,
                          text=True).stdout.strip()


def _run(folder, commit, cpu="Intel Xeon"):
    folder.mkdir(exist_ok=True)
    (folder / "run.json").write_text(json.dumps({
        "git_commit": commit, "cpu_model": cpu, "fingerprint": "abc", "finished": "2026-01-02",
        "settings": {"trials": 3}}))


def test_a_commit_outside_the_history_is_flagged(tmp_path):
    head = _repo(tmp_path)
    _run(tmp_path / "s", head)
    assert f"commit `{head[:10]}`, finished" in run_note(tmp_path / "s")
    _run(tmp_path / "t", "36e2a92de33df902a5fa8e86346d6df2b8293c2a")
    assert "commit `36e2a92de3` (not an ancestor of this checkout's HEAD" in run_note(
        tmp_path / "t")


def test_the_timing_pass_says_its_machine_and_date(tmp_path):
    _run(tmp_path / "s", "", cpu="Intel Xeon")
    pd.DataFrame({"algorithm": ["a", "b"], "cpu_model": "AMD EPYC",
                  "measured": ["2026-11-24T13:42:16+00:00", "2026-11-24T14:00:00+00:00"]}
                 ).to_csv(tmp_path / "s" / "timing.csv", index=False)
    note = run_note(tmp_path / "s")
    assert ("its timing pass (the speeds) measured on AMD EPYC on 2026-11-24, another "
            "machine than the sweep's.*") in note
