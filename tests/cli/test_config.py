"""Every path and value problem, in every command, is one line on stderr and exit status 2
(issue 17): outputs that are files or cannot be written, inputs that are folders, compressed
or out of range, and the values of every sweep kind."""

from __future__ import annotations

import gzip
import json
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.core.geometry import fibonacci_sphere

#: A folder even root cannot write to (the kernel's, not the permission bits').
UNWRITABLE = Path("/sys/magbench-test-cannot-create")
needs_sys = pytest.mark.skipif(not sys.platform.startswith("linux") or
                               not Path("/sys/kernel").is_dir(),
                               reason="needs Linux /sys as a folder nobody can write")


def samples(scale: float = 40.0) -> np.ndarray:
    return scale * (fibonacci_sphere(200) * [1.1, 0.9, 1.0] + [0.2, -0.1, 0.05])


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("inputs")
    frame = pd.DataFrame(samples(), columns=["mx", "my", "mz"])
    frame.to_csv(root / "rec.csv", index=False)
    (root / "a_file").write_text("not a folder\n")
    with gzip.open(root / "rec.csv.gz", "wt") as handle:
        frame.to_csv(handle, index=False)
    with zipfile.ZipFile(root / "rec.zip", "w") as archive:
        archive.writestr("rec.csv", frame.to_csv(index=False))
    pd.DataFrame(samples(1e298), columns=["mx", "my", "mz"]).to_csv(root / "huge.csv",
                                                                    index=False)
    pd.DataFrame(samples(1e-300), columns=["mx", "my", "mz"]).to_csv(root / "tiny.csv",
                                                                     index=False)
    (root / "binary.csv").write_bytes(bytes(range(256)) * 4)
    assert main(["calibrate", f"file={root / 'rec.csv'}", "method=sphere",
                 f"out={root / 'cal'}"]) == 0
    return {"root": root, "rec": root / "rec.csv", "file": root / "a_file",
            "gz": root / "rec.csv.gz", "zip": root / "rec.zip", "huge": root / "huge.csv",
            "tiny": root / "tiny.csv", "binary": root / "binary.csv",
            "cal": root / "cal" / "calibration.json"}


SWEEP = ["progress=false", "trials=1", "algorithms=[sphere]"]

