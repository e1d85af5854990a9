"""Flight-log readers: logs written with known content (two compasses at unequal rates, a gap
in the attitude, streams that start late), and the shared PX4 sample logs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from magbench.core.quaternions import matrix_to_quat
from magbench.core.rotations import euler_zyx_to_matrix
from magbench.sources.logs import MIN_LOG_SAMPLES, Stream, align, read_log
from magbench.sources.recordings import log_recording, read_samples
from tests.sources.log_writers import write_dataflash, write_ulog

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "logs"
SHARED_LOGS = sorted(Path("/work/shared/data/logs").glob("*.ulg")) or sorted(
    SHARED.glob("*.ulg"))

#: Compass 0 at 20 Hz from 0.2 s, compass 1 at 10 Hz from 1 s, both to 6 s.
T0 = np.round(np.arange(0.2, 6.0, 0.05), 6)
T1 = np.round(np.arange(1.0, 6.0, 0.1), 6)
#: The IMU (50 Hz) starts at 0.5 s, so compass 0's first samples have no gyro.
T_IMU = np.round(np.arange(0.5, 7.0, 0.02), 6)
#: The attitude (25 Hz) has a gap from 3 to 4 s.
T_ATT = np.round(np.array([t for t in np.arange(0.5, 7.0, 0.04) if not 3.0 < t < 4.0]), 6)
T_BAT = np.round(np.arange(0.0, 7.0, 0.2), 6)


def mag0(t):
    return np.column_stack([100 + 10 * t, -50 + 5 * t, 300 - 2 * t])


def mag1(t):
    return np.column_stack([1000 + t, 2 * t, -t])


def gyro(t):
    return np.column_stack([0.01 * t, -0.02 * t, 0.03 + 0 * t])


def accel(t):
    return np.column_stack([0.1 * t, 0 * t, -9.8 + 0 * t])


def yaw_deg(t):
    return 10.0 * t


def euler_zyx_to_quaternion(roll, pitch, yaw):
    """Scalar-first quaternion of ``Rz(yaw) Ry(pitch) Rx(roll)`` (w >= 0)."""
    return matrix_to_quat(euler_zyx_to_matrix(roll, pitch, yaw))


def us(t: float) -> int:
    return round(t * 1e6)


def px4_log(path: Path) -> Path:
    f = "float"
    mag_fields = [("uint64_t", "timestamp"), ("uint32_t", "device_id"), (f, "x"), (f, "y"),
                  (f, "z"), (f, "temperature")]
    q = euler_zyx_to_quaternion(0 * T_ATT, 0 * T_ATT, np.deg2rad(yaw_deg(T_ATT)))
    pairs0, pairs1 = zip(T0, mag0(T0), strict=True), zip(T1, mag1(T1), strict=True)
    topics = [
        ("sensor_mag", 0, mag_fields, [(us(t), 11, *v, 20 + t) for t, v in pairs0]),
        ("sensor_mag", 1, mag_fields, [(us(t), 22, *v, 30.0) for t, v in pairs1]),
        ("sensor_combined", 0, [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"),
                                ("int32_t", "accelerometer_timestamp_relative"),
                                ("float[3]", "accelerometer_m_s2")],
         [(us(t), list(g), 0, list(a))
          for t, g, a in zip(T_IMU, gyro(T_IMU), accel(T_IMU), strict=True)]),
        ("vehicle_attitude", 0, [("uint64_t", "timestamp"), ("float[4]", "q")],
         [(us(t), list(v)) for t, v in zip(T_ATT, q, strict=True)]),
        ("battery_status", 0, [("uint64_t", "timestamp"), (f, "current_a")],
         [(us(t), 2 * t) for t in T_BAT]),
        ("actuator_controls_0", 0, [("uint64_t", "timestamp"), ("float[8]", "control")],
         [(us(t), [0, 0, 0, 0.1 * t, 0, 0, 0, 0]) for t in T_BAT]),
    ]
    return write_ulog(path, topics)


OFS = np.array([5.0, -5.0, 2.0])
MOT = np.array([1.0, 1.0, 1.0])


def ardupilot_log(path: Path, binary: bool) -> Path:
    mag_cols = "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ"
    mags = [(us(t), i, *(v + OFS + MOT), *OFS, *MOT)
            for i, (times, truth) in enumerate(((T0, mag0), (T1, mag1)))
            for t, v in zip(times, truth(times), strict=True)]
    messages = {
        "MAG": ("QBfffffffff", mag_cols, mags),
        "IMU": ("QBfffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T",
                [(us(t), i, *g, *a, 20 + t) for i in (0, 1) for t, g, a in
                 zip(T_IMU, gyro(T_IMU) + i, accel(T_IMU), strict=True)]),
        "ATT": ("Qfff", "TimeUS,Roll,Pitch,Yaw", [(us(t), 0.0, 0.0, yaw_deg(t)) for t in T_ATT]),
        "BAT": ("QBf", "TimeUS,Inst,Curr", [(us(t), i, 2 * t + 100 * i) for t in T_BAT
                                           for i in (0, 1)]),
        "CTUN": ("Qf", "TimeUS,ThO", [(us(t), 0.1 * t) for t in T_BAT]),
    }
    return write_dataflash(path, messages, binary)


def written(kind: str, tmp_path: Path) -> Path:
    if kind == "ulog":
        return px4_log(tmp_path / "flight.ulg")
    pytest.importorskip("pymavlink")
    return ardupilot_log(tmp_path / ("flight.bin" if kind == "bin" else "flight.log"),
                         binary=kind == "bin")


KINDS = ["ulog", "log", "bin"]


@pytest.mark.parametrize("kind", KINDS)
def test_two_compasses_listed_and_each_read_at_its_own_rate(kind, tmp_path):
    log = read_log(written(kind, tmp_path))
    assert sorted(log.mags) == [0, 1]
    assert [len(log.mags[i].t) for i in (0, 1)] == [len(T0), len(T1)]
    with pytest.raises(ValueError, match=r"has 2 compasses; choose one with instance=N: 0 "
                                         r"\(.*116 samples\), 1 \(.*50 samples\)"):
        log.choose(None)
    with pytest.raises(ValueError, match="no compass instance 5; instances: 0"):
        log.choose(5)
    for instance, truth, times in ((0, mag0, T0), (1, mag1, T1)):
        table = log.table(instance)
        np.testing.assert_allclose(table["t"], times, atol=1e-6)
        np.testing.assert_allclose(table[["mx", "my", "mz"]], truth(times), rtol=1e-5)


@pytest.mark.parametrize("kind", KINDS)
def test_streams_interpolated_onto_compass_times_with_gaps_left_empty(kind, tmp_path):
    table = read_log(written(kind, tmp_path)).table(0)
    t = table["t"].to_numpy()
    assert list(table.columns) == ["t", "mx", "my", "mz", "gx", "gy", "gz", "ax", "ay", "az",
                                   "qw", "qx", "qy", "qz", "current", "throttle",
                                   "temperature"]
    late = t < 0.5                       # before the IMU and the attitude started
    assert late.sum() == 6 and table.loc[late, ["gx", "ax", "qw"]].isna().all().all()
    np.testing.assert_allclose(table.loc[~late, ["gx", "gy", "gz"]], gyro(t[~late]),
                               rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(table.loc[~late, ["ax", "ay", "az"]], accel(t[~late]),
                               rtol=1e-5, atol=1e-6)
    gap = (t > T_ATT[T_ATT < 3].max()) & (t < T_ATT[T_ATT > 4].min())
    assert table.loc[gap, ["qw", "qx", "qy", "qz"]].isna().all().all()
    fine = ~late & ~gap
    q = euler_zyx_to_quaternion(0 * t[fine], 0 * t[fine], np.deg2rad(yaw_deg(t[fine])))
    np.testing.assert_allclose(table.loc[fine, ["qw", "qx", "qy", "qz"]], q, atol=1e-4)
    np.testing.assert_allclose(table["current"], 2 * t, rtol=1e-5)     # instance 0's battery
    np.testing.assert_allclose(table["throttle"], 0.1 * t, rtol=1e-5, atol=1e-7)
    # PX4: the compass's own temperature; ArduPilot: the IMU's (none before the IMU starts).
    temp = table["temperature"].to_numpy()
    np.testing.assert_allclose(temp[~late], 20 + t[~late], rtol=1e-5)


@pytest.mark.parametrize("kind", KINDS)
def test_recording_of_one_instance_drops_samples_without_gyro(kind, tmp_path):
    path = written(kind, tmp_path)
    with pytest.warns(UserWarning, match="dropped 6 of 116 compass samples with no gyro"):
        rec = read_samples(path, instance=0, check=False)
    assert rec.K == 110 and rec.has_gyro and rec.columns == ("mx", "my", "mz")
    np.testing.assert_allclose(rec.y, mag0(rec.t), rtol=1e-5)
    assert list(rec.extra) == ["ax", "ay", "az", "qw", "qx", "qy", "qz", "current",
                               "throttle", "temperature"]
    half = rec.rows(slice(0, 10))
    assert all(len(v) == 10 for v in half.extra.values())
    assert half.extra["current"][3] == rec.extra["current"][3]


def test_dataflash_compass_is_the_logged_field_less_offsets(tmp_path):
    """MagX..Z carries the firmware's offsets and motor offsets; the reader removes both."""
    pytest.importorskip("pymavlink")
    log = read_log(ardupilot_log(tmp_path / "flight.log", binary=False))
    np.testing.assert_allclose(log.mags[0].values, mag0(T0), rtol=1e-6)
    assert log.units == "milligauss"


