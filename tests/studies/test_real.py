"""Real-recording loader, geometry checks, thinning and the real-data sweep (the fits of one
recording: tests/pipeline/test_fitting.py).

Unit tests write their own small CSV files (synthetic data); only the last test reads the shared
recordings, and it skips when the data directory is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.core.geometry import check_geometry, coverage, fibonacci_sphere, sphere_fit, thickness
from magbench.engine.sweep import run_study
from magbench.report.real import real_report_section
from magbench.sources.recordings import (
    DATA_ENV,
    Recording,
    data_dir,
    list_recordings,
    load_recording,
    read_samples,
)
from magbench.studies.real import RealStudy

T_TRUE = np.array([[1.1, 0.05, -0.02], [0.0, 0.9, 0.04], [0.0, 0.0, 1.2]])
H_TRUE = np.array([0.3, -0.2, 0.1])


def ellipsoid(K: int = 200, *, sigma: float = 0.0, seed: int = 0, scale: float = 1.0,
              offset: np.ndarray = H_TRUE) -> np.ndarray:
    m = fibonacci_sphere(K)
    y = m @ T_TRUE.T + offset + sigma * np.random.default_rng(seed).standard_normal((K, 3))
    return scale * y


def write(path: Path, y: np.ndarray, header: str | None = "t,mx,my,mz",
          extra: dict | None = None) -> Path:
    frame = pd.DataFrame(y, columns=["mx", "my", "mz"])
    frame.insert(0, "t", np.arange(len(y)) * 0.1)
    for k, v in (extra or {}).items():
        frame[k] = v
    if header is None:
        frame[["mx", "my", "mz"]].to_csv(path, index=False, header=False)
    else:
        frame[header.split(",") + list(extra or {})].to_csv(path, index=False)
    return path


# --------------------------------------------------------------------------- loader


def test_reads_named_columns_in_recorded_units(tmp_path):
    y = ellipsoid(scale=1000.0)
    rec = read_samples(write(tmp_path / "a.csv", y))
    np.testing.assert_allclose(rec.y, y)
    assert rec.K == 200 and rec.columns == ("mx", "my", "mz") and rec.t is not None
    assert rec.gyro is None and not rec.has_gyro


def test_columns_by_name_and_by_position_select_the_same_data(tmp_path):
    y = ellipsoid()
    frame = pd.DataFrame({"time": np.arange(200.0), "Bz": y[:, 2], "Bx": y[:, 0],
                          "By": y[:, 1], "temp": 25.0})
    path = tmp_path / "mine.csv"
    frame.to_csv(path, index=False)
    by_name = read_samples(path, ["Bx", "By", "Bz"])
    by_position = read_samples(path, [2, 3, 1])
    np.testing.assert_array_equal(by_name.y, y)
    np.testing.assert_array_equal(by_position.y, y)
    assert by_name.columns == ("Bx", "By", "Bz")


def test_headerless_and_whitespace_separated_files(tmp_path):
    y = np.round(ellipsoid(scale=500.0))
    path = tmp_path / "counts.txt"
    np.savetxt(path, y, fmt="%d")
    rec = read_samples(path)                       # three columns, no header: those three
    np.testing.assert_array_equal(rec.y, y)
    with pytest.raises(ValueError, match=r"no header row.*columns=\[0,1,2\]"):
        read_samples(path, ["mx", "my", "mz"])


def test_missing_column_names_what_the_file_has(tmp_path):
    path = write(tmp_path / "a.csv", ellipsoid())
    with pytest.raises(ValueError, match=r"missing column\(s\) 'bz'; the file has columns "
                                         r"t, mx, my, mz"):
        read_samples(path, ["mx", "my", "bz"])
    with pytest.raises(ValueError, match=r"positions \[7\] are out of range; the file has 4"):
        read_samples(path, [1, 2, 7])
    with pytest.raises(ValueError, match="exactly 3 columns"):
        read_samples(path, ["mx", "my"])


def test_unknown_layout_without_mx_my_mz_asks_for_columns(tmp_path):
    path = tmp_path / "b.csv"
    pd.DataFrame(np.hstack([ellipsoid(), np.ones((200, 1))]),
                 columns=["a", "b", "c", "d"]).to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"cannot tell which columns.*a, b, c, d"):
        read_samples(path)


def test_non_numeric_cell_is_reported_with_row_and_column(tmp_path):
    path = write(tmp_path / "a.csv", ellipsoid())
    lines = path.read_text().splitlines()
    fields = lines[5].split(",")                  # data row 5, line 6 of the file
    fields[2] = "12.3.4"
    lines[5] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"non-numeric value '12.3.4' in column 'my' at data "
                                         r"row 5 \(line 6 of the file\)"):
        read_samples(path)


def test_nan_rows_are_dropped_with_a_warning_that_counts_them(tmp_path):
    y = ellipsoid()
    y[[3, 50, 51], 1] = np.nan
    path = write(tmp_path / "a.csv", y)
    text = path.read_text().replace(",nan,", ",,", 1)   # an empty cell counts as missing too
    path.write_text(text)
    with pytest.warns(UserWarning, match="dropped 3 of 200 rows"):
        rec = read_samples(path)
    assert rec.K == 197 and np.isfinite(rec.y).all()


def test_too_few_samples(tmp_path):
    path = write(tmp_path / "a.csv", ellipsoid(8))
    with pytest.raises(ValueError, match="has 8 usable samples; at least 9 are needed"):
        read_samples(path, min_samples=9, check=False)


def test_missing_file_and_empty_file(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        read_samples(tmp_path / "nope.csv")
    (tmp_path / "empty.csv").write_text("\n")
    with pytest.raises(ValueError, match="is empty"):
        read_samples(tmp_path / "empty.csv")


def test_gyro_columns_are_read_when_present(tmp_path):
    y = ellipsoid(50)
    g = np.random.default_rng(0).standard_normal((50, 3))
    path = write(tmp_path / "g.csv", y, extra={"gx": g[:, 0], "gy": g[:, 1], "gz": g[:, 2]})
    rec = read_samples(path)
    assert rec.has_gyro
    np.testing.assert_allclose(rec.gyro, g)
    np.testing.assert_allclose(rec.t, np.arange(50) * 0.1)


# --------------------------------------------------------------------------- geometry


def test_sphere_fit_recovers_centre_and_radius():
    c0, r0 = np.array([120.0, -40.0, 15.0]), 48.0
    c, r = sphere_fit(fibonacci_sphere(100) * r0 + c0)
    np.testing.assert_allclose(c, c0, atol=1e-9)
    assert r == pytest.approx(r0)


def test_coverage_full_sphere_cap_and_circle():
    assert coverage(fibonacci_sphere(500)) == 1.0
    u = fibonacci_sphere(2000)
    cap = u[u[:, 2] > np.cos(np.radians(30))]          # cap of 30 deg: ~(1 - cos 60)/2
    assert coverage(cap) == pytest.approx(0.25, abs=0.03)
    phi = np.linspace(0, 2 * np.pi, 400)
    circle = np.column_stack([np.cos(phi), np.sin(phi), 0 * phi])
    assert coverage(circle) == pytest.approx(0.5, abs=0.03)   # a band of +-30 deg
    assert thickness(circle) < 1e-12 and thickness(fibonacci_sphere(300)) > 0.95


def test_nearly_coplanar_samples_are_rejected_with_the_figure(tmp_path):
    phi = np.linspace(0, 2 * np.pi, 300)
    y = np.column_stack([np.cos(phi), np.sin(phi), 0.01 * np.sin(3 * phi)]) * 40 + 5
    with pytest.raises(ValueError, match=r"nearly coplanar \(thickness 0.0\d+"):
        read_samples(write(tmp_path / "flat.csv", y))


def test_small_cap_is_rejected_with_the_coverage_figure(tmp_path):
    u = fibonacci_sphere(3000)
    cap = u[u[:, 2] > np.cos(np.radians(25))] @ T_TRUE.T + H_TRUE   # thickness 0.14
    with pytest.raises(ValueError, match=r"cover too little of the sphere \(coverage 0\.24"):
        read_samples(write(tmp_path / "cap.csv", cap))
    check_geometry(ellipsoid())                          # a full ellipsoid passes


# --------------------------------------------------------------------------- thinning


def test_thinning_and_halves_are_deterministic():
    rec = Recording("x", np.arange(30.0).reshape(10, 3), t=np.arange(10.0), n_rows=10)
    thin = rec.thinned(4)
    assert thin.stride == 3 and thin.t.tolist() == [0, 3, 6, 9]
    first, second = rec.halves()
    assert first.t.tolist() == [0, 1, 2, 3, 4] and second.t.tolist() == [5, 6, 7, 8, 9]
    assert rec.thinned(None) is rec and rec.thinned(10) is rec


# --------------------------------------------------------------------------- the sweep


def make_data_dir(root: Path) -> Path:
    """Three synthetic recordings in the shared layout (one short, like the 24-shot sets)."""
    specs = {"long_a": (400, 0.01, 0), "long_b": (300, 0.02, 1), "short": (8, 0.001, 2)}
    for name, (K, sigma, seed) in specs.items():
        (root / name).mkdir(parents=True)
        write(root / name / "data.csv", ellipsoid(K, sigma=sigma, seed=seed, scale=50.0))
    pd.DataFrame({"name": list(specs), "rows": [v[0] for v in specs.values()]}).to_csv(
        root / "INDEX.csv", index=False)
    return root


def test_data_dir_and_listing(tmp_path, monkeypatch):
    root = make_data_dir(tmp_path / "data")
    monkeypatch.setenv(DATA_ENV, str(root))
    assert data_dir() == root and data_dir(str(root)) == root
    assert list_recordings(root) == ["long_a", "long_b", "short"]
    monkeypatch.delenv(DATA_ENV)
    with pytest.raises(ValueError, match="no data directory: set the environment variable"):
        data_dir(None)
    with pytest.raises(ValueError, match="does not exist"):
        data_dir(tmp_path / "nowhere")
    with pytest.raises(ValueError, match=r"no recording 'zz'.*long_a, long_b, short"):
        load_recording(root, "zz")


def run_real_sweep(spec: RealStudy, out_dir: Path):
    run_study(spec, out_dir, progress=False)
    per_rec, per_method = spec.summarize(out_dir)
    trials = pd.read_csv(out_dir / "real_trials.csv", dtype={"error": str})
    return trials.assign(error=trials["error"].fillna("")), per_rec, per_method


def test_real_sweep_rows_and_summaries(tmp_path):
    root = make_data_dir(tmp_path / "data")
    spec = RealStudy(str(root), ["long_a", "long_b", "short"], ["magical", "twostep"],
                     preprocess=("centre",), max_samples=150)
    trials, per_rec, per_method = run_real_sweep(spec, tmp_path / "out" / "real")
    # 3 recordings x 2 methods x 3 fits, one row per fit (no partners here).
    assert len(trials) == 18
    long_a = trials[(trials["dataset"] == "long_a") & (trials["fit_on"] == "all")]
    assert (long_a["stride"] == 3).all() and (long_a["K_fit"] == 134).all()
    # The short recording's halves (4 samples) are below TWOSTEP's minimum of 10: skipped rows.
    short = trials[(trials["dataset"] == "short") & (trials["algorithm"] == "twostep")]
    assert short.set_index("fit_on")["skipped"].to_dict() == {
        "all": True, "first_half": True, "second_half": True}
    assert short["error"].str.contains("needs at least 10 samples").all()
    ok = per_rec[per_rec["dataset"] != "short"]
    assert ok["meaningful"].all()
    assert (ok["J_r_in"] < 0.1 * ok["J_r_sphere_in"]).all()   # soft iron removed
    assert np.isfinite(ok["J_r_out"]).all()
    twostep = per_method.set_index("algorithm").loc["twostep"]
    assert twostep["n_applicable"] == 2 and twostep["RB_pct"] == 100.0
    assert twostep["accuracy_in"] == pytest.approx(
        1 / ok[ok["algorithm"] == "twostep"]["J_r_in"].mean())
    for name in ("real_trials.csv", "real_summary.csv", "fig6_real.csv"):
        assert (tmp_path / "out" / "real" / name).exists()
    section = real_report_section(tmp_path / "out")
    assert "| TWOSTEP | 100 [34.2, 100] |" in section and "2 / 2" in section   # Wilson, 2 of 2
    assert real_report_section(tmp_path / "elsewhere") == ""


def test_cli_runs_the_real_sweep_from_data_dir(tmp_path, capsys):
    root = make_data_dir(tmp_path / "data")
    assert main(["sweep=real", f"data_dir={root}", f"results_dir={tmp_path}/res", "n_jobs=1",
                 "progress=false", "algorithms=[magical]", "sweep.datasets=[long_a,short]",
                 "sweep.preprocess=[scale]"]) == 0
    out = tmp_path / "res" / "real"
    assert (out / "fig6_real.png").stat().st_size > 10_000
    assert "| MAG.I.C.AL |" in (out / "real.md").read_text()
    assert "6 rows" in capsys.readouterr().out


@pytest.mark.parametrize(("override", "message"), [
    ("sweep.datasets=[long_a,zz]", "unknown recording(s) zz"),
    ("sweep.preprocess=[scale,bogus]", "sweep.preprocess must be a list from"),
    ("sweep.max_samples=3", "sweep.max_samples must be an integer >= 8"),
])
def test_cli_real_sweep_errors(override, message, tmp_path, capsys):
    root = make_data_dir(tmp_path / "data")
    assert main(["sweep=real", f"data_dir={root}", f"results_dir={tmp_path}/res",
                 override]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_cli_real_sweep_without_data_dir(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(DATA_ENV, raising=False)
    assert main(["sweep=real", f"results_dir={tmp_path}"]) == 2
    assert "no data directory" in capsys.readouterr().err


SHARED = os.environ.get(DATA_ENV) or str(Path(__file__).resolve().parents[3]
                                         / "shared" / "data" / "real")


@pytest.mark.skipif(not (Path(SHARED) / "INDEX.csv").exists(),
                    reason=f"shared recordings not found ({DATA_ENV} unset and {SHARED} absent)")
def test_real_sweep_on_shared_recordings(tmp_path):
    spec = RealStudy(SHARED, ["bno055_hand", "cavesurvey_sap6_bb"], ["ellipsoid", "sphere"],
                     preprocess=("centre",))
    _, per_rec, per_method = run_real_sweep(spec, tmp_path / "real")
    rec = per_rec.set_index(["dataset", "algorithm"])
    assert rec["meaningful"].all()
    # The ellipsoid fit removes the soft iron of the 24 clean shots: far below the sphere fit.
    assert rec.loc[("cavesurvey_sap6_bb", "ellipsoid"), "J_r_in"] < 0.05 * rec.loc[
        ("cavesurvey_sap6_bb", "sphere"), "J_r_in"]
    assert rec.loc[("bno055_hand", "ellipsoid"), "K"] == 809
    assert set(per_method["algorithm"]) == {"ellipsoid", "sphere"}


def test_a_recording_edited_between_runs_changes_the_fingerprint(tmp_path):
    """The real sweep's fingerprint holds each recording's SHA-256: rows of an edited
    recording are never reused on resume."""
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        write(tmp_path / name / "data.csv", ellipsoid(60, seed=len(name)))
    study = RealStudy(root=str(tmp_path), datasets=["a", "b"], algorithms=["sphere"])
    first = study.fingerprint()
    assert set(study.describe()["recording_sha256"]) == {"a", "b"}
    assert study.fingerprint() == first                              # nothing changed
    path = tmp_path / "b" / "data.csv"
    path.write_text(path.read_text().replace("1", "2", 1))
    assert study.fingerprint() != first