#: (arguments with {placeholders}, words the one line must hold)
CASES = [
    # outputs
    (["results_dir={file}", *SWEEP], "is a file; expected a folder"),
    (["results_dir={file}/below", *SWEEP], "is a file; expected a folder"),
    (["sweep=gyro", "results_dir={file}", *SWEEP], "is a file; expected a folder"),
    (["bench", "results_dir={file}"], "is a file; expected a folder"),
    (["report", "results_dir={file}"], "is not a folder of results"),
    (["report", "results_dir={root}/never-written"], "is not a folder of results"),
    (["calibrate", "file={rec}", "method=sphere", "out={file}"], "is a file; expected a folder"),
    (["apply", "calibration={cal}", "file={rec}", "out={root}"], "is a folder; expected"),
    (["apply", "calibration={cal}", "file={rec}", "out={file}/x.csv"],
     "the folder of out="),
    # inputs
    (["calibrate", "file={root}"], "is a folder; expected a CSV"),
    (["calibrate", "file={zip}"], "compressed input (zip): unpack it first"),
    (["calibrate", "file={binary}"], "is not a text file"),
    (["calibrate", "file={huge}"], "outside the range magbench can calibrate"),
    (["calibrate", "file={tiny}"], "outside the range magbench can calibrate"),
    (["apply", "calibration={rec}", "file={rec}"], "is not valid JSON"),
    # values, every sweep kind
    (["n_jobs=abc", *SWEEP], "n_jobs must be a non-zero integer"),
    (["sweep=gyro", "n_jobs=abc", *SWEEP], "n_jobs must be a non-zero integer"),
    (["sweep=gyro", "n_jobs=0", *SWEEP], "n_jobs must be a non-zero integer"),
    (["sweep=gyro", "seed=-1", *SWEEP], "seed must be an integer >= 0"),
    (["sweep=gyro", "nominal.sigma=-1", *SWEEP], "nominal.sigma must be in [0,"),
    (["sweep=gyro", "sweep.rate_hz=0", *SWEEP], "sweep.rate_hz must be in (0,"),
    (["sweep=gyro", "+sweep.trials=0", "progress=false"], "unknown key(s) sweep.trials"),
    (["sweep=gyro", "trials=0", "progress=false"], "trials must be an integer >= 1"),
    (["sweep=gyro", "trials=2.7", "progress=false"], "trials must be an integer >= 1, got 2.7"),
    (["sweep=gyro", "delta=7", *SWEEP], "delta must be in (0, 1)"),
    (["sweep=wushi", "seed=-1", *SWEEP], "seed must be an integer >= 0"),
    (["sweep=wushi", "+options.magical.bogus=1", "progress=false", "trials=1"],
     "unknown option(s) bogus for magical"),
    (["sweep=wushi", "sweep.N=9", *SWEEP], "sweep.N must be an integer >= 10"),
    # misspelt keys: one line with the key meant
    (["trails=5"], "unknown key 'trails'; did you mean 'trials'?"),
    (["+trails=5"], "unknown key 'trails'; did you mean 'trials'?"),
    (["nominal.Kk=5"], "did you mean 'nominal.K'?"),
    (["sweep=gyro", "sweep.rate_hx=5"], "(did you mean sweep.rate_hz?)"),
    # values that once ran out of memory, overflowed or failed every row
    (["nominal.K=100000000", *SWEEP], "nominal.K must be an integer in"),
    (["nominal.sigma=1e308", *SWEEP], "nominal.sigma must be in [0,"),
    (["nominal.beta=1e308", *SWEEP], "nominal.beta must be in [0,"),
    (["nominal.gamma=1e308", *SWEEP], "nominal.gamma must be in [0,"),
    (["nominal.alpha=[1e308,1e308]", *SWEEP], "nominal.alpha[0] must be in"),
    (["sweep=gyro", "sweep.rate_hz=1e9", *SWEEP], "sweep.rate_hz must be in"),
    (["sweep=wushi", "sweep.time_N=[1000000000]", *SWEEP], "sweep.time_N[0] must be an integer"),
    (["options.magical.max_iter=abc", "progress=false"], "options.magical.max_iter must be"),
    (["options.magical.max_iter=-5", "progress=false"], "options.magical.max_iter must be"),
    (["options.magical.max_iter=1.5", "progress=false"], "options.magical.max_iter must be"),
    (["options.magical.max_iter=[1,2]", "progress=false"], "options.magical.max_iter must be"),
    (["call_timeout_s=1e300", *SWEEP], "call_timeout_s must be in (0,"),
    (["algorithms=[fang,fang]", "progress=false"], "algorithms lists fang more than once"),
    (["results_dir=null", *SWEEP], "results_dir must be a folder path"),
    (["progress=abc", "trials=1"], "progress must be true or false"),
    (["algorithms=[sar_ls]", "progress=false"], "sar_ls need(s) gyro data"),
    (["plugins=[.evil]", *SWEEP], "plugin module '.evil' is relative"),
    (["plugins=[tests.plugins.raises_on_import]", *SWEEP], "failed to import: RuntimeError"),
    (["backend=dask", "scheduler_address=garbage", *SWEEP], "scheduler_address must be"),
    (["sweep=baseline", "+sweep.rate_hz=3", *SWEEP], "unknown key(s) sweep.rate_hz"),
    (["calibrate", "file={rec}", "seed=-1"], "seed must be an integer >= 0"),
    (["bench", "scale=abc"], "scale must be a list of trial counts"),
    (["bench", "scale=[10]"], "scale[0] must be an integer in [1000, 10000000], got 10"),
    (["bench", "scale=[10000,1e9]"], "scale[1] must be an integer in [1000, 10000000], got 1"),
    (["bench", "scale=[100000000]"], "scale[0] must be an integer in [1000, 10000000]"),
    (["bench", "scale=[]"], "scale must be a list of trial counts"),
    (["calibrate", "file={rec}", "max_samples=0"], "max_samples must be an integer >= 8"),
]


