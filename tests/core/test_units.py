"""The units key and an expected field strength: parsing, conversion, one-line refusals."""

from __future__ import annotations

import pytest

from magbench.core.units import UNKNOWN, infer_units, parse_field, parse_units


@pytest.mark.parametrize(("text", "name", "gauss"), [
    ("uT", "uT", 1e-2), ("µT", "uT", 1e-2), ("nT", "nT", 1e-5), ("gauss", "gauss", 1.0),
    ("G", "gauss", 1.0), ("mgauss", "mGauss", 1e-3), ("mG", "mGauss", 1e-3), ("T", "T", 1e4),
    ("counts", "counts", None), (None, "", None),
    ("0.0625uT", "counts", 0.0625e-2), ("0.92 mgauss", "counts", 0.92e-3),
    ("1e-3G", "counts", 1e-3),
])
def test_units_name_and_gauss_per_unit(text, name, gauss):
    units = parse_units(text)
    assert units.name == name
    assert units.gauss == (pytest.approx(gauss, rel=1e-12) if gauss else None)
    assert units.known == (gauss is not None)


def test_units_describe_and_show_the_value_in_the_right_unit():
    assert parse_units("gauss").show(0.532) == "0.532 gauss"
    assert parse_units("0.0625uT").show(800) == "800 counts (0.5 gauss)"
    assert parse_units("counts").show(800) == "800 counts"
    assert parse_units(None).show(0.532) == "0.532 (file units, unit unknown)"
    assert parse_units("0.0625uT").describe() == "counts of 0.0625 uT"


@pytest.mark.parametrize("bad", ["furlongs", "-1uT", "0uT", 3, "mg/s", "1.2.3uT"])
def test_a_bad_unit_is_one_line_naming_what_is_accepted(bad):
    with pytest.raises(ValueError, match=r"^units: .*|^units must be one of uT, nT, gauss") as e:
        parse_units(bad)
    assert "\n" not in str(e.value)


def test_field_strength_converts_into_the_file_unit():
    assert parse_field("48uT", parse_units("gauss")) == pytest.approx(0.48)
    assert parse_field("0.5gauss", parse_units("0.0625uT")) == pytest.approx(800)
    assert parse_field(0.5, parse_units(None)) == 0.5
    assert parse_field(None, parse_units("uT")) is None
    with pytest.raises(ValueError, match="has a unit but the file's unit is unknown:"):
        parse_field("48uT", parse_units(None))
    with pytest.raises(ValueError, match="must be positive"):
        parse_field(-3, parse_units("uT"))
    with pytest.raises(ValueError, match="number with a unit"):
        parse_field("lots", parse_units("uT"))


@pytest.mark.parametrize("text", ["uT", "0.0625uT", "counts", None, "mG"])
def test_units_survive_the_json_round_trip(text):
    from magbench.core.units import Units

    units = parse_units(text)
    assert Units.from_dict(units.to_dict()) == units


def test_the_unit_is_the_one_whose_strength_matches_the_expected_field():
    # 0.5 gauss expected: each unit's number, within 25 %, and nothing for counts or zero.
    assert infer_units(50.0, 0.5) == parse_units("uT")
    assert infer_units(0.55, 0.5) == parse_units("gauss")
    assert infer_units(4.1e4, 0.5) == parse_units("nT")
    assert infer_units(480.0, 0.5).name == "mGauss"
    assert infer_units(5e-5, 0.5).name == "T"
    assert infer_units(70.0, 0.5) is UNKNOWN                # 40 % off every unit
    assert infer_units(0.0, 0.5) is UNKNOWN
    assert infer_units(50.0, 0.5, tol=0.01).known and not infer_units(51.0, 0.5, tol=0.01).known
