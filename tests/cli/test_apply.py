"""``python -m magbench apply``: corrected samples equal the API's, one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.cli.main import command_help, general_help
from magbench.core.exports import to_json_dict
from magbench.core.model import Calibration
from magbench.sources.recordings import without_unit
from tests.cli.test_calibrate import H_TRUE, T_TRUE, recording, save


def apply(*args):
    return main(["apply", *args])


def write_calibration(path, cal=None, columns=None):
    cal = cal or Calibration(T_TRUE, H_TRUE)
    path.write_text(json.dumps(to_json_dict(cal, columns=columns)))
    return path


def test_apply_after_calibrate_gives_the_apis_corrected_samples(tmp_path, capsys):
    y = recording()
    rec = save(tmp_path / "rec.csv", y)
    assert main(["calibrate", f"file={rec}", "method=ellipsoid", f"out={tmp_path / 'cal'}"]) == 0
    out = tmp_path / "corrected.csv"
    assert apply(f"calibration={tmp_path / 'cal' / 'calibration.json'}", f"file={rec}",
                 f"out={out}") == 0
    data = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    frame = pd.read_csv(out)
    assert list(frame.columns) == ["t", "mx", "my", "mz"]
    np.testing.assert_allclose(frame["t"], np.arange(len(y)) * 0.02)
    expected = Calibration(np.array(data["T"]), np.array(data["h"])).apply(y)
    np.testing.assert_allclose(frame[["mx", "my", "mz"]], expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(frame[["mx", "my", "mz"]],
                               (y - np.array(data["b"])) @ np.array(data["A"]).T, atol=1e-12)
    assert "corrected 240 samples" in capsys.readouterr().out


def test_the_columns_the_json_records_are_used(tmp_path):
    y = recording()
    rec = tmp_path / "log.csv"
    pd.DataFrame({"ms": np.arange(240), "Z": y[:, 2], "X": y[:, 0], "Y": y[:, 1]}).to_csv(
        rec, index=False)
    cal = write_calibration(tmp_path / "c.json", columns=["X", "Y", "Z"])
    assert apply(f"calibration={cal}", f"file={rec}", f"out={tmp_path / 'o.csv'}") == 0
    frame = pd.read_csv(tmp_path / "o.csv")
    assert list(frame.columns) == ["X", "Y", "Z"]
    np.testing.assert_allclose(np.linalg.norm(frame.to_numpy(), axis=1), 1.0, atol=0.05)


def test_a_unit_in_a_column_name_becomes_the_corrected_unit(tmp_path, capsys):
    y = recording()
    rec = tmp_path / "phyphox.csv"
    pd.DataFrame({"Time (s)": np.arange(240) * 0.02, "Magnetic field x (µT)": y[:, 0],
                  "Magnetic field y (µT)": y[:, 1], "Magnetic field z (µT)": y[:, 2],
                  }).to_csv(rec, index=False)
    cal = write_calibration(tmp_path / "c.json")
    assert apply(f"calibration={cal}", f"file={rec}", f"out={tmp_path / 'o.csv'}") == 0
    frame = pd.read_csv(tmp_path / "o.csv")
    names = [f"Magnetic field {a} (1 = calibrated field)" for a in "xyz"]
    assert list(frame.columns) == ["t", *names]
    np.testing.assert_allclose(frame[names], Calibration(T_TRUE, H_TRUE).safe().apply(y),
                               atol=1e-12)


@pytest.mark.parametrize(("column", "bare", "had"), [
    ("Magnetic field x (µT)", "Magnetic field x", True),
    ('"mag_x [counts]"', "mag_x", True),
    ("mx", "mx", False),
])
def test_without_unit_drops_only_a_unit_suffix(column, bare, had):
    assert without_unit(column) == (bare, had)


def test_one_sample_without_header_is_corrected(tmp_path):
    m = np.array([0.6, 0.0, 0.8])
    rec = tmp_path / "one.csv"
    rec.write_text(",".join(repr(float(v)) for v in T_TRUE @ m + H_TRUE) + "\n")
    cal = write_calibration(tmp_path / "c.json")
    assert apply(f"calibration={cal}", f"file={rec}", f"out={tmp_path / 'o.csv'}") == 0
    frame = pd.read_csv(tmp_path / "o.csv")
    assert list(frame.columns) == ["mx", "my", "mz"]
    np.testing.assert_allclose(frame.to_numpy()[0], Calibration(T_TRUE, H_TRUE).safe().apply(
        T_TRUE @ m + H_TRUE), atol=1e-12)


@pytest.mark.parametrize(("args", "message"), [
    (["file={rec}"], "apply needs calibration=PATH"),
    (["calibration={cal}"], "apply needs file=PATH"),
    (["calibration={tmp}/none.json", "file={rec}"], "calibration file {tmp}/none.json not found"),
    (["calibration={badjson}", "file={rec}"], "is not valid JSON (Expecting value: line 1"),
    (["calibration={mirror}", "file={rec}"], "A is not symmetric positive definite"),
    (["calibration={cal}", "file={tmp}/none.csv"], "file {tmp}/none.csv not found"),
    (["calibration={cal}", "file={rec}", "columns=[mx,my,bz]"], "missing column(s) 'bz'"),
    (["calibration={cal}", "file={rec}", "columns=mx"],
     "columns must be a list of three names or positions"),
    (["calibration={xyz}", "file={rec}"], "missing column(s) 'X', 'Y', 'Z'"),
    (["calibration={cal}", "file={rec}", "out={tmp}"], "is a folder; expected the name of the CSV"),
])
def test_errors_are_one_line_with_status_2(args, message, tmp_path, capsys):
    names = {"tmp": tmp_path, "rec": save(tmp_path / "rec.csv", recording()),
             "cal": write_calibration(tmp_path / "c.json"),
             "xyz": write_calibration(tmp_path / "xyz.json", columns=["X", "Y", "Z"])}
    names["badjson"] = tmp_path / "bad.json"
    names["badjson"].write_text("not json")
    mirror = to_json_dict(Calibration(T_TRUE, H_TRUE))
    mirror["A"] = (np.array(mirror["A"]) @ np.diag([1.0, 1.0, -1.0])).tolist()
    names["mirror"] = tmp_path / "mirror.json"
    names["mirror"].write_text(json.dumps(mirror))
    out_args = [a.format(**names) for a in args]
    if not any(a.startswith("out=") for a in out_args):
        out_args.append(f"out={tmp_path / 'o.csv'}")
    assert apply(*out_args) == 2
    err = capsys.readouterr().err
    assert err.startswith("magbench: error: ") and message.format(**names) in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "o.csv").exists()


def test_an_existing_output_is_kept_unless_overwrite_is_given(tmp_path, capsys):
    rec = save(tmp_path / "rec.csv", recording())
    cal = write_calibration(tmp_path / "c.json")
    out = tmp_path / "o.csv"
    out.write_text("keep me\n")
    assert apply(f"calibration={cal}", f"file={rec}", f"out={out}") == 2
    assert "exists; choose another name or pass overwrite=true" in capsys.readouterr().err
    assert out.read_text() == "keep me\n"
    assert apply(f"calibration={cal}", f"file={rec}", f"out={rec}", "overwrite=true") == 2
    assert "is the input file" in capsys.readouterr().err
    assert apply(f"calibration={cal}", f"file={rec}", f"out={out}", "overwrite=true") == 0
    assert list(pd.read_csv(out).columns) == ["t", "mx", "my", "mz"]


def test_apply_is_in_the_help():
    assert "apply      correct a recording with a saved calibration.json" in general_help()
    text = command_help("apply")
    for key in ("calibration", "file", "columns", "out"):
        assert f"\n  {key} " in text
    assert "apply: output CSV" in text


def test_apply_keeps_the_chosen_instance(tmp_path, capsys):
    y0, y1 = recording(seed=1), recording(seed=2) + 40
    frame = pd.concat([pd.DataFrame({"I": 0, "mx": y0[:, 0], "my": y0[:, 1], "mz": y0[:, 2]}),
                       pd.DataFrame({"I": 1, "mx": y1[:, 0], "my": y1[:, 1], "mz": y1[:, 2]})])
    path = tmp_path / "mag.csv"
    frame.to_csv(path, index=False)
    cal = write_calibration(tmp_path / "cal.json")
    assert apply(f"calibration={cal}", f"file={path}", f"out={tmp_path / 'a.csv'}") == 2
    assert "holds 2 sensors in column 'I'" in capsys.readouterr().err
    assert apply(f"calibration={cal}", f"file={path}", f"out={tmp_path / 'a.csv'}",
                 "instance=1") == 0
    out = pd.read_csv(tmp_path / "a.csv")
    np.testing.assert_allclose(out[["mx", "my", "mz"]].to_numpy(),
                               Calibration(T_TRUE, H_TRUE).safe().apply(y1), atol=1e-9)


@pytest.mark.parametrize(("scale", "code", "warned"), [(1.0, 0, False), (1.2, 0, False),
                                                      (1.5, 0, True), (0.5, 0, True),
                                                      (3.5, 3, False), (1e-3, 3, False)])
def test_a_field_far_from_the_calibrated_one_warns_or_fails(tmp_path, capsys, scale, code,
                                                            warned):
    """Another site changes the field by at most ~3x: beyond it the calibration does not fit
    (another sensor or unit), FAIL with nothing written; beyond 25 % a warning."""
    y = (recording(sigma=0.0) - H_TRUE) * scale + H_TRUE
    rec = save(tmp_path / "rec.csv", y)
    cal = write_calibration(tmp_path / "c.json")
    out = tmp_path / "o.csv"
    assert apply(f"calibration={cal}", f"file={rec}", f"out={out}") == code
    said = capsys.readouterr()
    assert out.exists() == (code == 0)
    if code:
        assert said.out.startswith(f"FAIL  field magnitude {scale:.4g} (median, 1 = calibrated "
                                   "field)") and "nothing written" in said.out
    assert ("from the calibrated field: expected at a site" in said.err) == warned