def test_too_short_streams_are_refused_with_their_counts(tmp_path):
    t = np.arange(8) * 0.1
    path = write_ulog(tmp_path / "short.ulg", [
        ("sensor_mag", i, [("uint64_t", "timestamp"), ("float", "x"), ("float", "y"),
                           ("float", "z")], [(us(s), 0.2, 0.1, 0.4) for s in t[: 6 + i]])
        for i in (0, 1)])
    with pytest.raises(ValueError, match=rf"streams are too short to calibrate: 6 and 7 samples "
                                         rf"\(instances 0, 1\); at least {MIN_LOG_SAMPLES}"):
        log_recording(path)
    assert read_samples(path, instance=1, check=False, min_samples=1).K == 7


def test_align_nlerp_takes_the_shorter_arc_and_stays_unit():
    """A quaternion stream whose sign flips between samples interpolates as if it did not."""
    q0 = np.array([1.0, 0, 0, 0])
    q1 = -euler_zyx_to_quaternion(0.0, 0.0, 0.2)            # same attitude, opposite sign
    out = align(np.array([0.5]), Stream(np.array([0.0, 1.0]), np.stack([q0, q1])),
                quaternion=True)
    np.testing.assert_allclose(out[0], euler_zyx_to_quaternion(0.0, 0.0, 0.1), atol=1e-3)
    assert np.isclose(np.linalg.norm(out[0]), 1.0)


