"""Hand-made summaries for the report's tests: one row per (method, swept value)."""

from __future__ import annotations

import pandas as pd

from magbench.report.baseline import REVIEW

NOMINAL = {"K": 300, "sigma": 0.005, "beta": 0.05, "gamma": 0.05, "cap_deg": 180.0,
           "band_deg": 90.0}


def summary(x: str, values: list, table: dict[str, dict[str, list]], floor=None) -> pd.DataFrame:
    """A summary.csv-like frame: table[method][column] lists one value per swept value."""
    rows = []
    for name, cols in table.items():
        for i, v in enumerate(values):
            row = {**NOMINAL, x: v, "algorithm": name, "n": 10}
            row.update({c: vals[i] for c, vals in cols.items()})
            row["tau_s"] = 1 / row["speed_hz"]
            row["crb_accuracy"] = floor[i] if floor else 400.0
            row["efficiency"] = 1.0
            rows.append(row)
    return pd.DataFrame(rows)


def gamma_case(magical_rb=100.0, speed_magical=(300, 300, 100)) -> pd.DataFrame:
    values = [0.05, 0.25, 1.0]
    table = {n: {"RB_pct": [100, 100, 95], "accuracy": [400, 400, 400],
                 "speed_hz": [500, 500, 500]} for n in REVIEW}
    table["magical"] = {"RB_pct": [100, 100, magical_rb], "accuracy": [400, 400, 400],
                        "speed_hz": list(speed_magical)}
    table["ali"]["RB_pct"] = [100, 100, 100]
    table["twostep"] = {"RB_pct": [100, 90, 80], "accuracy": [40, 40, 40],
                        "speed_hz": [500, 500, 500]}
    table["wu_shi"]["RB_pct"] = [100, 90, 85]
    table["crassidis"] = {"RB_pct": [100, 100, 50], "accuracy": [100, 50, 10],
                          "speed_hz": [500, 500, 500]}
    table["dorveaux"]["RB_pct"] = [100, 100, 60]
    return summary("gamma", values, table)


def verdicts(checks):
    return [c.verdict for c in checks]


def rb_sweep(x: str, values: list, rb: dict[str, list[float]], n: int = 250) -> pd.DataFrame:
    """A summary of RB % only (n runs per point), the other review methods at 100 %."""
    table = {name: {"RB_pct": rb.get(name, [100.0] * len(values)),
                    "accuracy": [400.0] * len(values), "speed_hz": [500.0] * len(values)}
             for name in REVIEW}
    s = summary(x, values, table)
    s["n"] = n
    s["n_meaningful"] = (s["RB_pct"] * n / 100).round().astype(int)
    return s
