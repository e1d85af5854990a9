"""The benchmark's logic (no timing is asserted: timing lives in `make bench`)."""


import numpy as np
import pandas as pd
import pytest

from magbench.report.speed import bench_report_section
from magbench.studies import speed as bench


def test_sizes_below_a_methods_minimum_are_recorded_not_timed():
    calls = bench.bench_calls(["magical"], sizes=(3, 12), datasets=1, repeats=1)
    first = calls.iloc[0]
    assert first["note"] == "K below minimum" and first["n"] == 0
    assert calls.iloc[1]["n"] == 1  # one dataset x one timed call (the warm-up is not counted)


def test_report_section_reads_the_csv_files(tmp_path):
    folder = tmp_path / "bench"
    folder.mkdir()
    pd.DataFrame({"algorithm": ["magical", "magical"], "K": [300, 1000], "n": [5, 5],
                  "median_s": [0.002, 0.006], "q25_s": [0.001, 0.005], "q75_s": [0.003, 0.007],
                  "min_s": [0.001, 0.005], "note": ["", ""]}).to_csv(folder / "calls.csv")
    pd.DataFrame({"n_jobs": [1, 2], "wall_s": [10.0, 5.5], "trials": [100, 100],
                  "methods": [2, 2], "speedup": [1.0, 10 / 5.5]}).to_csv(folder / "parallel.csv")
    pd.DataFrame({"algorithm": ["magical"], "compile_s": [7.5], "cached_first_s": [0.15],
                  "import_s": [0.3], "second_s": [0.0006]}).to_csv(folder / "first_calls.csv")
    text = bench_report_section(tmp_path)
    assert "| MAG.I.C.AL | 2 | 1-3 | - |" in text            # no K = 10000 row
    assert "MATLAB" not in text and "paper speed" not in text   # Table 2 holds the one speed
    assert "| MAG.I.C.AL | 7.5e+03 | 150 | 0.6 |" in text
    assert "speed-up 1.82x" in text
    assert bench_report_section(tmp_path / "nothing") == ""


def test_reproduce_times_add_up_and_read_the_calls_time(tmp_path):
    (tmp_path / "gamma").mkdir()
    pd.DataFrame({"algorithm": ["a", "b", "a"], "time_s": [1.0, 2.0, 0.5]}).to_csv(
        tmp_path / "gamma" / "trials_times.csv", index=False)
    (tmp_path / "heading").mkdir()
    pd.DataFrame({"algorithm": ["a"], "time_s": [0.25]}).to_csv(
        tmp_path / "heading" / "heading_trials_times.csv", index=False)
    pd.DataFrame({"algorithm": ["a", "b"], "spent_s": [0.75, 0.5]}).to_csv(
        tmp_path / "heading" / "timing.csv", index=False)
    steps = [{"step": "start-up", "wall_s": 1.0, "cpu_s": 1.0, "load_1min": 0.1},
             {"step": "gamma", "wall_s": 3.0, "cpu_s": 5.0, "load_1min": 0.2},
             {"step": "report", "wall_s": 6.0, "cpu_s": 6.0, "load_1min": 0.3},
             {"step": "heading", "wall_s": 1.0, "cpu_s": 2.0, "load_1min": 0.3}]
    table = bench.reproduce_times(steps, tmp_path, {"cpu_model": "X", "n_jobs": 2})
    assert list(table["step"]) == ["start-up", "gamma", "report", "heading", "total"]
    # any trials table's sidecar and the timing pass's calls count as calls
    assert table.iloc[3]["method_s"] == 1.5
    total = table.iloc[-1]
    assert (total["wall_s"], total["cpu_s"], total["method_s"]) == (11.0, 14.0, 5.0)
    gamma = table.iloc[1]
    assert gamma["method_s"] == 3.5 and gamma["overhead_cpu_s"] == 1.5
    assert gamma["cpu_per_wall"] == pytest.approx(5 / 3)
    assert gamma["share_wall"] == pytest.approx(3 / 11)
    assert np.isnan(table.iloc[2]["method_s"])          # the report times no calls
    assert set(table["cpu_model"]) == {"X"} and list(table["load_1min"][:3]) == [0.1, 0.2, 0.3]
    text = bench.format_reproduce_times(table)
    assert text.splitlines()[2].split() == ["gamma", "3.0", "5.0", "1.67", "3.5", "27%"]
    assert text.endswith("make reproduce: 0 min 11 s wall")


def test_requirement_closure_follows_requirements_but_not_extras():
    closure = bench._requirement_closure(["pandas"])
    assert {"pandas", "numpy", "python-dateutil"} <= closure
    assert "pytest" not in closure          # pandas[test] is an extra, not a requirement


def test_install_size_of_a_missing_peer_is_recorded_as_unknown(monkeypatch):
    monkeypatch.setattr(bench, "PEER_PACKAGES", ("no-such-peer-package",))
    row = bench.peer_install_size().iloc[0]
    assert row["package"] == "no-such-peer-package" and np.isnan(row["added_mb"])


