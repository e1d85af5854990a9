"""The speed section's file-to-correction table, from a known calibrate.csv."""

import pandas as pd

from magbench.report.speed import calibrate_lines, reproduce_case_lines


def test_the_calibrate_table_counts_the_rounds_magbench_was_faster():
    times = {"magbench calibrate": [0.7, 0.9, 0.8], "magcal.ellipsoid_fit": [0.8, 0.85, 0.9],
             "navlib.cal_mag_twostep_hsi": [1.2, 1.3, 1.1]}
    cal = pd.DataFrame([{"tool": tool, "K": 10_000, "run": run, "process_s": t,
                         "command_s": 0.3 if tool == "magbench calibrate" else float("nan")}
                        for run in (1, 2, 3) for tool, ts in times.items()
                        for t in [ts[run - 1]]])
    rows = {line.split(" | ")[0].lstrip("| "): line for line in calibrate_lines(cal)
            if line.startswith("| ") and "---" not in line}
    assert rows["magbench calibrate"].endswith("| 3 | 0.8 | 0.3 | - |")
    # round 2: 0.9 s against magcal's 0.85 s
    assert rows["magcal.ellipsoid_fit"].endswith("| 3 | 0.85 | - | 2 of 3 |")
    assert rows["navlib.cal_mag_twostep_hsi"].endswith("| 3 | 1.2 | - | 3 of 3 |")


def test_the_reproduce_cases_table_says_each_case_and_what_lies_beyond_the_method():
    cases = pd.DataFrame([
        {"case": "make reproduce, empty results_dir", "wall_s": 263.26, "cpu_s": 473.9,
         "method_s": float("nan"), "beyond_method_s": float("nan"), "cpu_model": "AMD EPYC",
         "cpu_count": 2, "load_1min": 2.153},
        {"case": "make reproduce again, one plugin method added", "wall_s": 38.03,
         "cpu_s": 64.66, "method_s": 4.505, "beyond_method_s": 33.53, "cpu_model": "AMD EPYC",
         "cpu_count": 2, "load_1min": 2.153}])
    lines = reproduce_case_lines(cases)
    assert "(AMD EPYC, 2 CPUs, load 2.2 at the start" in lines[1]
    assert "| make reproduce, empty results_dir | 263 | 474 | - | - |" in lines
    assert "| make reproduce again, one plugin method added | 38 | 64.7 | 4.5 | 33.5 |" in lines
    assert reproduce_case_lines(cases.iloc[:0]) == []
