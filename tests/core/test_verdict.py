"""The verdict's figures: field error in %, heading error in degrees, coverage warning."""

from __future__ import annotations

import re

import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere, largest_gap
from magbench.core.verdict import (
    MAX_GAP_DEG,
    coverage_report,
    field_error_pct,
    heading_error_deg,
    magnitude_verdict,
)


def test_field_error_known_answers():
    m = np.array([[1.0, 0, 0], [0, 1.02, 0], [0, 0, -0.95]])
    np.testing.assert_allclose(field_error_pct(m), [0.0, 2.0, 5.0], atol=1e-12)


def test_heading_error_known_answers():
    assert heading_error_deg(0.0) == 0.0
    assert heading_error_deg(50.0) == pytest.approx(30.0)                 # asin(0.5)
    assert heading_error_deg(50.0, inclination_deg=60.0) == pytest.approx(90.0)
    assert heading_error_deg(1.0, inclination_deg=60.0) == pytest.approx(
        np.degrees(np.arcsin(0.02)))


def test_magnitude_verdict_percentiles():
    m = fibonacci_sphere(100) * np.linspace(0.99, 1.01, 100)[:, None]
    v = magnitude_verdict(m, held_out=True)
    assert v["held_out"] and v["samples"] == 100
    assert v["field_error_pct"]["max"] == pytest.approx(1.0)
    assert v["field_error_pct"]["p95"] == pytest.approx(0.95, abs=0.02)


@pytest.mark.parametrize(("z_low", "gap"), [(0.0, 90.0), (0.5, 120.0), (-1.0, 0.0)])
def test_largest_gap_of_caps(z_low, gap):
    radius, centre = largest_gap(fibonacci_sphere(3000, z_range=(z_low, 1.0)))
    assert radius == pytest.approx(gap, abs=5.0)
    if z_low > -1:
        assert centre[2] < -0.95


def test_coverage_warns_on_a_60_degree_cap_not_on_a_hemisphere_or_band():
    assert coverage_report(fibonacci_sphere(500))["warning"] is None
    assert coverage_report(fibonacci_sphere(500, z_range=(0.0, 1.0)))["warning"] is None
    assert coverage_report(fibonacci_sphere(500, z_range=(-0.17, 0.17)))["warning"] is None
    cap = coverage_report(fibonacci_sphere(500, z_range=(0.5, 1.0)))
    assert cap["largest_gap_deg"] > MAX_GAP_DEG
    assert re.search(r"coverage is insufficient: .* cap of about 6\d deg", cap["warning"])
    axis = np.array(cap["rotate_about"])
    assert abs(axis[2]) < 0.1                        # any horizontal axis tilts the cap over


GOOD = dict(p95_pct=1.0, held_out=True, gap_deg=20.0, directions=200, band_deg=70.0,
            field=1.0, radius=1.0)


@pytest.mark.parametrize(("change", "status", "words"), [
    ({}, "PASS", ""),
    ({"p95_pct": 7.0}, "WARN", "field error 7.0 % (p95, held out) > 6 %"),
    ({"p95_pct": 41.8}, "FAIL", "> 12 %"),
    ({"gap_deg": 120.0}, "WARN", "within 120 deg"),
    ({"gap_deg": 150.0}, "FAIL", "> 135 deg"),
    ({"directions": 14}, "WARN", "14 distinct directions (< 20)"),
    ({"directions": 8}, "FAIL", "8 distinct directions (< 10)"),
    ({"band_deg": 15.0}, "WARN", "within +-15 deg of one plane"),
    ({"held_out": False}, "WARN", "no held-out score"),
    ({"field": 0.02}, "FAIL", "from the data's radius"),
    ({"expected_field": 1.15}, "WARN", "13 % from the expected 1.15"),
    ({"expected_field": 2.0}, "FAIL", "50 % from the expected 2"),
    ({"expected_field": (0.9, 1.1)}, "PASS", ""),
    ({"expected_field": (1.3, 1.5)}, "FAIL", "expected 1.3-1.5"),
    ({"heading_deg": 3.0}, "PASS", ""),
    ({"heading_deg": float("nan")}, "PASS", ""),
    ({"heading_deg": 12.5}, "WARN", "heading error 12.5 deg RMS (held out, against the "
                                    "attitude) > 10 deg"),
    ({"heading_deg": 41.0}, "FAIL", "> 30 deg"),
])
def test_fitness_statuses_and_reasons(change, status, words):
    from magbench.core.verdict import Gate, fitness

    out = fitness(Gate(), **{**GOOD, **change})
    assert out["status"] == status
    assert (out["reasons"] == []) == (status == "PASS")
    assert all(words in r for r in out["reasons"][:1])


def test_a_failing_reason_comes_before_the_warnings():
    from magbench.core.verdict import Gate, fitness

    out = fitness(Gate(), **{**GOOD, "p95_pct": 7.0, "directions": 5})
    assert out["status"] == "FAIL" and out["reasons"][0].startswith("5 distinct")
