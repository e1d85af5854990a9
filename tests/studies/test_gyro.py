"""The gyro sweep end to end at a tiny size, and its report section."""

from __future__ import annotations

import numpy as np
import pandas as pd

import magbench
from magbench.cli import main
from magbench.engine.sweep import run_study
from magbench.figures.gyro import write_gyro_figure
from magbench.report.gyro import gyro_report_section
from magbench.studies.gyro import GYRO_ROW_COLUMNS, GyroPoint, GyroStudy, gyro_trial_rows
from magbench.studies.review import read_trials

ALGOS = ["sar_ls", "magyc_ls", "magyc_nls", "magfactor3", "magical"]


def tiny_spec(**kw) -> GyroStudy:
    points = [GyroPoint("wide", 0.0, 0.0), GyroPoint("low", 0.01, 0.005)]
    return GyroStudy(points=points, trials=2, seed=1, algorithms=ALGOS, rate_hz=50.0,
                         duration_s=12.0, **kw)


def test_trial_rows_and_noise_free_gyro_bias():
    spec = tiny_spec()
    rows = gyro_trial_rows(spec, spec.points[0], 0)
    assert [r["algorithm"] for r in rows] == ALGOS
    by = {r["algorithm"]: r for r in rows}
    # Noise-free point: MAGYC-NLS recovers T, h and the gyro bias; MAG.I.C.AL is on the same y.
    assert by["magyc_nls"]["J"] < 1e-3 and by["magyc_nls"]["J_wb"] < 1e-3
    assert by["magical"]["J"] < 1e-6
    assert np.isnan(by["sar_ls"]["J_wb"]) and by["magyc_nls"]["gyro"] and not by["magical"]["gyro"]
    assert rows == gyro_trial_rows(spec, spec.points[0], 0) or all(
        a["J"] == b["J"] for a, b in zip(rows, gyro_trial_rows(spec, spec.points[0], 0),
                                         strict=True))


def test_sweep_end_to_end_writes_files_and_section(tmp_path):
    spec = tiny_spec()
    run_study(spec, tmp_path / "gyro", n_jobs=1, chunk_size=1, progress=False)
    summary = spec.summarize(tmp_path / "gyro")
    write_gyro_figure(summary, tmp_path / "gyro")
    trials = read_trials(tmp_path / "gyro" / "trials.csv")
    assert list(trials.columns) == [*GYRO_ROW_COLUMNS, "time_s"]   # time_s from its sidecar
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
    code = main(["sweep=gyro", "trials=1", "sweep.gyro_noise=[0.01]",
                 "sweep.coverage=[wide]", "algorithms=[sar_ls,magyc_nls]", "n_jobs=1",
                 f"results_dir={tmp_path}", "progress=false"])
    assert code == 0
    trials = pd.read_csv(tmp_path / "gyro" / "trials.csv")
    assert list(trials["algorithm"]) == ["sar_ls", "magyc_nls"]
    assert (tmp_path / "gyro" / "section.md").exists()
    assert main(["sweep=gyro", "sweep.coverage=[nowhere]", f"results_dir={tmp_path}"]) == 2
    from magbench.cli.config import compose_config
    from magbench.cli.kinds import study_for

    spec, _ = study_for(compose_config(["sweep=gyro"]))
    # 'all' includes the gyro-aided methods, not those that need an accelerometer
    from magbench.methods.registry import get_method

    assert set(spec.algorithms) == {m for m in magbench.methods()
                                    if not get_method(m).needs_accel}
    assert len(spec.points) == 9 and spec.trials == 30
    assert "unknown coverage" in capsys.readouterr().err
