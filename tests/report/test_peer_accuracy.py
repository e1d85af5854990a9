"""The bench section's peer-accuracy table and lattice explanation, from a hand-made summary."""

import pandas as pd

from magbench.report.peer_accuracy import lattice_explanation, peer_accuracy_lines

#: (geometry, tool) -> (mean J_h, rms J_h, mean |mean direction|); the bound's rms is 0.001.
CASE = {("lattice", "magcal.ellipsoid_fit"): (0.0005, 0.0006, 0.0002),
        ("lattice", "magbench.ellipsoid"): (0.001, 0.0011, 0.0002),
        ("random", "magcal.ellipsoid_fit"): (0.05, 0.055, 0.05),
        ("random", "magbench.ellipsoid"): (0.001, 0.0011, 0.05),
        ("cap 120 deg", "magcal.ellipsoid_fit"): (0.3, 0.31, 0.25),
        ("cap 120 deg", "magbench.ellipsoid"): (0.0015, 0.0016, 0.25)}


def summary(case=CASE) -> pd.DataFrame:
    rows = []
    for (geometry, tool), (jh, rms, offset) in case.items():
        rows.append({"geometry": geometry, "tool": tool, "n": 200, "failures": 0,
                     "J_h": jh, "J_h_lo": 0.9 * jh, "J_h_hi": 1.1 * jh,
                     "J_T": 0.002, "J_T_lo": 0.0018, "J_T_hi": 0.0022, "J": jh + 0.002,
                     "J_lo": jh, "J_hi": jh + 0.003, "rms_h": rms, "crb_rms_h": 0.001,
                     "rms_T": 0.0021, "crb_rms_T": 0.002, "mean_offset": offset})
    return pd.DataFrame(rows)


def test_table_has_one_row_per_geometry_and_tool_with_both_parts():
    lines = peer_accuracy_lines(summary())
    rows = [ln for ln in lines if ln.startswith("| ") and "---" not in ln][1:]
    assert len(rows) == len(CASE)
    assert rows[0] == ("| lattice | magcal.ellipsoid_fit | 0 | 0.0005 [0.00045, 0.00055] | "
                       "0.002 [0.0018, 0.0022] | 0.0006 / 0.001 | 0.0021 / 0.002 |")
    assert rows[1].startswith("| lattice | magbench Ellipsoid fit |")


def test_explanation_is_computed_from_the_numbers():
    text = lattice_explanation(summary())
    assert "(|mean of the directions| = 0.0002)" in text
    assert "mean J_h is 0.5x that of magbench Ellipsoid fit" in text
    assert "even below the Cramer-Rao floor (0.001)" in text
    assert "on random directions: mean J_h 0.05, 50x magbench's" in text
    assert "on cap 120 deg: mean J_h 0.3, 200x magbench's" in text


def test_explanation_says_above_the_floor_and_is_empty_without_the_peer():
    case = {**CASE, ("lattice", "magcal.ellipsoid_fit"): (0.0012, 0.0013, 0.0002)}
    assert "above the Cramer-Rao floor (0.001)" in lattice_explanation(summary(case))
    no_peer = {k: v for k, v in CASE.items() if k[1] != "magcal.ellipsoid_fit"}
    assert lattice_explanation(summary(no_peer)) == ""
    assert not any("sample mean" in ln for ln in peer_accuracy_lines(summary(no_peer)))


def test_peer_agreement_lines_give_one_verdict_per_pair():
    import numpy as np

    from magbench.report.peer_accuracy import REASONS, peer_agreement_lines

    nums = {"field_rel_median": 1e-16, "field_rel_max": 2e-16, "h_rel_median": 0.0,
            "h_rel_max": 0.0, "T_rel_median": 0.0, "T_rel_max": 0.0,
            "Jr_peer_median": 1e-4, "Jr_magbench_median": 1e-4}
    summary = pd.DataFrame([
        {"peer": "navlib.cal_mag_ellipsoid_fit_fang", "magbench": "fang", "data": "synthetic",
         "n": 3, "n_ok": 3, "status": "ok", **nums},
        {"peer": "navlib.cal_mag_sar_ls", "magbench": "sar_ls", "data": "real", "n": 2,
         "n_ok": 2, "status": "ok", **{**nums, "field_rel_max": 0.5}},
        {"peer": "navlib.cal_mag_magyc_bfg", "magbench": "magyc_bfg", "data": "-", "n": 1,
         "n_ok": 0, "status": "not installed: gtsam", **dict.fromkeys(nums, np.nan)}])
    rows = [line for line in peer_agreement_lines(summary) if line.startswith("| navlib")]
    assert len(rows) == 3
    assert rows[0].endswith("agree within 2e-16 |")
    assert REASONS["navlib.cal_mag_sar_ls"] in rows[1]
    assert rows[2].endswith("not installed: gtsam |")
