import pandas as pd

from magbench.report.efficiency import efficiency_section, efficiency_table, efficiency_verdicts

#: method -> (efficiency, low, high) at K = 300 and K = 10000.
CASE = {"twostep": [(1.0, 0.95, 1.05), (0.70, 0.65, 0.75)],
        "magical": [(1.0, 0.95, 1.05), (0.94, 0.91, 0.97)],
        "ellipsoid": [(1.0, 0.95, 1.05), (0.93, 0.90, 0.96)],
        "fang": [(0.99, 0.94, 1.04), (0.78, 0.74, 0.82)],
        "als": [(1.0, 0.95, 1.05), (0.99, 0.95, 1.04)]}


def frame(case=CASE) -> pd.DataFrame:
    rows = [{"K": K, "sigma": 0.005, "algorithm": name, "n": 200, "n_meaningful": 200,
             "efficiency": e, "eff_lo": lo, "eff_hi": hi}
            for name, cells in case.items()
            for K, (e, lo, hi) in zip((300, 10000), cells, strict=True)]
    return pd.DataFrame(rows)


def test_table_has_one_row_per_method_and_one_column_per_K():
    lines = efficiency_table(frame()).splitlines()
    assert lines[0] == "| method | K = 300 | K = 10000 |"
    assert len(lines) == 2 + len(CASE)
    assert "| TWOSTEP | 1 [0.95, 1.05] | 0.7 [0.65, 0.75] |" in lines


def test_verdicts_sort_methods_by_their_interval_at_the_largest_K():
    text = efficiency_verdicts(frame())
    assert "At K = 10000, 1 of 5 methods stay within their interval of 1: ALS ellipsoid." in text
    assert "Below 0.9: TWOSTEP 0.7, Fang 0.78." in text
    assert "above 0.9: MAG.I.C.AL, Ellipsoid fit." in text
    assert "ALS stays on the floor and the algebraic fits leave it" in text
    assert "Fang 0.99 -> 0.78 [0.74, 0.82]" in text


def test_verdict_says_when_als_leaves_the_floor_too():
    case = {**CASE, "als": [(1.0, 0.95, 1.05), (0.8, 0.75, 0.85)]}
    assert "ALS is below the floor too" in efficiency_verdicts(frame(case))


def test_section_is_empty_without_the_sweep_and_rendered_with_it(tmp_path):
    assert efficiency_section(tmp_path) == ""
    (tmp_path / "largeK").mkdir()
    frame().to_csv(tmp_path / "largeK" / "efficiency.csv", index=False)
    text = efficiency_section(tmp_path)
    assert text.startswith("## Large K: who stays on the Cramer-Rao floor")
    assert "| ALS ellipsoid |" in text and "Kukush" in text