@pytest.mark.parametrize(("args", "words"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_every_problem_is_one_line_and_status_2(args, words, files, tmp_path, capsys):
    filled = [a.format(**files) for a in args]
    if not any(a.startswith(("results_dir=", "out=")) for a in filled):
        filled.append(f"results_dir={tmp_path / 'results'}")
    assert main(filled) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("magbench: error: ") and words in err[0], err[0]


@needs_sys
@pytest.mark.parametrize("args", [["results_dir={bad}", *SWEEP], ["bench", "results_dir={bad}"],
                                  ["calibrate", "file={rec}", "method=sphere", "out={bad}"]])
def test_an_unwritable_output_is_one_line_and_status_2(args, files, capsys):
    assert main([a.format(bad=UNWRITABLE, **files) for a in args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be written" in err[0], err


def test_gzip_input_is_read_as_the_plain_file(files, tmp_path):
    assert main(["calibrate", f"file={files['gz']}", "method=sphere",
                 f"out={tmp_path / 'gz'}"]) == 0
    a = json.loads((tmp_path / "gz" / "calibration.json").read_text())
    b = json.loads(files["cal"].read_text())
    assert a["T"] == b["T"] and a["h"] == b["h"]


@pytest.mark.parametrize("methods_key", ["plugins", "methods"])
def test_a_plugin_with_a_syntax_error_is_one_line(methods_key, tmp_path, monkeypatch, capsys):
    (tmp_path / "broken_plugin.py").write_text("def fit(:\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    args = (["plugins=[broken_plugin]", *SWEEP] if methods_key == "plugins"
            else ["methods", "plugins=[broken_plugin]"])
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "failed to import: SyntaxError" in err[0], err


def test_calibrates_site_keys_are_parsed_or_refused_in_one_line():
    import datetime as dt

    from omegaconf import OmegaConf

    from magbench.cli.config import UsageError, check_site
    from magbench.core.geomagnetic import Site

    def cfg(**keys):
        return OmegaConf.create({"location": None, "date": None, **keys})

    assert check_site(cfg()) == (None, None)
    site, date = check_site(cfg(location="52.51,13.33,40", date="2021-07-08"))
    assert site == Site(52.51, 13.33, 40.0) and date == dt.date(2021, 7, 8)
    assert check_site(cfg(location=[52.5, 13.3]))[1] == dt.date.today()
    for bad, message in [({"location": "52.5"}, "lat,lon"),
                         ({"location": "52.5,13.3", "date": "July"}, "ISO date"),
                         ({"date": "2021-07-08"}, "give both or neither")]:
        with pytest.raises(UsageError, match=message):
            check_site(cfg(**bad))


def test_all_means_the_methods_a_sweeps_data_can_feed():
    """'all': magnetometer-only methods; with gyro data the gyro-aided ones too; the heading
    study, whose data have an accelerometer, also the three alignment methods."""
    from omegaconf import OmegaConf

    from magbench.cli.config import selected_algorithms
    from magbench.methods.registry import get_method, methods

    cfg = OmegaConf.create({"algorithms": "all"})
    plain = selected_algorithms(cfg)
    gyro = selected_algorithms(cfg, include_gyro=True)
    heading = selected_algorithms(cfg, include_gyro=True, include_accel=True)
    assert plain == [m for m in methods() if get_method(m).magnetometer_only]
    assert set(gyro) - set(plain) == {m for m in methods() if get_method(m).needs_gyro
                                      and not get_method(m).needs_accel}
    assert set(heading) - set(gyro) == {"dip_align", "magical_aligned", "mag_imu_map"}
    assert heading == methods()
