"""``python -m magbench calibrate``: ranking, JSON, picture and one-line errors."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.cli.outfolder import check_manifest
from magbench.core.exports import GAUGE
from magbench.core.geometry import fibonacci_sphere
from magbench.core.model import Calibration
from magbench.methods.registry import get_method
from magbench.pipeline.rounds import FIRST_ROUND
from magbench.sources.recordings import DATA_ENV

T_TRUE = np.array([[520.0, 20.0, -8.0], [0.0, 470.0, 15.0], [0.0, 0.0, 610.0]])
H_TRUE = np.array([900.0, -350.0, 120.0])          # counts; offset larger than the radius
# The picture is written as an empty file here; tests/cli/test_picture.py draws it for real.
pytestmark = pytest.mark.usefixtures("blank_figures")


def recording(K: int = 240, sigma: float = 3.0, seed: int = 0) -> np.ndarray:
    y = fibonacci_sphere(K) @ T_TRUE.T + H_TRUE
    return y + sigma * np.random.default_rng(seed).standard_normal((K, 3))


def save(path, y: np.ndarray, names=("mx", "my", "mz")):
    frame = pd.DataFrame(y, columns=list(names))
    frame.insert(0, "t", np.arange(len(y)) * 0.02)
    frame.to_csv(path, index=False)
    return path


#: What a FAIL writes: the reasons, the ranking and the picture (no correction, no firmware).
FAIL_FILES = {"calibration.json", "ranking.csv", "calibration.png", "manifest.json"}


def calibrate(*args):
    return main(["calibrate", "progress=false", *args])


def test_one_method_writes_json_in_the_safe_gauge(tmp_path, capsys):
    y = recording()
    path = save(tmp_path / "rec.csv", y)
    assert calibrate(f"file={path}", "method=magical", f"out={tmp_path / 'out'}") == 0
    data = json.loads((tmp_path / "out" / "calibration.json").read_text())
    assert data["method"] == "magical" and data["gauge"] == GAUGE and data["version"] == 1
    T, h = np.array(data["T"]), np.array(data["h"])
    A, b = np.array(data["A"]), np.array(data["b"])
    np.testing.assert_array_equal(A, A.T)
    assert np.linalg.eigvalsh(A).min() > 0
    np.testing.assert_allclose(T @ A, np.eye(3), atol=1e-12)        # T is the gauge's A^-1
    own = Calibration(np.array(data["removed"]["method_T"]), h)
    np.testing.assert_allclose(np.linalg.norm((y - b) @ A.T, axis=1),
                               np.linalg.norm(own.apply(y), axis=1), rtol=1e-10)
    np.testing.assert_allclose((y - b) @ A.T, Calibration(T, h).apply(y), atol=1e-12)
    np.testing.assert_allclose(h, H_TRUE, atol=2.0)          # noise 3 counts on ~500
    # T_TRUE is upper triangular, not symmetric: the gauge's A inverts its symmetric factor.
    np.testing.assert_allclose(np.linalg.inv(A), Calibration(T_TRUE, H_TRUE).safe().T, rtol=0.02,
                               atol=3.0)
    assert data["J_r_in"] < 1e-3 and data["J_r_out"] < 1e-3 and data["meaningful"]
    assert data["samples_used"] == 240 and data["columns"] == ["mx", "my", "mz"]
    assert (tmp_path / "out" / "calibration.png").is_file()
    out = capsys.readouterr().out
    assert "   1  magical" in out and "calibration.json" in out


def test_verdict_is_held_out_in_percent_and_degrees(tmp_path, capsys):
    # Shuffled, so that each half in time covers the whole sphere (the lattice runs +Z to -Z).
    y = np.random.default_rng(2).permutation(recording(sigma=3.0))
    assert calibrate(f"file={save(tmp_path / 'rec.csv', y)}", "method=ellipsoid",
                     f"out={tmp_path / 'o'}") == 0
    v = json.loads((tmp_path / "o" / "calibration.json").read_text())["verdict"]
    assert v["held_out"] and v["samples"] == 240
    # Noise of 3 counts on a field radius of about 530 counts: 0.57 % along the field, so the
    # magnitude error's 95th percentile is near 1.96 * 0.57 = 1.1 % (a little more held out).
    assert 0.8 < v["field_error_pct"]["p95"] < 1.6
    assert v["field_error_pct"]["max"] >= v["field_error_pct"]["p95"]
    assert v["heading_error_deg"]["p95"] == pytest.approx(
        np.degrees(np.arcsin(v["field_error_pct"]["p95"] / 100)))
    out = capsys.readouterr()
    first = out.out.splitlines()[0]
    assert first.startswith("PASS  field error ") and "(p95), heading ~" in first
    assert "ellipsoid (full model) -> " in first
    assert "coverage is insufficient" not in out.err


def test_a_mirrored_method_answer_is_written_unmirrored(tmp_path, capsys):
    from magbench.methods.registry import register, unregister

    def mirrored(samples, **_):
        from magbench.methods.api import calibrate as fit

        cal = fit(samples, "ellipsoid")
        flip = np.diag([1.0, -1.0, 1.0]) @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0],
                                                      [0.0, 0.0, 1.0]])
        return Calibration(cal.T @ flip, cal.h)

    register("mirror_test", label="Mirrored", min_samples=9, family="extra")(mirrored)
    try:
        path = save(tmp_path / "rec.csv", recording())
        assert calibrate(f"file={path}", "method=mirror_test", f"out={tmp_path / 'o'}") == 0
    finally:
        unregister("mirror_test")
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["removed"]["mirrored"]
    assert data["removed"]["rotation_deg"] == pytest.approx(180.0, abs=1.0)
    assert np.linalg.det(np.array(data["A"])) > 0
    assert "rotation and a mirror image removed" in capsys.readouterr().out


def test_a_60_degree_cap_warns_and_names_the_gap(tmp_path, capsys):
    rng = np.random.default_rng(1)
    y = fibonacci_sphere(400, z_range=(0.5, 1.0)) @ T_TRUE.T + H_TRUE   # cap of 60 deg about +Z
    path = save(tmp_path / "cap.csv", y + rng.standard_normal(y.shape))
    assert calibrate(f"file={path}", "method=sphere", f"out={tmp_path / 'o'}") == 0
    err = capsys.readouterr().err
    assert "magbench: warning: coverage is insufficient" in err
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["warnings"] == [data["coverage"]["warning"]]
    assert data["coverage"]["largest_gap_deg"] > 100
    assert np.array(data["coverage"]["gap_centre"])[2] < -0.8        # the uncovered -Z side


def test_all_methods_are_ranked_and_the_simplest_of_the_tie_is_chosen(tmp_path, capsys):
    path = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={path}", "candidates=all", f"out={tmp_path / 'o'}") == 0
    ranking = pd.read_csv(tmp_path / "o" / "ranking.csv")
    names = set(ranking["algorithm"])
    assert "magical" in names and "sar_ls" not in names                  # no gyro in the file
    assert not names & {"vasconcelos_printed", "wu_shi_printed"}       # benchmark-only variants
    ranked = ranking[ranking["rank"].notna()]
    assert ranked["rank"].tolist() == list(range(1, len(ranked) + 1))
    assert ranked.index.tolist() == list(range(len(ranked)))           # ranked ones first
    assert np.isfinite(ranked["J_r_out"]).all() and ranked["meaningful"].all()
    admissible = ranked[~ranked["note"].fillna("").str.startswith("held-out worst case")]
    assert admissible["J_r_out"].is_monotonic_increasing               # by held-out J_r
    assert admissible.index.max() < len(admissible)      # worst-case outliers ranked after
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    tie = ranking[ranking["tie"]]
    assert data["tie"] == tie["algorithm"].tolist() and data["method"] in data["tie"]
    assert tie["algorithm"].iloc[0] == ranked["algorithm"].iloc[0]        # the best is in it
    chosen = tie[tie["algorithm"] == data["method"]].iloc[0]
    # the simplest of the tie: no member with fewer parameters, nor a closed-form one when
    # the chosen is iterative
    params = {"full": 9, "diagonal": 6, "sphere": 4, "bias": 3}
    assert params[chosen["model"]] == min(params[m] for m in tie["model"])
    assert chosen["n_iter"] == 0 or (tie["n_iter"] > 0).all()
    assert f"{len(tie)} tie with" in data["choice"] or len(tie) == 1
    assert f"chosen {data['method']}, the simplest" in capsys.readouterr().out


def test_the_second_round_is_skipped_on_a_full_sphere_with_the_same_choice(tmp_path, capsys):
    path = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={path}", f"out={tmp_path / 'auto'}") == 0
    out = capsys.readouterr().out
    assert calibrate(f"file={path}", "candidates=all", f"out={tmp_path / 'all'}") == 0
    auto, every = (json.loads((tmp_path / f / "calibration.json").read_text())
                   for f in ("auto", "all"))
    fitted = set(pd.read_csv(tmp_path / "auto" / "ranking.csv")["algorithm"])
    assert fitted == set(FIRST_ROUND)                      # the iterative ones were not fitted
    assert "not fitted: crassidis, dorveaux, vasconcelos, ali and " in out
    assert auto["method"] == every["method"] and auto["A"] == every["A"]
    assert set(auto["candidates"]["fitted"]) == set(FIRST_ROUND)
    assert "magical" in auto["candidates"]["not_fitted"]
    assert auto["candidates"]["second_round"] is None and every["candidates"]["not_fitted"] == []


def test_a_cap_fits_the_second_round_and_says_why(tmp_path, capsys):
    rng = np.random.default_rng(1)
    y = fibonacci_sphere(400, z_range=(0.5, 1.0)) @ T_TRUE.T + H_TRUE   # cap of 60 deg about +Z
    path = save(tmp_path / "cap.csv", rng.permutation(y + rng.standard_normal(y.shape)))
    assert calibrate(f"file={path}", "bootstrap=0", f"out={tmp_path / 'o'}") == 0
    out = capsys.readouterr().out
    fitted = set(pd.read_csv(tmp_path / "o" / "ranking.csv")["algorithm"])
    assert "second round fitted: " in out
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["candidates"]["second_round"] and not data["candidates"]["not_fitted"]
    assert {"magical", "dorveaux", "crassidis"} <= fitted


def test_a_candidates_list_fits_only_those(tmp_path):
    path = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={path}", "candidates=[fang,sphere]", "bootstrap=0",
                     f"out={tmp_path / 'o'}") == 0
    assert set(pd.read_csv(tmp_path / "o" / "ranking.csv")["algorithm"]) == {"fang", "sphere"}


def test_a_printed_variant_still_runs_when_named(tmp_path):
    path = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={path}", "method=wu_shi_printed", f"out={tmp_path / 'o'}") == 0
    assert json.loads((tmp_path / "o" / "calibration.json").read_text())["method"] == \
        "wu_shi_printed"


def test_columns_by_position_and_by_name(tmp_path):
    y = recording()
    path = tmp_path / "log.csv"
    pd.DataFrame({"ms": np.arange(240), "Z": y[:, 2], "X": y[:, 0], "Y": y[:, 1]}).to_csv(
        path, index=False)
    for i, cols in enumerate(["columns=[2,3,1]", "columns=[X,Y,Z]"]):
        assert calibrate(f"file={path}", "method=ellipsoid", cols, f"out={tmp_path / str(i)}") == 0
    a = json.loads((tmp_path / "0" / "calibration.json").read_text())
    b = json.loads((tmp_path / "1" / "calibration.json").read_text())
    np.testing.assert_allclose(a["h"], b["h"])
    np.testing.assert_allclose(a["h"], H_TRUE, atol=2.0)
    assert b["columns"] == ["X", "Y", "Z"]


def test_nan_rows_give_a_warning_line_and_are_dropped(tmp_path, capsys):
    y = recording()
    y[[10, 20], 0] = np.nan
    path = save(tmp_path / "rec.csv", y)
    assert calibrate(f"file={path}", "method=magical", f"out={tmp_path / 'o'}") == 0
    assert "magbench: warning: rec.csv: dropped 2 of 240 rows" in capsys.readouterr().err
    assert json.loads((tmp_path / "o" / "calibration.json").read_text())["samples_used"] == 238


@pytest.mark.parametrize(("args", "message"), [
    ([], "calibrate needs file=PATH"),
    (["file={tmp}/nope.csv"], "not found"),
    (["file={rec}", "columns=[mx,my,bz]"], "missing column(s) 'bz'"),
    (["file={rec}", "columns=mx"], "columns must be a list of three names or positions"),
    (["file={rec}", "method=nope"], "unknown method 'nope'"),
    (["file={rec}", "method=sar_ls"], "sar_ls needs gyroscope data"),
    (["file={bad}"], "non-numeric value 'x' in column 'my' at data row 3"),
    (["file={few}", "method=twostep"], "has 5 usable samples; at least 10 are needed"),
    (["file={flat}"], "nearly coplanar"),
    (["file={rec}", "preprocess=bogus"], "preprocess must be one of none, scale, centre"),
    (["file={rec}", "candidates=[fang,bogus]"], "candidates: unknown method(s) bogus"),
    (["file={rec}", "candidates=some"], "candidates must be auto, all or a list"),
    (["file={rec}", "candidates=[fang]", "method=fang"], "give either method=NAME"),
    (["file={rec}", "units=furlongs"], "units must be one of uT, nT, gauss, mgauss, counts"),
    (["file={rec}", "field_strength=48uT"], "field_strength=48uT has a unit but the file's unit"),
    (["file={rec}", "instance=1"], "instance=1 was given but rec.csv has no instance column"),
    (["file={rec}", "overwrite=maybe"], "overwrite must be true or false"),
    (["file={rec}", "picture=maybe"], "picture must be true or false"),
])
def test_errors_are_one_line_with_status_2(args, message, tmp_path, capsys):
    rec = save(tmp_path / "rec.csv", recording())
    bad = tmp_path / "bad.csv"
    bad.write_text("mx,my,mz\n1,2,3\n4,5,6\n7,x,9\n")
    few = save(tmp_path / "few.csv", recording(5))
    phi = np.linspace(0, 2 * np.pi, 100)
    flat = save(tmp_path / "flat.csv", 500 * np.column_stack([np.cos(phi), np.sin(phi),
                                                              0 * phi]) + H_TRUE)
    names = {"tmp": tmp_path, "rec": rec, "bad": bad, "few": few, "flat": flat}
    args = [a.format(**names) for a in args]
    assert calibrate(*args, f"out={tmp_path / 'o'}") == 2
    err = capsys.readouterr().err
    assert err.startswith("magbench: error: ") and message in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_picture_false_writes_the_same_correction_without_the_picture(tmp_path, capsys):
    rec = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={rec}", f"out={tmp_path / 'a'}", "bootstrap=0") == 0
    capsys.readouterr()
    assert main(["calibrate", "progress=false", f"file={rec}", f"out={tmp_path / 'b'}",
                 "bootstrap=0", "picture=false"]) == 0
    wrote = capsys.readouterr().out.splitlines()[-1]
    assert "calibration.png" not in wrote and "ranking.csv" in wrote
    assert (tmp_path / "a" / "calibration.png").exists()
    assert not (tmp_path / "b" / "calibration.png").exists()
    first, second = (json.loads((tmp_path / f / "calibration.json").read_text())
                     for f in "ab")
    assert first["A"] == second["A"] and first["b"] == second["b"]


def test_long_recordings_are_thinned_and_say_so(tmp_path, capsys):
    path = save(tmp_path / "long.csv", recording(3000))
    assert calibrate(f"file={path}", "method=ellipsoid", "max_samples=1000",
                     f"out={tmp_path / 'o'}") == 0
    assert "fitted 1000 (1 in 3)" in capsys.readouterr().out
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["stride"] == 3 and data["samples_in_file"] == 3000


def test_writes_c_header_and_ardupilot_params_beside_the_json(tmp_path, capsys):
    from tests.core.test_exports import ardupilot_correct, parse_header, parse_params

    y = recording()
    path = save(tmp_path / "rec.csv", y)
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 'o'}",
                     "units=mgauss") == 0
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    A, b = np.array(data["A"]), np.array(data["b"])
    header = (tmp_path / "o" / "calibration.h").read_text()
    assert "Verdict: Ellipsoid fit: field magnitude error" in header
    assert "y and b in mGauss" in header and data["unit"]["gauss_per_unit"] == 1e-3
    A32, b32 = parse_header(header, "mag_cal")
    np.testing.assert_allclose((y.astype(np.float32) - b32) @ A32.T, (y - b) @ A.T, rtol=2e-6,
                               atol=2e-6)
    params = parse_params((tmp_path / "o" / "ardupilot.param").read_text())
    corrected = ardupilot_correct(params, y) / data["field_strength"]
    np.testing.assert_allclose(corrected, (y - b) @ A.T, rtol=2e-6, atol=2e-6)
    out = capsys.readouterr().out
    assert "ardupilot.param" in out and "px4.params" in out
    assert "field strength 530.2 mGauss" in out


def test_px4_params_of_a_gauss_recording_give_back_the_corrected_samples(tmp_path, capsys):
    from tests.core.test_exports import parse_qgc, px4_correct

    y = recording() / 1000                                   # gauss
    path = save(tmp_path / "gauss.csv", y)
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 'o'}", "units=gauss",
                     "field_strength=50uT") == 0
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    A, b = np.array(data["A"]), np.array(data["b"])
    p = parse_qgc((tmp_path / "o" / "px4.params").read_text())
    np.testing.assert_allclose(px4_correct(p, y) / data["field_strength"], (y - b) @ A.T,
                               rtol=2e-6, atol=2e-6)
    assert (tmp_path / "o" / "ardupilot.param").exists()
    out = capsys.readouterr().out
    assert "field strength 0.5302 gauss (expected 0.5 gauss: +6.0 %)" in out
    assert data["field_strength_expected"] == pytest.approx(0.5)
    assert "not writing inav.txt, betaflight.txt (they take the flight controller's raw counts" \
        in out


def test_counts_without_a_unit_write_no_ardupilot_or_px4_file(tmp_path, capsys):
    # A field of 1060 fits no physical unit (530 would be inferred as mGauss).
    path = save(tmp_path / "counts.csv", 2 * recording())
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 'o'}") == 0
    out = capsys.readouterr().out
    assert out.count("not writing ardupilot.param, px4.params (unit unknown: pass units=") == 1
    assert out.splitlines()[1].startswith("units: unknown, and the field strength 1060 fits no "
                                          "physical unit")
    assert "field strength 1060 (file units, unit unknown)" in out
    assert not (tmp_path / "o" / "ardupilot.param").exists()
    assert (tmp_path / "o" / "calibration.h").exists()
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 'c'}",
                     "units=counts") == 0
    assert "not writing ardupilot.param, px4.params (unit counts (size unknown)" in \
        capsys.readouterr().out
    inav = (tmp_path / "c" / "inav.txt").read_text()
    b = np.array(json.loads((tmp_path / "c" / "calibration.json").read_text())["b"])
    assert all(f"set magzero_{a} = {round(v)}" in inav for a, v in zip("xyz", b, strict=True))
    # 16 counts per uT: 530 counts are 33 uT = 331 mGauss, which ArduPilot takes.
    path = save(tmp_path / "counts1.csv", recording())
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 's'}",
                     "units=0.0625uT") == 0
    p = (tmp_path / "s" / "ardupilot.param").read_text()
    assert re.search(r"^COMPASS_OFS_X -562\.4", p, re.M)          # -899.9 counts / 1.6


def test_an_existing_calibration_folder_is_kept_without_overwrite(tmp_path, capsys):
    path = save(tmp_path / "rec.csv", recording())
    out = tmp_path / "o"
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={out}", "units=mgauss",
                     "bootstrap=0") == 0
    before = (out / "calibration.json").read_text()
    capsys.readouterr()
    assert calibrate(f"file={path}", "method=sphere", f"out={out}") == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"magbench: error: out={out} already holds a calibration (calibration.json); "
                   "pass overwrite=true to replace it, or choose another out=")
    assert (out / "calibration.json").read_text() == before
    # Replaced with overwrite=true, as a whole: the folder holds the second run's files only.
    (out / "inav.txt").write_text("an earlier run's\n")
    assert calibrate(f"file={path}", "method=twostep", f"out={out}", "overwrite=true",
                     "bootstrap=0", "units=counts") == 0
    assert json.loads((out / "calibration.json").read_text())["method"] == "twostep"
    assert not (out / "ardupilot.param").exists()
    assert "an earlier run's" not in (out / "inav.txt").read_text()
    assert check_manifest(out) == ""


def test_two_compasses_exit_2_naming_them_and_instance_picks_one(tmp_path, capsys):
    from tests.core.test_exports import ardupilot_correct, parse_params

    y0, y1 = recording(seed=1), recording(seed=2) * 0.8 + 50
    frame = pd.concat([pd.DataFrame({"I": 0, "mx": y0[:, 0], "my": y0[:, 1], "mz": y0[:, 2]}),
                       pd.DataFrame({"I": 1, "mx": y1[:, 0], "my": y1[:, 1], "mz": y1[:, 2]})])
    path = tmp_path / "mag.csv"
    frame.to_csv(path, index=False)
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 'o'}") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds 2 sensors in column 'I': 0 (240 rows), 1 (240 rows); " \
        "choose one with instance=, e.g. instance=0" in err
    assert calibrate(f"file={path}", "method=ellipsoid", f"out={tmp_path / 'o'}", "instance=1",
                     "units=mgauss", "bootstrap=0") == 0
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["instance"] == {"column": "I", "value": "1"} and data["samples_used"] == 240
    p = parse_params((tmp_path / "o" / "ardupilot.param").read_text())
    assert "COMPASS_OFS2_X" in p and "COMPASS_OFS_X" not in p
    A, b = np.array(data["A"]), np.array(data["b"])
    np.testing.assert_allclose(ardupilot_correct(p, y1, "2") / data["field_strength"],
                               (y1 - b) @ A.T, rtol=2e-6, atol=2e-6)


def test_default_folder_is_named_after_the_folder_of_a_data_csv(tmp_path, monkeypatch):
    (tmp_path / "my_drone").mkdir()
    save(tmp_path / "my_drone" / "data.csv", recording())
    save(tmp_path / "flight7.csv", recording())
    monkeypatch.chdir(tmp_path)
    assert calibrate("file=my_drone/data.csv", "method=ellipsoid", "bootstrap=0") == 0
    assert calibrate("file=flight7.csv", "method=ellipsoid", "bootstrap=0") == 0
    assert (tmp_path / "my_drone-calibration" / "calibration.json").exists()
    assert (tmp_path / "flight7-calibration" / "calibration.json").exists()
    assert not (tmp_path / "data-calibration").exists()


@pytest.mark.parametrize("option", ["+options.magical.foo=1", "options.magical.foo=1"])
def test_an_unknown_option_exits_2_naming_it_before_the_file_is_judged(option, tmp_path,
                                                                        capsys):
    phi = np.linspace(0, 2 * np.pi, 100)
    flat = save(tmp_path / "flat.csv", 500 * np.column_stack([np.cos(phi), np.sin(phi),
                                                              0 * phi]) + H_TRUE)
    assert calibrate(f"file={flat}", option, f"out={tmp_path / 'o'}") == 2
    err = capsys.readouterr().err
    accepted = ", ".join(get_method("magical").option_names())
    assert err == f"magbench: error: unknown option(s) foo for magical; it accepts: {accepted}\n"


def test_spikes_are_reported_and_the_intervals_printed(tmp_path, capsys):
    y = np.random.default_rng(4).permutation(recording(600))
    y[::20] *= 10.0                                        # 5 % spikes, 10x
    assert calibrate(f"file={save(tmp_path / 'rec.csv', y)}", "method=fang", "bootstrap=20",
                     f"out={tmp_path / 'o'}") == 0
    out = capsys.readouterr().out
    assert "30 outliers set aside" in out
    assert "(95 %, block bootstrap)" in out or "(95 %, model-based)" in out
    assert "wider of model-based and block bootstrap (20 refits, blocks of" in out
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["outliers"]["set_aside"] == 30
    iv = data["intervals"]
    assert np.all(np.abs(np.array(iv["h"]) - H_TRUE) <= 2 * np.array(iv["h_half_width"]))


SHARED = Path(os.environ.get(DATA_ENV) or Path(__file__).resolve().parents[3] / "shared" /
              "data" / "real")


@pytest.mark.skipif(not (SHARED / "hmc5883l_sphere" / "data.csv").exists(),
                    reason=f"real recordings not found ({DATA_ENV} unset, {SHARED} absent)")
def test_a_60_degree_cap_of_a_real_recording_warns_and_names_the_rotation(tmp_path, capsys):
    from magbench.core.robust import robust_sphere_fit

    frame = pd.read_csv(SHARED / "hmc5883l_sphere" / "data.csv")
    y = frame[["mx", "my", "mz"]].to_numpy()
    centre, _, _ = robust_sphere_fit(y)
    u = (y - centre) / np.linalg.norm(y - centre, axis=1)[:, None]
    frame[u[:, 2] >= 0.5].to_csv(tmp_path / "cap.csv", index=False)   # 60 deg about +Z
    args = ["max_samples=800", "bootstrap=0"]
    assert calibrate(f"file={tmp_path / 'cap.csv'}", *args, f"out={tmp_path / 'c'}") == 0
    err = capsys.readouterr().err
    assert "magbench: warning: coverage is insufficient" in err
    assert "rotate it about its" in err and "axis, turning its" in err
    assert "the choice was limited to" in err
    assert calibrate(f"file={SHARED / 'hmc5883l_sphere' / 'data.csv'}", *args,
                     f"out={tmp_path / 'f'}") == 0
    assert "coverage is insufficient" not in capsys.readouterr().err


@pytest.mark.skipif(not (SHARED / "bno055_hand" / "data.csv").exists(),
                    reason=f"real recordings not found ({DATA_ENV} unset, {SHARED} absent)")
def test_bno055_counts_become_milligauss_only_with_their_size(tmp_path, capsys):
    # Its SOURCE.md: raw register counts, 16 per microtesla.
    from tests.core.test_exports import ardupilot_correct, parse_params

    path = SHARED / "bno055_hand" / "data.csv"
    args = [f"file={path}", "method=ellipsoid", "bootstrap=0"]
    assert calibrate(*args, f"out={tmp_path / 'raw'}") == 0
    assert "not writing ardupilot.param, px4.params (unit unknown" in capsys.readouterr().out
    assert not (tmp_path / "raw" / "ardupilot.param").exists()
    assert calibrate(*args, f"out={tmp_path / 'mg'}", "units=0.0625uT") == 0
    data = json.loads((tmp_path / "mg" / "calibration.json").read_text())
    assert data["unit"]["description"] == "counts of 0.0625 uT"
    p = parse_params((tmp_path / "mg" / "ardupilot.param").read_text())
    np.testing.assert_allclose([p[f"COMPASS_OFS_{a}"] for a in "XYZ"],
                               -0.625 * np.array(data["b"]), rtol=1e-6)
    y = pd.read_csv(path)[["mx", "my", "mz"]].to_numpy()
    corrected = ardupilot_correct(p, y * 0.625)                # counts -> mGauss
    np.testing.assert_allclose(corrected / (0.625 * data["field_strength"]),
                               (y - data["b"]) @ np.array(data["A"]).T, rtol=2e-6, atol=2e-6)


def test_a_single_device_id_becomes_px4s_calibration_id(tmp_path):
    y = recording() / 1000                                   # gauss
    frame = pd.DataFrame({"device_id": 396809, "mx": y[:, 0], "my": y[:, 1], "mz": y[:, 2]})
    frame.to_csv(tmp_path / "px4.csv", index=False)
    assert calibrate(f"file={tmp_path / 'px4.csv'}", "method=ellipsoid", "units=gauss",
                     f"out={tmp_path / 'o'}", "bootstrap=0") == 0
    text = (tmp_path / "o" / "px4.params").read_text()
    assert "1\t1\tCAL_MAG0_ID\t396809\t6" in text and "not set here" not in text
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["instance"] == {"column": "device_id", "value": "396809"}


FIRMWARE = {"calibration.h", "ardupilot.param", "ranking.csv", "calibration.png"}


def status_of(tmp_path, y, *args, name="rec"):
    """Exit code, first output line, the JSON and the files written for samples ``y``."""
    path = save(tmp_path / f"{name}.csv", y)
    out_dir = tmp_path / f"{name}-out"
    code = calibrate(f"file={path}", "bootstrap=0", *args, f"out={out_dir}")
    data = json.loads((out_dir / "calibration.json").read_text())
    return code, data, {p.name for p in out_dir.iterdir()}


def still_prefix(y: np.ndarray, share: float, sigma: float, seed: int = 5) -> np.ndarray:
    """``y`` after a still stretch of ``share`` of the whole (the first sample plus noise)."""
    n = round(share / (1 - share) * len(y))
    noise = sigma * np.random.default_rng(seed).standard_normal((n, 3))
    return np.vstack([y[0] + noise, y])


@pytest.mark.parametrize("share", [0.3, 0.5, 0.7])
def test_a_still_prefix_is_thinned_and_the_calibration_passes(share, tmp_path, capsys):
    y = np.random.default_rng(2).permutation(recording(600))
    code, data, files = status_of(tmp_path, still_prefix(y, share, 3.0))
    first = capsys.readouterr().out.splitlines()[0]
    assert code == 0 and data["status"] == "PASS" and first.startswith("PASS  ")
    assert FIRMWARE - {"ardupilot.param"} <= files
    n_still = round(share / (1 - share) * 600)
    assert data["thinning"]["thinned"] >= n_still - 60
    assert data["model"] == "full"
    np.testing.assert_allclose(data["b"], H_TRUE, atol=3.0)
    assert data["field_strength"] == pytest.approx(530, rel=0.05)


@pytest.mark.skipif(not (SHARED / "hmc5883l_sphere" / "data.csv").exists(),
                    reason=f"real recordings not found ({DATA_ENV} unset, {SHARED} absent)")
@pytest.mark.parametrize(("name", "share"), [("hmc5883l_sphere", 0.5),
                                             ("qmc5883l_filtered", 0.5),
                                             ("hmc5883l_sphere", 0.7)])
def test_a_still_prefix_on_a_real_recording_keeps_its_calibration(name, share, tmp_path):
    y = pd.read_csv(SHARED / name / "data.csv")[["mx", "my", "mz"]].to_numpy()
    sigma = float(np.median(np.abs(np.diff(y, axis=0)))) / 0.6745 / np.sqrt(2)
    plain = status_of(tmp_path, y, name="plain")
    code, data, files = status_of(tmp_path, still_prefix(y, share, max(sigma, 1e-9)))
    assert code == plain[0] == 0 and data["status"] == plain[1]["status"] != "FAIL"
    assert "calibration.h" in files
    assert data["model"] == "full"
    assert data["field_strength"] == pytest.approx(plain[1]["field_strength"], rel=0.01)
    np.testing.assert_allclose(data["b"], plain[1]["b"], atol=0.01 * plain[1]["field_strength"])
    assert data["verdict"]["field_error_pct"]["p95"] <= \
        1.2 * plain[1]["verdict"]["field_error_pct"]["p95"]


def test_a_band_of_15_degrees_warns_and_still_writes(tmp_path, capsys):
    rng = np.random.default_rng(5)
    y = fibonacci_sphere(400, z_range=(-0.259, 0.259)) @ T_TRUE.T + H_TRUE
    code, data, files = status_of(tmp_path, rng.permutation(y + 3 * rng.standard_normal(
        y.shape)))
    out = capsys.readouterr().out.splitlines()
    assert code == 0 and data["status"] == "WARN" and out[0].startswith("WARN  ")
    assert out[1].startswith("  warn: directions within +-1") and "of one plane" in out[1]
    assert FIRMWARE - {"ardupilot.param"} <= files


def test_8_samples_fail_with_exit_3_and_write_only_the_reasons(tmp_path, capsys):
    y = recording(8, seed=5)
    code, data, files = status_of(tmp_path, y)
    out = capsys.readouterr().out.splitlines()
    assert code == 3 and data["status"] == "FAIL" and out[0].startswith("FAIL  ")
    assert "nothing to flash" in out[0]
    assert any("8 distinct directions (< 10)" in r for r in data["fitness"]["reasons"])
    assert files == FAIL_FILES
    assert "A" not in data and "b" not in data and "A" in data["rejected"]
    assert main(["apply", f"calibration={tmp_path / 'rec-out' / 'calibration.json'}",
                 f"file={tmp_path / 'rec.csv'}", f"out={tmp_path / 'x.csv'}"]) == 2
    assert "judged this recording FAIL" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_a_60_degree_cap_warns_with_its_gap(tmp_path, capsys):
    rng = np.random.default_rng(5)
    y = fibonacci_sphere(400, z_range=(0.5, 1.0)) @ T_TRUE.T + H_TRUE
    code, data, files = status_of(tmp_path, rng.permutation(y + 3 * rng.standard_normal(
        y.shape)))
    out = capsys.readouterr().out.splitlines()
    assert code == 0 and data["status"] == "WARN"
    assert "deg of the gap centre (> 100 deg)" in out[1]
    assert FIRMWARE - {"ardupilot.param"} <= files
    # the same cap under a stricter gate fails
    code, data, files = status_of(tmp_path, y, "gate.fail_gap_deg=100", name="strict")
    assert code == 3 and data["status"] == "FAIL" and files == FAIL_FILES


def test_an_offset_only_fit_never_prints_a_zero_interval_for_A(tmp_path, capsys):
    rng = np.random.default_rng(3)
    y = 500.0 * rng.permutation(fibonacci_sphere(240)) + H_TRUE       # no soft iron
    path = save(tmp_path / "rec.csv", y + 2.0 * rng.standard_normal(y.shape))
    assert calibrate(f"file={path}", "method=twostep_hi", "bootstrap=20",
                     f"out={tmp_path / 'o'}") == 0
    out = capsys.readouterr().out
    assert "+- 0," not in out and "+- 0 " not in out
    assert "fixed (offset-only model: A is not estimated)" in out


@pytest.mark.parametrize(("arg", "message"), [
    ("gate.fail_error_pct=-1", "gate.fail_error_pct must be >= 0"),
    ("gate.warn_error_pct=20", "gate.warn_error_pct must not exceed gate.fail_error_pct"),
    ("gate.fail_directions=x", "gate.fail_directions must be an integer"),
    ("gate.warn_heading_deg=40", "gate.warn_heading_deg must not exceed gate.fail_heading_deg"),
    ("+gate.bogus=1", "gate.bogus"),
])
def test_bad_gate_keys_exit_2_in_one_line(arg, message, tmp_path, capsys):
    path = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={path}", arg, f"out={tmp_path / 'o'}") == 2
    err = capsys.readouterr().err
    assert err.startswith("magbench: error: ") and message in err and err.count("\n") == 1


def test_a_confident_mounting_rotation_is_written_to_both_autopilots(tmp_path, capsys):
    from tests.pipeline.test_flight import simulated_ulog

    log = simulated_ulog(tmp_path / "flight.ulg", 6, seed=4, seconds=30.0)
    out = tmp_path / "cal"
    assert calibrate(f"file={log}", f"out={out}", "bootstrap=0") == 0
    found = json.loads((out / "calibration.json").read_text())["mounting_rotation"]
    assert found["id"] == 6 and found["confidence"] > 2                # ROTATION_YAW_270
    assert "\nCOMPASS_ORIENT 6\n" in (out / "ardupilot.param").read_text()
    assert "1\t1\tCAL_MAG0_ROT\t6\t6\n" in (out / "px4.params").read_text()
    # The same samples with the attitude frozen: the rotation is refused and neither is set.
    from magbench.sources.recordings import read_samples

    rec = read_samples(log)
    frame = pd.DataFrame(rec.y, columns=["mx", "my", "mz"])
    frame.insert(0, "t", rec.t)
    for c in ("qw", "qx", "qy", "qz"):
        frame[c] = rec.extra[c][0]
    frame.to_csv(tmp_path / "frozen.csv", index=False)
    out = tmp_path / "frozen"
    assert calibrate(f"file={tmp_path / 'frozen.csv'}", f"out={out}", "bootstrap=0",
                     "units=gauss") == 0
    found = json.loads((out / "calibration.json").read_text())["mounting_rotation"]
    assert found["id"] is None and found["reason"]
    assert "ORIENT" not in (out / "ardupilot.param").read_text()
    assert "_ROT" not in (out / "px4.params").read_text()


def test_an_offset_that_follows_the_current_is_fitted_not_cut(tmp_path, capsys):
    """A flight log whose offset moves with the battery current (4 mGauss/A): the
    time-varying terms model it, so the offset check does not cut the recording, and the
    status carries no 'offset changed' warning."""
    from tests.pipeline.test_flight import simulated_ulog

    log = simulated_ulog(tmp_path / "flight.ulg", 0, seed=3, seconds=60.0,
                         motor=np.array([0.004, -0.002, 0.003]))
    assert calibrate(f"file={log}", f"out={tmp_path / 'o'}", "bootstrap=0",
                     "picture=false") == 0
    out = capsys.readouterr().out
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert "\noffset:" not in out
    assert not any("offset changed" in r for r in data["fitness"]["reasons"])
    assert data["time_varying"]["kept"] and data["samples_used"] > 1100


def test_calibrate_does_not_import_pandas(tmp_path):
    # pandas' import is a fifth of calibrate's wall time on a small file: the command reads,
    # ranks and writes without it (a program's calibrate_auto and the sweeps still use it).
    path = save(tmp_path / "rec.csv", recording())
    args = ["calibrate", f"file={path}", f"out={tmp_path / 'out'}", "picture=false",
            "bootstrap=0"]
    code = ("import sys\nfrom magbench.cli import main\n"
            f"rc = main({args!r})\n"
            "print(rc, 'pandas' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
                          check=False)
    assert done.stdout.splitlines()[-1] == "0 False", done.stdout + done.stderr
