import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from magbench.cli import main
from magbench.cli.commands import sweep_names


def run(*args):
    return main(list(args))


def test_baseline_runs_end_to_end(tmp_path, capsys):
    assert run("trials=3", f"results_dir={tmp_path}", "progress=false", "n_jobs=1",
               "nominal.K=40", "algorithms=[magical,dorveaux]") == 0
    trials = pd.read_csv(tmp_path / "baseline" / "trials.csv")
    assert len(trials) == 6 and set(trials["algorithm"]) == {"magical", "dorveaux"}
    summary = pd.read_csv(tmp_path / "baseline" / "summary.csv")
    assert list(summary["algorithm"]) == ["magical", "dorveaux"]
    table = (tmp_path / "baseline" / "table2.md").read_text()
    assert "| MAG.I.C.AL |" in table and "2.28e+05" in table
    assert "6 rows" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("trials=0", "trials must be an integer >= 1, got 0"),
        ("trials=abc", "trials must be an integer"),
        ("trials=1000000000000", "trials must be an integer <= 1000000, got 1000000000000"),
        ("overwrite=maybe", "overwrite must be true or false, got 'maybe'"),
        ("sweep=nope", "Could not find 'sweep/nope'"),
        ("nosuchkey=1", "unknown key 'nosuchkey'"),
        ("algorithms=[magical,xx]", "unknown algorithm(s) xx"),
        ("delta=1.5", "delta must be in (0, 1)"),
        ("nominal.sigma=-1", "nominal.sigma must be in [0,"),
        ("nominal.K=3", "nominal.K must be an integer in ["),
        ("n_jobs=0", "n_jobs must be a non-zero integer"),
        ("options.magical.bogus=1", "unknown option(s) bogus for magical"),
    ],
)
def test_bad_values_stop_with_one_line_and_status_2(override, message, tmp_path, capsys):
    marker = tmp_path / "baseline" / "trials.csv"
    marker.parent.mkdir()
    marker.write_text("keep me")
    assert run(override, f"results_dir={tmp_path}") == 2
    err = capsys.readouterr().err
    assert err.startswith("magbench: error: ") and message in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert marker.read_text() == "keep me"


def test_method_options_reach_the_method(tmp_path):
    assert run("trials=2", f"results_dir={tmp_path}", "progress=false", "n_jobs=1",
               "algorithms=[magical]", "options.magical.max_iter=2") == 0
    trials = pd.read_csv(tmp_path / "baseline" / "trials.csv", keep_default_na=False)
    assert (trials["n_iter"] == 2).all() and (trials["ok"] == False).all()  # noqa: E712


SWEEPS = sorted(p.stem for p in (Path(__file__).resolve().parents[2] / "conf" / "sweep")
                .glob("*.yaml"))


@pytest.mark.parametrize("sweep", SWEEPS)
@pytest.mark.usefixtures("blank_figures")
def test_every_sweep_config_composes_and_runs(sweep, tmp_path):
    from magbench.cli.config import compose_config

    cfg = compose_config([f"sweep={sweep}"])
    if cfg.sweep.get("kind"):
        pytest.skip(f"sweep {sweep} is of kind {cfg.sweep.kind}, tested with its own module")
    vary = str(cfg.sweep.get("vary"))
    # an option axis (options.<method>.<option>) needs its method, which also runs at its default
    method = vary.split(".")[1] if vary.startswith("options.") else "magical"
    assert run(f"sweep={sweep}", "trials=2", f"results_dir={tmp_path}", "progress=false",
               "n_jobs=1", f"algorithms=[{method}]", "nominal.K=30") == 0
    summary = pd.read_csv(tmp_path / sweep / "summary.csv")
    values = cfg.sweep.get("values") or cfg.sweep.get("points") or [None]
    extra = 1 if vary.startswith("options.") else 0
    assert len(summary) == len(values) + extra and (summary["n"] == 2).all()


def test_a_sweep_point_with_an_unknown_parameter_is_rejected(tmp_path, capsys):
    assert run("sweep=coverage", "+sweep.points=[{tilt: 3}]", f"results_dir={tmp_path}") == 2
    assert "sweep point sets 'tilt'" in capsys.readouterr().err


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_reproduce_runs_the_reproduce_command():
    # make never applies an implicit rule to a .PHONY target: check the real command list.
    repo = Path(__file__).resolve().parents[2]
    dry = subprocess.run(["make", "-n", "reproduce", "MAGBENCH_DATA=/data"], cwd=repo,
                         capture_output=True, text=True, check=True).stdout
    assert dry.rstrip().endswith("-m magbench reproduce")


def test_reproduce_runs_every_sweep_baseline_first():
    sweeps = sweep_names()
    assert sorted(sweeps) == SWEEPS and sweeps[0] == "baseline"


def test_reproduce_checks_every_sweep_before_running_any(tmp_path, capsys):
    # trials does not apply to the real sweep: refused before the baseline has run.
    assert run("reproduce", "trials=2", f"data_dir={tmp_path}", f"results_dir={tmp_path}") == 2
    assert "trials does not apply to sweep=real" in capsys.readouterr().err
    assert not (tmp_path / "baseline").exists()


@pytest.mark.parametrize(("vary", "message"), [
    ("options.crassidis.nope", "crassidis has no option 'nope'; it accepts: theta0, P0"),
    ("options.magical.max_iter", "names 'magical', which is not among the selected"),
    ("options.crassidis", "an option axis is written options.<method>.<option>"),
])
def test_a_bad_option_axis_stops_with_one_line_and_status_2(vary, message, tmp_path, capsys):
    assert run("sweep=p0", f"sweep.vary={vary}", f"results_dir={tmp_path}") == 2
    err = capsys.readouterr().err
    assert err.startswith("magbench: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "p0").exists()


# A process entry point: main() reads sys.argv; the interpreter's own exit follows.
_ENTRY = """
import atexit, sys, threading, time
atexit.register(lambda: print("atexit ran", flush=True))
if sys.argv[1] == "thread":
    threading.Thread(target=lambda: (time.sleep(0.3), print("thread finished"))).start()
sys.argv = ["magbench", "--version"]
from magbench.cli.main import main
raise SystemExit(main())
"""


@pytest.mark.parametrize("case", ["alone", "thread"])
def test_a_process_ends_with_its_output_and_exit_functions(case):
    import sys

    done = subprocess.run([sys.executable, "-c", _ENTRY, case], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0 and done.stderr == ""
    lines = done.stdout.splitlines()
    assert lines[0].startswith("magbench ") and "atexit ran" in lines
    # another thread alive: the normal exit waits for it before the exit functions
    assert ("thread finished" in lines) == (case == "thread")
