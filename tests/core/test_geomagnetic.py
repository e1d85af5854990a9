"""The expected geomagnetic field: IGRF against published model values, parsing, units."""

from __future__ import annotations

import datetime as dt

import pytest

from magbench.core.geomagnetic import (
    Site,
    expected_field,
    parse_date,
    parse_location,
)
from magbench.core.units import infer_units

#: NOAA's published WMM2020 test values (README-WMM-COEFS.txt of the WMM2020 release, "a set
#: of test values"): date, height above the WGS-84 ellipsoid (km), latitude, longitude,
#: inclination (deg), total intensity F (nT), declination (deg). IGRF and WMM are different
#: models of the same main field; they agree to tens of nT and a few hundredths of a degree.
WMM2020 = [
    (dt.date(2020, 1, 1), 66, 14, 143, 13.08, 35847.5, 0.12),
    (dt.date(2020, 1, 1), 18, 0, 21, -26.46, 32745.6, 1.05),
    (dt.date(2020, 7, 2), 6, -36, -137, -52.21, 41630.3, 20.16),
    (dt.date(2020, 7, 2), 63, 26, 81, 40.84, 45914.9, 0.43),
]


@pytest.mark.parametrize(("date", "km", "lat", "lon", "inc", "F", "dec"), WMM2020)
def test_igrf_matches_noaas_published_wmm_values(date, km, lat, lon, inc, F, dec):
    field = expected_field(Site(lat, lon, km * 1e3), date)
    assert field.strength_nT == pytest.approx(F, abs=50.0)
    assert field.inclination_deg == pytest.approx(inc, abs=0.06)
    assert field.declination_deg == pytest.approx(dec, abs=0.06)


def test_parsing_and_its_errors():
    assert parse_location("52.5,13.4") == Site(52.5, 13.4, 0.0)
    assert parse_location("52.5, 13.4, 35") == Site(52.5, 13.4, 35.0)
    assert parse_date("2021-07-08") == dt.date(2021, 7, 8)
    with pytest.raises(ValueError, match="lat,lon"):
        parse_location("52.5")
    with pytest.raises(ValueError, match=r"\[-90, 90\]"):
        parse_location("95,0")
    with pytest.raises(ValueError, match="ISO date"):
        parse_date("8/7/2021")
    with pytest.raises(ValueError, match="1900-2030"):
        parse_date("2042-01-01")


def test_the_unit_of_a_recording_follows_from_its_field_strength():
    # Berlin, where BROAD was recorded: the recordings' |h| is 44 uT.
    expected = expected_field(parse_location("52.51,13.33"), dt.date(2021, 1, 1))
    assert 48_000 < expected.strength_nT < 51_000 and 67 < expected.inclination_deg < 69
    assert expected.strength_gauss == pytest.approx(expected.strength_nT * 1e-5)
    assert infer_units(44.2, expected.strength_gauss).name == "uT"
    assert infer_units(0.49, expected.strength_gauss).name == "gauss"
    assert infer_units(493.0, expected.strength_gauss).name == "mGauss"
    assert not infer_units(1370.0, expected.strength_gauss).known    # raw counts
