"""``python -m magbench extract``: a flight log's compass as CSV; one-line errors; calibrate's
answer on the shared sample logs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.cli.main import command_help
from magbench.sources.logs import read_log
from tests.sources.test_logs import SHARED_LOGS, T0, mag0, px4_log


def test_extract_writes_the_aligned_table_that_calibrate_reads_back(tmp_path, capsys):
    log = px4_log(tmp_path / "flight.ulg")
    out = tmp_path / "data.csv"
    assert main(["extract", f"file={log}", "instance=0", f"out={out}"]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"flight.ulg: compass instance 0 (device 11, gauss), {len(T0)} "
                           "samples at 20 Hz from t = 0.200 to 5.950 s; columns t, mx, my, mz, "
                           "gx, gy, gz, ax, ay, az, qw, qx, qy, qz, current, throttle, "
                           "temperature; no value (outside the stream or in a gap): gx 6,")
    frame = pd.read_csv(out)
    expected = read_log(log).table(0)
    pd.testing.assert_frame_equal(frame, expected, check_exact=False, rtol=1e-12)
    np.testing.assert_allclose(frame[["mx", "my", "mz"]], mag0(T0), rtol=1e-5)
    # The CSV reader keeps the same extra columns (rows without gyro dropped, as for the log).
    from magbench.sources.recordings import read_samples

    with pytest.warns(UserWarning, match="dropped 6 of 116 rows"):
        rec = read_samples(out, check=False)
    assert rec.has_gyro and list(rec.extra) == ["ax", "ay", "az", "qw", "qx", "qy", "qz",
                                                 "current", "throttle", "temperature"]


def test_extract_errors_are_one_line(tmp_path, capsys):
    log = px4_log(tmp_path / "flight.ulg")
    assert main(["extract", f"file={log}", f"out={tmp_path / 'x.csv'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("magbench: error: flight.ulg has 2 compasses; choose one with instance=N: "
                   "0 (device 11, 116 samples), 1 (device 22, 50 samples)")
    assert main(["extract", f"file={log}", "instance=-1"]) == 2
    assert "instance must be a compass number of the log (0, 1, ...), got '-1'" in \
        capsys.readouterr().err
    (tmp_path / "a.csv").write_text("mx,my,mz\n1,2,3\n")
    assert main(["extract", f"file={tmp_path / 'a.csv'}"]) == 2
    assert "extract reads flight logs (.ulg, .bin, .log); a.csv is not one" in \
        capsys.readouterr().err
    assert main(["extract"]) == 2
    assert "extract needs file=PATH" in capsys.readouterr().err


def test_extract_help_lists_its_keys():
    text = command_help("extract")
    for key in ("file", "instance", "out", "overwrite"):
        assert f"\n  {key} " in text


@pytest.mark.skipif(not SHARED_LOGS, reason="the shared sample logs are not here")
@pytest.mark.parametrize("path", SHARED_LOGS, ids=lambda p: p.name)
def test_calibrate_on_the_shared_logs_says_the_stream_is_too_short(path, tmp_path, capsys):
    assert main(["calibrate", f"file={path}", f"out={tmp_path / 'cal'}"]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "the magnetometer streams are too short to calibrate" in lines[0]
    assert ("6 and 6 samples" in lines[0]) or ("11 and 11 samples" in lines[0])
    assert not (tmp_path / "cal").exists()
    assert main(["calibrate", f"file={path}", "instance=0", f"out={tmp_path / 'cal'}"]) == 2
    assert "the magnetometer stream is too short" in capsys.readouterr().err


def test_calibrate_from_a_log_reports_the_mounting_rotation(tmp_path, capsys):
    import json

    from tests.pipeline.test_flight import simulated_ulog

    log = simulated_ulog(tmp_path / "flight.ulg", 6, seed=4, seconds=30.0)
    out = tmp_path / "cal"
    assert main(["calibrate", f"file={log}", f"out={out}", "bootstrap=0"]) == 0
    said = capsys.readouterr().out
    line = next(s for s in said.splitlines() if s.startswith("mounting rotation:"))
    assert line.startswith("mounting rotation: ROTATION_YAW_270 (id 6) from the attitude, "
                           "confidence ")
    found = json.loads((out / "calibration.json").read_text())["mounting_rotation"]
    assert found["id"] == 6 and found["confidence"] > 2 and found["basis"] == "attitude"


def test_calibrate_from_a_log_fits_the_current_term_and_keeps_it(tmp_path, capsys):
    import json

    from tests.pipeline.test_flight import simulated_ulog

    motor = np.array([0.004, -0.002, 0.003])               # gauss per A
    log = simulated_ulog(tmp_path / "flight.ulg", 0, seed=5, seconds=30.0, motor=motor)
    out = tmp_path / "cal"
    assert main(["calibrate", f"file={log}", f"out={out}", "bootstrap=0"]) == 0
    said = capsys.readouterr().out
    line = next(s for s in said.splitlines() if s.startswith("time-varying terms"))
    assert "u = current" in line and ": kept; C per unit of u" in line
    # The rotation is detected on the samples corrected with the kept term.
    rotation = next(s for s in said.splitlines() if s.startswith("mounting rotation"))
    assert rotation.startswith("mounting rotation: ROTATION_NONE (id 0)")
    terms = json.loads((out / "calibration.json").read_text())["time_varying"]
    assert terms["kept"] and terms["held_out_time_varying"] < 0.1 * terms["held_out_static"]
    np.testing.assert_allclose(np.array(terms["C"])[:, 0], motor, atol=2e-4)
    # The firmware files carry the term: PX4 in gauss per kA, subtracted before the offset.
    assert "firmware files hold the fit with the current term" in said
    px4 = {row.split("\t")[2]: float(row.split("\t")[3])
           for row in (out / "px4.params").read_text().splitlines() if not row.startswith("#")}
    assert px4["CAL_MAG_COMP_TYP"] == 2
    np.testing.assert_allclose([px4[f"CAL_MAG0_{a}COMP"] for a in "XYZ"], -1000 * motor,
                               atol=0.2)
    assert "\nCOMPASS_MOTCT 2\n" in (out / "ardupilot.param").read_text()
    assert main(["calibrate", f"file={log}", f"out={tmp_path / 'none'}", "bootstrap=0",
                 "compensate=none"]) == 0
    assert "time-varying" not in capsys.readouterr().out
    assert "time_varying" not in json.loads((tmp_path / "none" / "calibration.json").read_text())
    assert main(["calibrate", f"file={log}", "compensate=[temperature]"]) == 2
    assert capsys.readouterr().err.strip() == ("magbench: error: compensate: the recording has "
                                               "no temperature column (it has: current)")
    assert main(["calibrate", f"file={log}", "compensate=[wind]"]) == 2
    assert "compensate must be auto, none or a list of current, throttle, temperature" in \
        capsys.readouterr().err


def test_apply_reads_one_compass_of_a_log(tmp_path, capsys):
    import json

    from magbench.core.exports import to_json_dict
    from magbench.core.model import Calibration

    log = px4_log(tmp_path / "flight.ulg")
    cal = tmp_path / "calibration.json"
    # Compass 1 reads about 1000: a calibration of that field strength.
    cal.write_text(json.dumps(to_json_dict(Calibration(1000 * np.eye(3), np.zeros(3)))))
    out = tmp_path / "corrected.csv"
    assert main(["apply", f"calibration={cal}", f"file={log}", f"out={out}"]) == 2
    assert "has 2 compasses; choose one with instance=N" in capsys.readouterr().err
    assert main(["apply", f"calibration={cal}", f"file={log}", "instance=1",
                 f"out={out}"]) == 0
    frame = pd.read_csv(out)
    from tests.sources.test_logs import T1, mag1

    np.testing.assert_allclose(frame[["mx", "my", "mz"]], mag1(T1) / 1000, rtol=1e-5)


def disturbed_csv(path, K: int, regressors: dict, *, seed: int | None = 1,
                  diag=(1.05, 0.97, 1.0), with_t: bool = True):
    """A mGauss recording of a 450 mGauss field (scaled by ``diag``, offset) plus ``u C`` for
    each ``name -> (u, C per unit or None)`` of ``regressors``, the ``u`` columns beside it,
    and 1 mGauss of noise (none when ``seed`` is None)."""
    from magbench.core.geometry import fibonacci_sphere

    y = 450.0 * fibonacci_sphere(K) @ np.diag(diag) + [60.0, -40.0, 25.0]
    for u, per_unit in regressors.values():
        if per_unit is not None:
            y = y + np.outer(u, per_unit)
    if seed is not None:
        y = y + np.random.default_rng(seed).normal(0.0, 1.0, y.shape)
    columns = {"t": np.arange(K) / 20.0} if with_t else {}
    columns |= {"mx": y[:, 0], "my": y[:, 1], "mz": y[:, 2]}
    columns |= {name: u for name, (u, _) in regressors.items()}
    pd.DataFrame(columns).to_csv(path, index=False)
    return path


def current_of(K: int) -> np.ndarray:
    """A battery current of 2-18 A, in A, at 20 Hz."""
    return 10.0 + 8.0 * np.sin(0.3 * np.arange(K) / 20.0)


def test_a_kept_temperature_term_leaves_the_firmware_files_static(tmp_path, capsys):
    """Neither ArduPilot nor PX4 has a parameter for a temperature term: when it is kept, the
    firmware files hold the static calibration and one line says why."""
    K = 1200
    temperature = np.linspace(5.0, 45.0, K)                  # C, a warming board
    drift = np.array([2.0, -1.5, 1.0])                       # mGauss per C: 80 mGauss over 40 C
    data = disturbed_csv(tmp_path / "data.csv", K, {"temperature": (temperature, drift)},
                         seed=3, with_t=False)
    out = tmp_path / "cal"
    assert main(["calibrate", f"file={data}", f"out={out}", "units=mgauss", "bootstrap=0",
                 "compensate=[temperature]"]) == 0
    said = capsys.readouterr().out
    assert "u = temperature" in said and ": kept; C per unit of u" in said
    assert ("firmware files hold the static calibration: the kept temperature terms have no "
            "ArduPilot or PX4 parameter") in said
    assert "COMPASS_MOT" not in (out / "ardupilot.param").read_text()
    assert "COMP" not in (out / "px4.params").read_text().replace("COMPASS", "")


def test_a_fail_caused_by_the_current_says_what_the_terms_would_give(tmp_path, capsys):
    """A motor disturbance ten times the field fails the static verdict; the FAIL still fits
    the current term and says how small the held-out error is with it."""
    import json

    K = 1500
    data = disturbed_csv(tmp_path / "data.csv", K,                 # mGauss per A
                         {"current": (current_of(K), [300.0, -200.0, 100.0])})
    out = tmp_path / "cal"
    assert main(["calibrate", f"file={data}", f"out={out}", "units=mgauss"]) == 3
    said = capsys.readouterr().out
    assert said.startswith("FAIL ")
    cure = next(s for s in said.splitlines() if s.startswith("the field moves with the current"))
    rms = float(cure.split("error is ")[1].split(" %")[0])
    assert rms < 1.0 and "against" in cure and "verdict judges the static calibration" in cure
    terms = json.loads((out / "calibration.json").read_text())["time_varying"]
    assert terms["kept"]
    np.testing.assert_allclose(np.array(terms["C"])[:, 0], [300.0, -200.0, 100.0], rtol=0.01)
    assert sorted(p.name for p in out.iterdir()) == ["calibration.json", "calibration.png",
                                                     "manifest.json", "ranking.csv"]


def test_a_regressor_column_left_out_is_named_with_the_reason(tmp_path, capsys):
    K = 400
    current = np.linspace(2.0, 18.0, K)
    current[::2] = np.nan                                   # logged at half the rate
    data = disturbed_csv(tmp_path / "data.csv", K, {"current": (current, None),
                                                    "temperature": (np.full(K, 25.0), None)},
                         seed=None, diag=(1.0, 1.0, 1.0), with_t=False)
    assert main(["calibrate", f"file={data}", f"out={tmp_path / 'cal'}", "units=mgauss",
                 "bootstrap=0"]) == 0
    said = capsys.readouterr().out.splitlines()
    assert ("time-varying terms not fitted: current (values in 50 % of the samples, 90 % "
            "needed), temperature (constant)") in said


def test_current_and_temperature_kept_give_the_firmware_the_current_alone(tmp_path, capsys):
    """A PX4 log usually has a varying temperature too: when both terms are kept, the firmware
    files (which hold a current term only) get the fit with the current alone if it holds."""
    K = 1500
    data = disturbed_csv(tmp_path / "data.csv", K, {
        "current": (current_of(K), [4.0, -2.0, 3.0]),                 # mGauss per A
        "temperature": (np.linspace(10.0, 40.0, K), [2.0, -1.5, 1.0])})   # mGauss per C
    out = tmp_path / "cal"
    assert main(["calibrate", f"file={data}", f"out={out}", "units=mgauss",
                 "bootstrap=0"]) == 0
    said = capsys.readouterr().out
    assert "u = current, temperature" in said
    assert ("firmware files hold the fit with the current term alone, as temperature has no "
            "parameter") in said
    params = dict(line.split() for line in (out / "ardupilot.param").read_text().splitlines()
                  if not line.startswith("#"))
    assert params["COMPASS_MOTCT"] == "2"
    # MOT = -M C with M close to the identity: about (-4, 2, -3) mGauss per A.
    np.testing.assert_allclose([float(params[f"COMPASS_MOT_{a}"]) for a in "XYZ"],
                               [-4.0, 2.0, -3.0], atol=0.5)
