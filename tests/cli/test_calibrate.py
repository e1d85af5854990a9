"""``python -m magbench calibrate``: ranking, JSON, picture and one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.core.geometry import fibonacci_sphere
from magbench.core.model import Calibration

T_TRUE = np.array([[520.0, 20.0, -8.0], [0.0, 470.0, 15.0], [0.0, 0.0, 610.0]])
H_TRUE = np.array([900.0, -350.0, 120.0])          # counts; offset larger than the radius


def recording(K: int = 240, sigma: float = 3.0, seed: int = 0) -> np.ndarray:
    y = fibonacci_sphere(K) @ T_TRUE.T + H_TRUE
    return y + sigma * np.random.default_rng(seed).standard_normal((K, 3))


def save(path, y: np.ndarray, names=("mx", "my", "mz")):
    frame = pd.DataFrame(y, columns=list(names))
    frame.insert(0, "t", np.arange(len(y)) * 0.02)
    frame.to_csv(path, index=False)
    return path


def calibrate(*args):
    return main(["calibrate", "progress=false", *args])


def test_one_method_writes_json_whose_correction_equals_apply(tmp_path, capsys):
    y = recording()
    path = save(tmp_path / "rec.csv", y)
    assert calibrate(f"file={path}", "method=magical", f"out={tmp_path / 'out'}") == 0
    data = json.loads((tmp_path / "out" / "calibration.json").read_text())
    assert data["method"] == "magical" and data["correction"]["formula"] == "m = A y + b"
    T, h = np.array(data["T"]), np.array(data["h"])
    A, b = np.array(data["correction"]["A"]), np.array(data["correction"]["b"])
    np.testing.assert_allclose(y @ A.T + b, Calibration(T, h).apply(y), atol=1e-12)
    np.testing.assert_allclose(h, H_TRUE, atol=2.0)          # noise 3 counts on ~500
    assert data["J_r_in"] < 1e-3 and data["J_r_out"] < 1e-3 and data["meaningful"]
    assert data["samples_used"] == 240 and data["columns"] == ["mx", "my", "mz"]
    assert (tmp_path / "out" / "calibration.png").stat().st_size > 20_000
    out = capsys.readouterr().out
    assert "   1  magical" in out and "calibration.json" in out


def test_all_methods_are_ranked_and_the_best_is_chosen(tmp_path, capsys):
    path = save(tmp_path / "rec.csv", recording())
    assert calibrate(f"file={path}", f"out={tmp_path / 'o'}") == 0
    ranking = pd.read_csv(tmp_path / "o" / "ranking.csv")
    assert ranking["rank"].tolist() == list(range(1, len(ranking) + 1))
    assert "magical" in set(ranking["algorithm"]) and "sar_ls" not in set(ranking["algorithm"])
    good = ranking[ranking["meaningful"]]
    assert good["J_r_out"].is_monotonic_increasing           # ranked by held-out J_r
    assert not ranking["meaningful"].iloc[len(good):].any()  # meaningful ones first
    chosen = json.loads((tmp_path / "o" / "calibration.json").read_text())["method"]
    assert chosen == good["algorithm"].iloc[0]


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
    (["file={few}", "method=twostep"], "has 5 usable samples; at least 9 are needed"),
    (["file={flat}"], "nearly coplanar"),
    (["file={rec}", "preprocess=bogus"], "preprocess must be one of none, scale, centre"),
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


def test_long_recordings_are_thinned_and_say_so(tmp_path, capsys):
    path = save(tmp_path / "long.csv", recording(3000))
    assert calibrate(f"file={path}", "method=ellipsoid", "max_samples=1000",
                     f"out={tmp_path / 'o'}") == 0
    assert "using 1 sample in 3: 1000 of 3000" in capsys.readouterr().out
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["stride"] == 3 and data["samples_in_file"] == 3000
