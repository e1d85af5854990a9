"""The live-stream parsers: text lines (numbers, headers, MotionCal) and MAVLink messages."""

from __future__ import annotations

import pytest

from magbench.sources.stream import LineParser, Sample, mavlink_sample


def test_three_numbers_any_separator():
    p = LineParser()
    assert p.parse("1.5, -2 ,3e1") == Sample(None, (1.5, -2.0, 30.0))
    assert p.parse(b"4\t5 6\r\n") == Sample(None, (4.0, 5.0, 6.0))
    assert p.parse("7;8;9") == Sample(None, (7.0, 8.0, 9.0))
    assert (p.lines, p.samples, p.garbage, p.units) == (3, 3, 0, None)


def test_four_numbers_are_time_then_field():
    assert LineParser().parse("0.25,1,2,3") == Sample(0.25, (1.0, 2.0, 3.0))


def test_motioncal_raw_and_uni_lines():
    p = LineParser()
    assert p.parse("Raw:10,20,8192,1,2,3,-150,320,455") == Sample(None, (-150.0, 320.0, 455.0))
    assert p.units == "0.1uT" and "MotionCal" in p.form
    q = LineParser()
    assert q.parse("Uni:0.01,0.02,1.0,0,0,0,-15.0,32.0,45.5") == Sample(None, (-15.0, 32.0, 45.5))
    assert q.units == "uT"
    # a broken Raw: line (a byte dropped: 8 numbers) is garbage, not a shifted sample
    assert p.parse("Raw:10,20,8192,1,2,3,-150,320") is None
    assert p.garbage == 1


def test_header_names_the_columns_of_a_csv():
    p = LineParser()
    assert p.parse("t,gx,gy,gz,mx,my,mz,ax") is None
    assert p.parse("0.5,9,9,9,1,2,3,9") == Sample(0.5, (1.0, 2.0, 3.0))
    assert (p.samples, p.garbage) == (1, 0)


def test_garbage_is_counted_and_skipped():
    p = LineParser()
    lines = ["", "hello", "1,2", "1,2,x", "nan,1,2", "1,2,inf", "\x00\x00", "1,2,3",
             "2,3", "4,5,6,7", "5,6,7"]
    got = [p.parse(line) for line in lines]
    assert [g for g in got if g is not None] == [Sample(None, (1.0, 2.0, 3.0)),
                                                 Sample(None, (5.0, 6.0, 7.0))]
    # blank lines are not garbage; once lines of three gave a sample, other counts are broken
    assert p.garbage == 7 and p.lines == 9


def test_wide_lines_need_columns():
    p = LineParser()
    assert p.parse("1,2,3,4,5,6,7,8,9") is None
    assert "columns=" in p.why_none()
    q = LineParser(columns=[6, 7, 8])
    assert q.parse("1,2,3,4,5,6,7,8,9") == Sample(None, (7.0, 8.0, 9.0))


class _Msg:
    def __init__(self, kind: str, **fields: float) -> None:
        self.kind = kind
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self.kind


@pytest.mark.parametrize(("kind", "instance", "unit"), [
    ("SCALED_IMU", 0, "mgauss"), ("SCALED_IMU2", 1, "mgauss"), ("SCALED_IMU3", 2, "mgauss")])
def test_scaled_imu_carries_one_compass_each(kind, instance, unit):
    msg = _Msg(kind, time_boot_ms=1500, xmag=100, ymag=-200, zmag=300)
    sample, got_kind, got_unit = mavlink_sample(msg, instance)
    assert sample == Sample(1.5, (100.0, -200.0, 300.0))
    assert (got_kind, got_unit) == (kind, unit)
    assert mavlink_sample(msg, (instance + 1) % 3) is None


def test_raw_and_highres_use_their_id_and_skip_absent_compasses():
    raw = _Msg("RAW_IMU", time_usec=2_000_000, xmag=1, ymag=2, zmag=3, id=1)
    assert mavlink_sample(raw, 0) is None
    assert mavlink_sample(raw, 1)[0] == Sample(2.0, (1.0, 2.0, 3.0))
    assert mavlink_sample(raw, 1)[2] is None            # raw units: not stated
    hi = _Msg("HIGHRES_IMU", time_usec=1_000_000, xmag=0.2, ymag=0.1, zmag=-0.4,
              fields_updated=0b111)                       # accelerometer only: no new field
    assert mavlink_sample(hi, 0) is None
    hi.fields_updated = 0b111 << 6
    assert mavlink_sample(hi, 0)[1:] == ("HIGHRES_IMU", "gauss")
    zero = _Msg("SCALED_IMU", time_boot_ms=0, xmag=0, ymag=0, zmag=0)
    assert mavlink_sample(zero, 0) is None
    assert mavlink_sample(_Msg("ATTITUDE"), 0) is None
