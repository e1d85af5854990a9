"""Every sweep kind runs on the one engine, so each behaves alike (issue 13's "must show").

For the review, gyro, Wu-Shi and real-recording studies, at a tiny size, through the command
line: a method that raises an unusual exception, one that returns NaN and one that hangs past
``call_timeout_s`` each become rows with a reason, with 1 and 2 workers; the rows are the same
with 1 worker, 2 workers and the Dask backend; a SIGKILL and a rerun give the rows of one
uninterrupted run; ``trials`` means the same for every kind. The two-worker, Dask and
kill-and-resume repeats of kinds the fast ones already cover are marked slow
(``make test-all``): resuming is the engine's, whatever the kind.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from magbench.cli import main
from magbench.core.geometry import fibonacci_sphere
from tests.engine.conftest import FAULTY

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.usefixtures("blank_figures")


def recordings(root: Path) -> Path:
    """Three small synthetic recordings in the shared layout."""
    for i, K in enumerate((120, 150, 90)):
        folder = root / f"rec{i}"
        folder.mkdir(parents=True)
        y = 40.0 * (fibonacci_sphere(K) * [1.1, 0.9, 1.0] + [0.2, -0.1, 0.05])
        pd.DataFrame(y, columns=["mx", "my", "mz"]).to_csv(folder / "data.csv", index=False)
    return root


def kind_args(kind: str, tmp_path: Path) -> tuple[list[str], str, str]:
    """Overrides of a tiny run of ``kind``, its folder and its main table."""
    if kind == "review":
        return ["sweep=baseline", "trials=3", "nominal.K=40"], "baseline", "trials.csv"
    if kind == "gyro":
        return (["sweep=gyro", "trials=3", "sweep.coverage=[wide]", "sweep.gyro_noise=[0.01]",
                 "sweep.duration_s=6"], "gyro", "trials.csv")
    if kind == "heading":
        return (["sweep=heading", "trials=3", "sweep.parts=[mc]", "sweep.duration_s=6"],
                "heading", "heading_trials.csv")
    if kind == "compensation":
        return (["sweep=compensation", "trials=3", "sweep.strengths=[0.1]",
                 "sweep.duration_s=6"], "compensation", "trials.csv")
    if kind == "wushi":
        return (["sweep=wushi", "trials=3", "sweep.N=40", "sweep.time_N=[40]",
                 "sweep.time_repeats=1", "sweep.time_calls=1", "sweep.control_runs=0",
                 "sweep.alphas_pct=[0]"], "wushi", "runs.csv")
    root = tmp_path / "data"
    if not root.exists():
        recordings(root)
    if kind == "generalisation":
        return (["sweep=generalisation", f"data_dir={root}", "sweep.protocols=[blocks]",
                 "sweep.peers=false", "sweep.bootstrap=0"], "generalisation",
                "generalisation_trials.csv")
    return (["sweep=real", f"data_dir={root}", "sweep.preprocess=[centre]",
             "sweep.max_samples=100"], "real", "real_trials.csv")


KINDS = ["review", "gyro", "wushi", "real", "generalisation", "heading", "compensation"]


def kinds_beyond(*fast: str) -> list:
    """Every kind, those not in ``fast`` marked slow: the repeats of a property that the fast
    kinds already show on the same engine run in ``make test-all``, keeping CI's suite short."""
    return [k if k in fast else pytest.param(k, marks=pytest.mark.slow) for k in KINDS]


def table(folder: Path, name: str) -> pd.DataFrame:
    return pd.read_csv(folder / name, keep_default_na=False)


@pytest.mark.parametrize("kind", KINDS)
def test_failures_of_every_kind_are_rows_in_every_study(kind, faulty, tmp_path):
    check_failures_are_rows(kind, 1, tmp_path)


@pytest.mark.parametrize("kind", kinds_beyond("review"))
def test_failures_are_rows_with_two_workers(kind, faulty, tmp_path):
    check_failures_are_rows(kind, 2, tmp_path)


