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
    ({"field": 0.02}, "FAIL", "from the data's field"),
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


def test_central_spread_leaves_out_one_sided_spikes_but_not_a_disturbed_fifth():
    from magbench.core.geometry import fibonacci_sphere
    from magbench.core.verdict import central_spread_pct

    u = fibonacci_sphere(1000)
    clean = central_spread_pct(u * 2.0)
    assert clean == pytest.approx(0.0, abs=1e-9)
    spiky = u * 2.0
    spiky[::20] *= 10.0                                   # 5 % spikes, all on one side
    assert central_spread_pct(spiky) == pytest.approx(0.0, abs=1e-9)
    disturbed = u * 2.0
    disturbed[::5] *= 1.3                                 # a fifth of the samples 30 % off
    assert central_spread_pct(disturbed) > 10.0


def test_noise_p95_is_the_white_noise_level_whatever_the_turn():
    from magbench.core.verdict import noise_p95_pct

    K, sigma, radius = 20000, 0.5, 50.0
    s = np.linspace(0, 1, K)
    turn = radius * np.column_stack([np.cos(40 * s), np.sin(40 * s), np.zeros(K)])
    y = turn + sigma * np.random.default_rng(0).standard_normal((K, 3))
    assert noise_p95_pct(y, radius) == pytest.approx(100 * 1.96 * sigma / radius, rel=0.05)
    assert np.isnan(noise_p95_pct(y[:5], radius))


def _fit(**kw):
    from magbench.core.verdict import Gate, fitness

    base = dict(p95_pct=2.0, held_out=True, gap_deg=20.0, directions=200, band_deg=90.0,
                field=1.0, radius=1.0)
    return fitness(Gate(), **{**base, **kw})


def test_a_correction_that_hardly_narrows_the_spread_fails():
    assert _fit(spread_pct=(1.0, 5.0))["status"] == "PASS"
    out = _fit(spread_pct=(4.5, 5.0))
    assert out["status"] == "FAIL"
    assert out["reasons"][0].startswith(
        "the correction narrows the field magnitude's spread over the recording by less than "
        "20% (4.5 % against 5.0 % of the field uncorrected)")


def test_a_shortfall_of_quality_warns_when_the_correction_beats_no_correction():
    # field error past the FAIL line, no other data: FAIL
    assert _fit(p95_pct=20.0)["status"] == "FAIL"
    # the same correction narrows the raw spread from 60 % to 8 % of the field: written, WARN
    out = _fit(p95_pct=20.0, spread_pct=(8.0, 60.0))
    assert out["status"] == "WARN" and out["better_than_raw"]
    assert out["reasons"][0] == "field error 20.0 % (p95, held out) > 12 %"
    assert out["reasons"][-1].startswith("written nonetheless: it is clearly better than no "
                                         "correction (field magnitude spread 8.0 % against "
                                         "60.0 % of the field uncorrected)")
    # no better than raw: the guard and the shortfall both FAIL, the guard first
    out = _fit(p95_pct=20.0, spread_pct=(8.0, 9.0))
    assert out["status"] == "FAIL" and not out["better_than_raw"]
    assert out["reasons"][0].startswith("the correction narrows")
    assert out["reasons"][1].startswith("field error 20.0 %")
    # a fit the data do not determine, an unsafe one or a wrong heading is never demoted
    out = _fit(field=2.0, radius=1.0, spread_pct=(1.0, 60.0))
    assert out["status"] == "FAIL" and out["reasons"][0].startswith("fitted field 2 is 100 %")
    for kw, start in ((dict(gap_deg=150.0), "no direction within 150"),
                      (dict(directions=5), "5 distinct directions"),
                      (dict(heading_deg=40.0), "heading error 40.0 deg")):
        out = _fit(p95_pct=20.0, spread_pct=(8.0, 60.0), **kw)
        assert out["status"] == "FAIL" and out["reasons"][0].startswith(start)
        assert out["reasons"][1].startswith("field error 20.0 %")


def test_with_reason_demotes_a_quality_failure_only_when_better_than_raw():
    from magbench.core.verdict import with_reason

    better = _fit(spread_pct=(1.0, 60.0))
    assert with_reason(better, "moved", fail=True, quality=True)["status"] == "WARN"
    assert with_reason(better, "moved", fail=True)["status"] == "FAIL"
    assert with_reason(_fit(), "moved", fail=True, quality=True)["status"] == "FAIL"


def test_a_failed_fit_never_says_it_was_written_nonetheless():
    from magbench.core.verdict import with_reason

    unsafe = _fit(field=2.0, radius=1.0, spread_pct=(1.0, 60.0))
    assert unsafe["status"] == "FAIL" and unsafe["better_than_raw"]
    out = with_reason(unsafe, "moved", fail=True, quality=True)
    assert out["status"] == "FAIL"
    assert out["reasons"][0] == "moved"
    assert not any(r.startswith("written nonetheless") for r in out["reasons"])
    # a shortfall demoted to a WARN, then a failing reason: the note goes with the write
    demoted = with_reason(_fit(spread_pct=(1.0, 60.0)), "moved", fail=True, quality=True)
    assert demoted["status"] == "WARN" and demoted["reasons"][-1].startswith("written")
    out = with_reason(demoted, "a minority state", fail=True)
    assert out["status"] == "FAIL" and out["reasons"] == ["a minority state", "moved"]


def test_central_spread_as_a_share_of_a_given_scale():
    from magbench.core.geometry import fibonacci_sphere
    from magbench.core.verdict import central_spread_pct

    u = fibonacci_sphere(2000)
    y = u * 40.0 + np.array([400.0, 0.0, 0.0])          # an offset ten times the field
    spread = 100 * np.std(np.linalg.norm(y, axis=1))
    own = central_spread_pct(y, share=1.0)
    assert own == pytest.approx(spread / np.mean(np.linalg.norm(y, axis=1)))
    assert central_spread_pct(y, share=1.0, scale=40.0) == pytest.approx(spread / 40.0)
    assert central_spread_pct(y, share=1.0, scale=40.0) > 9 * own


def test_an_error_that_is_the_sensors_noise_warns_instead_of_failing():
    assert _fit(p95_pct=13.0)["status"] == "FAIL"
    noisy = _fit(p95_pct=13.0, noise_p95_pct=10.0)
    assert noisy["status"] == "WARN"
    assert noisy["reasons"][0].startswith("field error 13.0 % (p95) is the sensor's own noise")
    assert _fit(p95_pct=16.0, noise_p95_pct=10.0)["status"] == "FAIL"   # beyond 1.5x noise
