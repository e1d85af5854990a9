"""Issue 6: failures contained, nothing lost on a kill, same numbers on every backend."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from magbench.engine.sweep import run_study
from magbench.sources.synthetic import Point
from magbench.studies.review import ReviewStudy, read_trials
from tests.engine.conftest import FAULTY

REPO = Path(__file__).resolve().parents[2]


def run_sweep(study: ReviewStudy, out_dir, **kw) -> tuple[pd.DataFrame, pd.DataFrame]:
    run_study(study, out_dir, progress=False, **kw)
    return read_trials(out_dir / "trials.csv"), study.summarize(out_dir)


def spec(algorithms, **kw) -> ReviewStudy:
    base = dict(name="rel", points=[Point(K=40)], trials=4, seed=3, algorithms=algorithms,
                call_timeout_s=0.5, plugins=(FAULTY,))
    base.update(kw)
    return ReviewStudy(**base)


# tests/engine/test_every_study.py holds the same rows for every kind in CI; this repeat,
# with MAG.I.C.AL beside the faults, runs in make test-all.
@pytest.mark.slow
@pytest.mark.parametrize("n_jobs", [1, 2])
def test_every_kind_of_failure_is_a_row(faulty, tmp_path, n_jobs):
    algos = ["faulty_raises", "faulty_nan", "faulty_hangs", "magical"]
    # 2 s: a fresh worker's first magical call loads its compiled loops within the limit.
    trials, summary = run_sweep(spec(algos, trials=2, call_timeout_s=2.0), tmp_path,
                                n_jobs=n_jobs, chunk_size=1)
    assert len(trials) == 2 * len(algos)
    err = trials.groupby("algorithm")["error"].first()
    assert err["faulty_raises"] == "RuntimeError: deliberate failure"
    assert err["faulty_nan"].startswith("CalibrationFailed: faulty_nan: estimate is not finite")
    assert err["faulty_hangs"] == "CallTimeout: call exceeded call_timeout_s = 2 s"
    ok = trials.groupby("algorithm")["ok"].all()
    assert not ok["faulty_raises"] and not ok["faulty_nan"] and not ok["faulty_hangs"]
    assert ok["magical"]
    assert summary.set_index("algorithm").loc["magical", "RB_pct"] == 100


def sweep_command(results: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "magbench", f"plugins=[{FAULTY}]",
            "algorithms=[faulty_slow,magical]", "trials=30", "chunk_size=2", "n_jobs=1",
            "nominal.K=40", "progress=false", f"results_dir={results}", *extra]


def with_ctrl_c() -> None:
    """A child's Ctrl-C back to the default: a shell's background job (a CI runner's, say)
    starts its processes with SIGINT ignored, which Python then keeps."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_for_parts(folder: Path, count: int, proc: subprocess.Popen, limit: float = 60) -> None:
    start = time.monotonic()
    while len(list(folder.glob("c*.json"))) < count:
        assert proc.poll() is None, "the sweep ended before it could be interrupted"
        assert time.monotonic() - start < limit, "no progress"
        time.sleep(0.05)


def read_without_time(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, keep_default_na=False)


@pytest.mark.slow      # test_every_study's kill-and-resume of the review kind runs in CI
def test_a_killed_sweep_resumes_to_the_same_rows(tmp_path):
    full = subprocess.run(sweep_command(tmp_path / "full"), cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert full.returncode == 0, full.stderr
    proc = subprocess.Popen(sweep_command(tmp_path / "cut"), cwd=REPO, stderr=subprocess.PIPE,
                            text=True)
    wait_for_parts(tmp_path / "cut" / "baseline" / "parts", 3, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert not (tmp_path / "cut" / "baseline" / "trials.csv").exists()
    kept = len(list((tmp_path / "cut" / "baseline" / "parts").glob("c*.json")))
    assert 3 <= kept < 15
    again = subprocess.run(sweep_command(tmp_path / "cut"), cwd=REPO, capture_output=True,
                           text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    a = read_without_time(tmp_path / "full" / "baseline" / "trials.csv")
    b = read_without_time(tmp_path / "cut" / "baseline" / "trials.csv")
    pd.testing.assert_frame_equal(a, b)
    assert not b.duplicated(["trial", "algorithm"]).any() and len(b) == 60


@pytest.mark.parametrize(("signum", "code", "word"), [
    (signal.SIGINT, 130, "interrupted"),
    pytest.param(signal.SIGTERM, 143, "terminated", marks=pytest.mark.slow)])
def test_sigint_and_sigterm_stop_cleanly_with_one_line(tmp_path, signum, code, word):
    proc = subprocess.Popen(sweep_command(tmp_path), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=with_ctrl_c)
    wait_for_parts(tmp_path / "baseline" / "parts", 1, proc)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == code
    assert err.strip().splitlines() == [
        f"magbench: {word}; finished chunks are kept and a rerun completes the rest"]


def test_a_killed_sweep_leaves_no_worker_process_behind(tmp_path):
    psutil = pytest.importorskip("psutil")
    proc = subprocess.Popen(sweep_command(tmp_path, "n_jobs=2"), cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for_parts(tmp_path / "baseline" / "parts", 2, proc)
    children = psutil.Process(proc.pid).children(recursive=True)
    assert len(children) >= 2                       # the loky workers (and resource trackers)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    _, alive = psutil.wait_procs(children, timeout=10)          # the issue: within 10 s
    assert alive == [], f"orphaned after SIGKILL: {[p.cmdline()[-3:] for p in alive]}"


# tests/engine/test_every_study.py holds the Dask rows against one and two workers in CI.
@pytest.mark.slow
def test_dask_backend_gives_the_same_rows(tmp_path):
    pytest.importorskip("distributed")
    # A generous limit: each run's fresh process loads the compiled loops in its first call.
    s = spec(["magical", "dorveaux"], trials=6, plugins=(), call_timeout_s=30)
    local, _ = run_sweep(s, tmp_path / "local", n_jobs=1, chunk_size=2)
    dask, _ = run_sweep(s, tmp_path / "dask", n_jobs=2, chunk_size=2, backend="dask")
    pd.testing.assert_frame_equal(local.drop(columns="time_s"), dask.drop(columns="time_s"))


def test_cli_rejects_a_missing_plugin(tmp_path):
    from magbench.cli import main

    assert main(["plugins=[no.such.module]", f"results_dir={tmp_path}"]) == 2
    assert not any(tmp_path.iterdir())


def test_cli_rejects_a_bad_backend_and_timeout(tmp_path, capsys):
    from magbench.cli import main

    assert main(["backend=spark", f"results_dir={tmp_path}"]) == 2
    assert "backend must be 'loky' or 'dask'" in capsys.readouterr().err
    assert main(["call_timeout_s=-1", f"results_dir={tmp_path}"]) == 2
    assert "call_timeout_s must be in (0," in capsys.readouterr().err


@pytest.mark.skipif(os.name != "posix", reason="SIGALRM timers are POSIX only")
def test_time_limit_interrupts_python_code():
    from magbench.engine.trial import CallTimeout, time_limit

    with pytest.raises(CallTimeout), time_limit(0.2):
        while True:
            pass


def test_hydra_multirun_runs_one_job_per_sweep(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "magbench.cli.hydra_app", "-m", "sweep=baseline,K", "trials=2",
         "algorithms=[magical]", f"results_dir={tmp_path}", "progress=false", "n_jobs=1",
         f"hydra.sweep.dir={tmp_path / 'hydra'}"],
        cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert len(pd.read_csv(tmp_path / "baseline" / "trials.csv")) == 2
    assert sorted(pd.read_csv(tmp_path / "K" / "summary.csv")["K"]) == [50, 150, 300]


def test_time_limit_interrupts_python_code_in_a_thread():
    """Where signals cannot go (a Dask worker's threads) the limit still holds, and a block
    that ends in time leaves no exception behind."""
    import threading

    from magbench.engine.trial import CallTimeout, time_limit

    seen = []

    def work():
        try:
            with time_limit(0.2):
                while True:
                    time.sleep(0.01)
        except CallTimeout as exc:
            seen.append(str(exc))
        with time_limit(0.1):
            pass
        time.sleep(0.3)                     # past the second limit: nothing may fire
        seen.append("after")

    thread = threading.Thread(target=work)
    thread.start()
    thread.join(timeout=10)
    assert seen == ["call exceeded call_timeout_s = 0.2 s", "after"]


def test_dask_backend_stops_a_hanging_method(faulty, tmp_path):
    pytest.importorskip("distributed")
    # The sphere fit (closed form, not compiled) is the control that must stay ok.
    trials, _ = run_sweep(spec(["faulty_hangs", "sphere"], trials=2, call_timeout_s=0.3),
                          tmp_path, n_jobs=2, chunk_size=1, backend="dask")
    err = trials.groupby("algorithm")["error"].first()
    assert err["faulty_hangs"] == "CallTimeout: call exceeded call_timeout_s = 0.3 s"
    assert trials.groupby("algorithm")["ok"].all()["sphere"]


# CI holds the refusal by tests/cli/test_product.py's held-lock test; the race runs in
# make test-all.
@pytest.mark.slow
def test_a_second_run_on_the_same_folder_exits_2_and_nothing_mixes(tmp_path):
    # 30 trials of 0.2 s: the first run is still going when the second one starts.
    slow = "options.faulty_slow.delay=0.2"
    first = subprocess.Popen(sweep_command(tmp_path, "seed=11", slow), cwd=REPO,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wait_for_parts(tmp_path / "baseline" / "parts", 1, first)
    second = subprocess.run(sweep_command(tmp_path, "seed=12", slow), cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    assert second.returncode == 2
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 1 and "is in use by a running magbench (pid" in lines[0], lines
    assert f"pid {first.pid}" in lines[0]
    _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    rows = pd.read_csv(tmp_path / "baseline" / "trials.csv")
    # Only the first run's rows: its seed, every trial and method once.
    assert set(rows["seed"]) == {11} and len(rows) == 60
    assert not rows.duplicated(["trial", "algorithm"]).any()


def test_the_lock_of_a_killed_run_is_taken_over(tmp_path):
    """The lock is the operating system's: it dies with its holder, so a run after a SIGKILL
    proceeds at once (the lock file stays, naming the dead run, and is simply reused)."""
    proc = subprocess.Popen(sweep_command(tmp_path), cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    wait_for_parts(tmp_path / "baseline" / "parts", 1, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert f"pid {proc.pid}" in (tmp_path / "baseline" / ".lock").read_text()
    again = subprocess.run(sweep_command(tmp_path), cwd=REPO, capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 0, again.stderr
    assert len(pd.read_csv(tmp_path / "baseline" / "trials.csv")) == 60


@pytest.mark.parametrize(("sweep", "folder"), [
    (["trials=2"], "baseline"),
    (["sweep=gyro", "trials=2", "sweep.coverage=[wide]", "sweep.gyro_noise=[0.01]",
      "sweep.duration_s=6"], "gyro")])
def test_the_folder_lock_covers_every_step_of_a_run(tmp_path, monkeypatch, sweep, folder):
    """The kind's finishing steps (timing, summary, tables), figures and report text are
    written under the same lock as the trials: a second run starting at any of them is
    refused."""
    import dataclasses

    import magbench.cli.commands as commands
    from magbench.cli import main
    from magbench.engine.sweep import FolderBusy, folder_lock

    seen = []

    def second_run(name, step):
        def checked(*args, **kwargs):
            with pytest.raises(FolderBusy, match="in use by a running magbench"), \
                    folder_lock(tmp_path / folder):
                pass
            seen.append(name)
            return step(*args, **kwargs)
        return checked

    real_kind_of = commands.kind_of

    def kind_of(cfg):
        kind = real_kind_of(cfg)
        return dataclasses.replace(kind, **{name: second_run(name, getattr(kind, name))
                                            for name in ("finish", "figures", "section")
                                            if getattr(kind, name) is not None})

    monkeypatch.setattr(commands, "kind_of", kind_of)
    assert main([*sweep, "algorithms=[sphere]", "n_jobs=1", "progress=false",
                 f"results_dir={tmp_path}"]) == 0
    assert seen == ["finish", "figures"] + (["section"] if folder == "gyro" else [])
    with folder_lock(tmp_path / folder):            # released once the run is done
        pass


def test_a_damaged_finished_table_exits_2_and_no_summary_is_rebuilt(tmp_path, capsys):
    from magbench.cli import main

    args = ["trials=3", "algorithms=[sphere]", "n_jobs=1", "progress=false",
            f"results_dir={tmp_path}"]
    assert main(args) == 0
    folder = tmp_path / "baseline"
    summary = (folder / "summary.csv").read_bytes()
    lines = (folder / "trials.csv").read_text().splitlines(keepends=True)
    (folder / "trials.csv").write_text("".join(lines[:-1]))            # a row deleted
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "trials.csv (checksum differs from run.json)" in err[0], err
    assert (folder / "summary.csv").read_bytes() == summary
    assert main([*args, "overwrite=true"]) == 0
    assert len(pd.read_csv(folder / "trials.csv")) == 3


def test_ctrl_c_to_the_process_group_prints_one_line_and_no_worker_speaks(tmp_path):
    """A terminal's Ctrl-C reaches the run and its workers: the run prints its one line, and
    neither a worker's traceback nor joblib's warning about a stopped worker appears."""
    proc = subprocess.Popen(sweep_command(tmp_path, "n_jobs=2"), cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=with_ctrl_c)
    wait_for_parts(tmp_path / "baseline" / "parts", 1, proc)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert err.strip().splitlines() == [
        "magbench: interrupted; finished chunks are kept and a rerun completes the rest"]


def test_workers_die_with_the_run_even_inside_one_long_compiled_call(tmp_path):
    """One worker holds the interpreter in a compiled call, the other never got a chunk: a
    SIGKILL of the run ends both within seconds (the kernel's parent-death signal)."""
    psutil = pytest.importorskip("psutil")
    command = [sys.executable, "-m", "magbench", f"plugins=[{FAULTY}]", "algorithms=[faulty_gil]",
               "options.faulty_gil.seconds=120", "call_timeout_s=300", "trials=1",
               "chunk_size=1", "n_jobs=2", "nominal.K=40", "progress=false",
               f"results_dir={tmp_path}", "seed=3"]
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    start = time.monotonic()
    while not list((tmp_path / "baseline" / "parts").glob("*.started")):
        assert proc.poll() is None and time.monotonic() - start < 120
        time.sleep(0.1)
    time.sleep(1.0)                                   # inside the call by now
    children = psutil.Process(proc.pid).children(recursive=True)
    assert len(children) >= 2
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    _, alive = psutil.wait_procs(children, timeout=10)
    assert alive == [], f"orphaned after SIGKILL: {[p.cmdline()[-3:] for p in alive]}"


def test_the_resource_trackers_leak_warning_is_filtered_and_the_users_filters_kept(
        monkeypatch):
    """After a Ctrl-C, loky's resource tracker warns of the semaphores it then removes; the
    filter passed to the processes silences exactly that warning."""
    from magbench.engine.sweep import _TRACKER_FILTER, _quiet_resource_tracker

    monkeypatch.setenv("PYTHONWARNINGS", "error::DeprecationWarning")
    _quiet_resource_tracker()
    _quiet_resource_tracker()                       # idempotent
    assert os.environ["PYTHONWARNINGS"] == f"error::DeprecationWarning,{_TRACKER_FILTER}"
    code = ("import warnings; warnings.warn_explicit('leaked semlock', UserWarning, "
            "'resource_tracker.py', 1, module='joblib.externals.loky.backend.resource_tracker');"
            " warnings.warn_explicit('other', UserWarning, 'x.py', 1, module='x')")
    err = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ)).stderr
    assert "leaked semlock" not in err and "other" in err
