"""The speed section's file-to-correction table, from a known calibrate.csv."""

import pandas as pd

from magbench.report.speed import calibrate_lines


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
