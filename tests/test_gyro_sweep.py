"""The gyro sweep end to end at a tiny size, its report section and the real-data entry."""

from __future__ import annotations

import numpy as np
import pandas as pd

import magbench
from magbench.cli import main
from magbench.gyro_sweep import (
    GYRO_ROW_COLUMNS,
    GyroPoint,
    GyroSweepSpec,
    gyro_report_section,
    run_gyro_methods_on_recording,
    run_gyro_sweep,
    run_gyro_trial,
)
from magbench.sources.trajectory import simulate

ALGOS = ["sar_ls", "magyc_ls", "magyc_nls", "magfactor3", "magical"]


def tiny_spec(**kw) -> GyroSweepSpec:
    points = [GyroPoint("wide", 0.0, 0.0), GyroPoint("low", 0.01, 0.005)]
    return GyroSweepSpec(points=points, trials=2, seed=1, algorithms=ALGOS, rate_hz=50.0,
                         duration_s=12.0, **kw)


def test_trial_rows_and_noise_free_gyro_bias():
    spec = tiny_spec()
    rows = run_gyro_trial(spec, spec.points[0], 0)
    assert [r["algorithm"] for r in rows] == ALGOS
    by = {r["algorithm"]: r for r in rows}
    # Noise-free point: MAGYC-NLS recovers T, h and the gyro bias; MAG.I.C.AL is on the same y.
    assert by["magyc_nls"]["J"] < 1e-3 and by["magyc_nls"]["J_wb"] < 1e-3
    assert by["magical"]["J"] < 1e-6
    assert np.isnan(by["sar_ls"]["J_wb"]) and by["magyc_nls"]["gyro"] and not by["magical"]["gyro"]
    assert rows == run_gyro_trial(spec, spec.points[0], 0) or all(
        a["J"] == b["J"] for a, b in zip(rows, run_gyro_trial(spec, spec.points[0], 0),
                                         strict=True))


def test_sweep_end_to_end_writes_files_and_section(tmp_path):
    spec = tiny_spec()
    trials, summary = run_gyro_sweep(spec, tmp_path / "gyro", n_jobs=1, chunk_size=1)
    assert list(trials.columns) == GYRO_ROW_COLUMNS
    assert len(trials) == len(spec.points) * spec.trials * len(ALGOS)
    on_disk = pd.read_csv(tmp_path / "gyro" / "trials.csv")
    assert len(on_disk) == len(trials)
    assert (tmp_path / "gyro" / "gyro_J.png").stat().st_size > 1000
    plotted = pd.read_csv(tmp_path / "gyro" / "gyro_J.csv")
    assert set(plotted["algorithm"]) == set(ALGOS) and len(plotted) == 2 * len(ALGOS)
    assert set(summary["n"]) == {spec.trials}
    text = gyro_report_section(tmp_path)
    assert "| MAGYC-NLS * |" in text and "gyro_J.png" in text and "| MAG.I.C.AL |" in text


def test_report_section_without_results(tmp_path):
    assert "No results yet" in gyro_report_section(tmp_path)


def test_cli_dispatches_the_gyro_sweep(tmp_path, capsys):
    code = main(["sweep=gyro", "sweep.trials=1", "sweep.gyro_noise=[0.01]",
                 "sweep.coverage=[wide]", "algorithms=[sar_ls,magyc_nls]", "n_jobs=1",
                 f"results_dir={tmp_path}", "progress=false"])
    assert code == 0
    trials = pd.read_csv(tmp_path / "gyro" / "trials.csv")
    assert list(trials["algorithm"]) == ["sar_ls", "magyc_nls"]
    assert (tmp_path / "gyro" / "section.md").exists()
    assert main(["sweep=gyro", "sweep.coverage=[nowhere]", f"results_dir={tmp_path}"]) == 2
    from magbench.cli import compose_config
    from magbench.gyro_sweep import spec_from_config

    spec, _, _ = spec_from_config(compose_config(["sweep=gyro"]))
    assert set(spec.algorithms) == set(magbench.methods())      # 'all' includes gyro methods
    assert len(spec.points) == 9 and spec.trials == 30
    assert "unknown coverage" in capsys.readouterr().err


def test_recording_entry_point_runs_every_gyro_method_but_magfactor3():
    tr = simulate(np.random.default_rng(0), rate_hz=50.0, duration_s=12.0,
                  T=40.0 * np.eye(3), h=np.array([3.0, -2.0, 1.0]), gyro_bias=np.zeros(3))
    rows = run_gyro_methods_on_recording(tr.y, tr.angular_rate, tr.t)
    names = [r["algorithm"] for r in rows]
    gyro = [m for m in magbench.methods() if magbench.get_method(m).needs_gyro]
    assert set(names) == set(gyro) - {"magfactor3"}
    by = {r["algorithm"]: r for r in rows}
    assert by["sar_ls"]["ok"]
    np.testing.assert_allclose([by["sar_ls"][f"h_{i}"] for i in range(3)], [3, -2, 1],
                               atol=1e-2)
    np.testing.assert_allclose(by["magyc_ls"]["T_00"], 40.0, rtol=1e-3)