def check_failures_are_rows(kind: str, n_jobs: int, tmp_path: Path) -> None:
    args, folder, name = kind_args(kind, tmp_path)
    assert main([*args, f"plugins=[{FAULTY}]", "call_timeout_s=0.3", f"n_jobs={n_jobs}",
                 "algorithms=[faulty_keyerror,faulty_nan,faulty_hangs,sphere]",
                 f"results_dir={tmp_path / 'out'}", "progress=false", "chunk_size=1"]) == 0
    rows = table(tmp_path / "out" / folder, name)
    error = rows.groupby("algorithm")["error"].first()
    assert error["faulty_keyerror"] == "KeyError: 'deliberate missing key'"
    assert error["faulty_nan"].startswith("CalibrationFailed: faulty_nan: estimate is not")
    assert error["faulty_hangs"] == "CallTimeout: call exceeded call_timeout_s = 0.3 s"
    assert (rows[rows["algorithm"] == "sphere"]["error"] == "").all()
    assert (tmp_path / "out" / folder / "run.json").exists()


@pytest.mark.parametrize("kind", kinds_beyond("review", "heading"))
def test_same_rows_with_one_worker_two_workers_and_dask(kind, tmp_path):
    pytest.importorskip("distributed")
    args, folder, name = kind_args(kind, tmp_path)
    runs = {}
    for label, extra in [("one", ["n_jobs=1"]), ("two", ["n_jobs=2"]),
                         ("dask", ["n_jobs=2", "backend=dask"])]:
        out = tmp_path / label
        assert main([*args, *extra, "algorithms=[sphere,ali]", f"results_dir={out}",
                     "progress=false", "chunk_size=1"]) == 0
        runs[label] = table(out / folder, name)
    pd.testing.assert_frame_equal(runs["one"], runs["two"])
    pd.testing.assert_frame_equal(runs["one"], runs["dask"])


def slow_args(kind: str, tmp_path: Path, results: Path) -> list[str]:
    """A run of ``kind`` slow enough to be killed mid-way (a 0.15 s method per unit)."""
    args, _, _ = kind_args(kind, tmp_path)
    return [*args, f"plugins=[{FAULTY}]", "algorithms=[faulty_slow,sphere]",
            "options.faulty_slow.delay=0.15", "chunk_size=1", "n_jobs=1", "progress=false",
            f"results_dir={results}"]


@pytest.mark.parametrize("kind", kinds_beyond("review"))
def test_a_killed_run_of_every_kind_resumes_to_the_same_rows(kind, faulty, tmp_path):
    _, folder, name = kind_args(kind, tmp_path)
    # The uninterrupted run and the resumed one run in this process; only the killed one needs
    # its own process.
    assert main(slow_args(kind, tmp_path, tmp_path / "full")) == 0
    proc = subprocess.Popen([sys.executable, "-m", "magbench",
                             *slow_args(kind, tmp_path, tmp_path / "cut")], cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    parts = tmp_path / "cut" / folder / "parts"
    start = time.monotonic()
    while len(list(parts.glob("c*.json"))) < 1:
        assert proc.poll() is None, "the run ended before it could be killed"
        assert time.monotonic() - start < 120
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert not (tmp_path / "cut" / folder / name).exists()
    assert main(slow_args(kind, tmp_path, tmp_path / "cut")) == 0
    pd.testing.assert_frame_equal(table(tmp_path / "cut" / folder, name),
                                  table(tmp_path / "full" / folder, name))


@pytest.mark.parametrize("kind", ["review", "gyro", "wushi"])
def test_trials_means_the_same_for_every_kind(kind, tmp_path):
    args, folder, name = kind_args(kind, tmp_path)
    args = [a for a in args if not a.startswith("trials=")]
    assert main([*args, "trials=2", "algorithms=[sphere]", f"results_dir={tmp_path}",
                 "progress=false", "n_jobs=1"]) == 0
    rows = pd.read_csv(tmp_path / folder / name)
    # Every kind was cut to one point, so each method has exactly `trials` rows.
    assert set(rows.groupby("algorithm").size()) == {2}


def test_trials_is_refused_where_it_cannot_apply(tmp_path, capsys):
    args, _, _ = kind_args("real", tmp_path)
    assert main([*args, "trials=5", f"results_dir={tmp_path}"]) == 2
    assert "trials does not apply to sweep=real" in capsys.readouterr().err