# A fresh interpreter per tool (magbench twice, each installed peer): the bench's own
# machinery, which `make bench` exercises in full, at a cost the CI budget cannot spare.
@pytest.mark.slow
def test_bench_calibrate_reads_the_commands_own_time_from_fresh_processes(tmp_path):
    from importlib.util import find_spec

    # A file laid out as the real recordings are (t first): the peers read mx, my, mz by the
    # positions of the header.
    synthetic = pd.read_csv(bench.synthetic_recording(tmp_path / "s.csv", 300))
    synthetic[["t", "mx", "my", "mz"]].to_csv(tmp_path / "rec.csv", index=False)
    out = bench.bench_calibrate(path=tmp_path / "rec.csv", repeats=1)
    ours = out[out["tool"] == bench.MAGBENCH_TOOL]
    assert ours[["file", "K", "run"]].values.tolist() == [["rec.csv", 300, 1]]
    assert 0 < ours["command_s"].iloc[0] < ours["process_s"].iloc[0]
    assert (out["cpu_s"] > 0).all() and out["cpu_model"].str.len().gt(0).all()
    assert (out["cpu_count"] >= 1).all() and (out["load_1min"] >= 0).all()
    quick = out[out["tool"] == bench.MAGBENCH_NO_PICTURE]
    assert len(quick) == 1 and 0 < quick["command_s"].iloc[0] < quick["process_s"].iloc[0]
    installed = [p for p, (pkg, _, _) in bench.PEER_FILE_FITS.items() if find_spec(pkg)]
    peers = out[~out["tool"].isin(bench.MAGBENCH_TOOLS)]
    assert peers["tool"].tolist() == installed                  # one run each, in order
    assert (peers["process_s"] > 0).all() and peers["command_s"].isna().all()


def test_rounds_won_counts_the_rounds_per_recording_and_peer():
    times = {("a.csv", "magbench calibrate"): [0.7, 0.9, 0.8],
             ("a.csv", "magcal.ellipsoid_fit"): [0.8, 0.85, 0.9],
             ("b.csv", "magbench calibrate"): [1.0, 1.0, 1.0],
             ("b.csv", "magcal.ellipsoid_fit"): [1.1, 0.9, 0.9],
             ("b.csv", "magbench calibrate picture=false"): [0.5, 0.5, 0.95]}
    table = pd.DataFrame([{"file": f, "K": 10, "tool": tool, "run": run + 1, "process_s": t}
                          for (f, tool), ts in times.items() for run, t in enumerate(ts)])
    every = bench.rounds_won(table)
    quick = every[every["magbench"] == bench.MAGBENCH_NO_PICTURE]
    assert quick[["file", "won", "rounds"]].values.tolist() == [["b.csv", 2, 3]]
    won = every[every["magbench"] == bench.MAGBENCH_TOOL].set_index("file")
    assert won.loc["a.csv", ["won", "rounds"]].tolist() == [2, 3]   # round 2: 0.9 > 0.85
    assert won.loc["b.csv", ["won", "rounds"]].tolist() == [1, 3]
    assert won.loc["a.csv", "magbench_median_s"] == 0.8
    assert won.loc["b.csv", "peer_median_s"] == 0.9


def test_the_calibrate_comparison_includes_the_real_recording_when_it_is_there(tmp_path,
                                                                                monkeypatch):
    calls = []
    monkeypatch.setattr(bench, "bench_calibrate", lambda **kw: calls.append(kw) or
                        pd.DataFrame([{"tool": "x", "K": kw.get("K")}]))
    bench.bench_calibrate_files(repeats=2, data=tmp_path)
    assert calls == [{"K": K, "repeats": 2} for K in bench.CALIBRATE_SIZES]
    real = tmp_path / bench.CALIBRATE_RECORDING / "data.csv"
    real.parent.mkdir()
    real.write_text("t,mx,my,mz\n")
    calls.clear()
    bench.bench_calibrate_files(repeats=2, data=tmp_path)
    assert calls[-1] == {"path": real, "repeats": 2} and len(calls) == 3


def test_the_peer_script_reads_the_file_fits_and_saves(tmp_path):
    import json
    import subprocess
    import sys

    y = np.random.default_rng(0).standard_normal((50, 3)) + [5.0, -2.0, 1.0]
    pd.DataFrame(y, columns=["mx", "my", "mz"]).assign(t=0.0).to_csv(tmp_path / "f.csv",
                                                                     index=False)
    script = bench.PEER_SCRIPT.format(imports="", fit="c = y.mean(axis=0); M = 2 * np.eye(3)")
    subprocess.run([sys.executable, "-c", script, str(tmp_path / "f.csv"),
                    str(tmp_path / "o.json"), "0,1,2"], check=True)
    saved = json.loads((tmp_path / "o.json").read_text())
    np.testing.assert_allclose(saved["c"], y.mean(axis=0), rtol=1e-12)
    assert saved["M"] == (2 * np.eye(3)).tolist()