@pytest.mark.skipif(not SHARED_LOGS, reason="the shared sample logs are not here")
@pytest.mark.parametrize("path", SHARED_LOGS, ids=lambda p: p.name)
def test_shared_px4_logs_read_and_refused_as_too_short(path):
    log = read_log(path)
    counts = {i: len(s.t) for i, s in log.mags.items()}
    assert counts in ({0: 6, 1: 6}, {0: 11, 1: 11}) and log.units == "gauss"
    table = log.table(1)
    assert {"gx", "ax", "qw", "throttle"} <= set(table.columns)
    norms = np.linalg.norm(table[["mx", "my", "mz"]], axis=1)
    assert ((norms > 0.2) & (norms < 0.8)).all()         # the Earth's field in gauss
    q = table[["qw", "qx", "qy", "qz"]].dropna().to_numpy()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    with pytest.raises(ValueError, match=f"too short to calibrate: {counts[0]} and "):
        read_samples(path)


def test_older_dataflash_logs_name_the_second_compass_mag2(tmp_path):
    """Before the instance field, ArduPilot logged MAG, MAG2 and MAG3."""
    pytest.importorskip("pymavlink")
    cols = "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ"
    rows0 = [(us(t), *v, 0.0, 0.0, 0.0) for t, v in zip(T0, mag0(T0), strict=True)]
    rows1 = [(us(t), *v, 0.0, 0.0, 0.0) for t, v in zip(T1, mag1(T1), strict=True)]
    path = write_dataflash(tmp_path / "old.log", {"MAG": ("Qffffff", cols, rows0),
                                                  "MAG2": ("Qffffff", cols, rows1)},
                           binary=False)
    log = read_log(path)
    assert sorted(log.mags) == [0, 1] and not log.streams
    np.testing.assert_allclose(log.table(1)[["mx", "my", "mz"]], mag1(T1), rtol=1e-6)


@pytest.mark.parametrize("suffix", [".ulg", ".bin"])
def test_a_file_that_is_not_a_log_is_one_error(suffix, tmp_path, capsys):
    if suffix == ".bin":
        pytest.importorskip("pymavlink")
    path = tmp_path / f"junk{suffix}"
    path.write_bytes(b"this is not a flight log\n" * 10)
    expected = {".ulg": "junk.ulg: cannot read as ULog (Invalid file format",
                ".bin": "junk.bin: not a DataFlash log (no valid message header"}[suffix]
    with pytest.raises(ValueError, match=re.escape(expected)) as caught:
        read_log(path)
    assert "\n" not in str(caught.value)
    said = capsys.readouterr()
    assert said.out == said.err == ""                # the reader's own chatter held back


def test_log_units_by_firmware():
    from magbench.sources.logs import log_units

    assert log_units("a.ulg") == "gauss"
    assert log_units("a.BIN") == log_units("a.log") == "milligauss"
