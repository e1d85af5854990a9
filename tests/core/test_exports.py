"""Exports: the JSON schema, the C header and ArduPilot's compass parameters reproduce apply()."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magbench.core.exports import (
    FIRMWARE_FILES,
    GAUGE,
    MotorCompensation,
    ardupilot_param_file,
    ardupilot_params,
    betaflight_cli,
    c_header,
    field_strength,
    firmware_files,
    from_json_dict,
    inav_cli,
    inav_gains,
    px4_param_file,
    px4_params,
    to_json_dict,
)
from magbench.core.model import Calibration
from magbench.core.units import parse_units

MGAUSS = parse_units("mgauss")

FLOAT32 = {"rtol": 2e-6, "atol": 2e-6}


def sensor(scale: float = 450.0, offset=(120.0, -80.0, 40.0), seed: int = 0) -> Calibration:
    """A rotated, mirrored, non-orthogonal T in milligauss (field 450 mGauss)."""
    rng = np.random.default_rng(seed)
    S = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    Q = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix() @ np.diag([1.0, -1.0, 1.0])
    return Calibration(scale * S @ Q, np.array(offset))


def raw_samples(cal: Calibration, K: int = 200, seed: int = 1) -> np.ndarray:
    m = np.random.default_rng(seed).standard_normal((K, 3))
    return (m / np.linalg.norm(m, axis=1)[:, None]) @ cal.T.T + cal.h


def test_json_round_trip_gives_the_safe_calibration():
    cal = sensor()
    data = json.loads(json.dumps(to_json_dict(cal, units="mGauss", columns=["mx", "my", "mz"])))
    assert data["gauge"] == GAUGE and data["version"] == 1 and data["columns"] == ["mx", "my", "mz"]
    back = from_json_dict(data)
    y = raw_samples(cal)
    np.testing.assert_allclose(back.apply(y), cal.safe().apply(y), atol=1e-12)
    np.testing.assert_array_equal(back.h, cal.h)
    np.testing.assert_allclose(np.linalg.norm(back.apply(y), axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d.pop("A"), "lacks 'A'"),
    (lambda d: d.update(b=[1, 2]), r"b must be finite numbers of shape \(3,\)"),
    (lambda d: d.update(A=(-np.array(d["A"])).tolist()), "not symmetric positive definite"),
    (lambda d: d.update(version=3), "schema version 3"),
    (lambda d: d.update(format="other"), "format 'other'"),
])
def test_from_json_dict_names_what_is_wrong(change, message):
    data = to_json_dict(sensor())
    change(data)
    with pytest.raises(ValueError, match=message):
        from_json_dict(data)


def parse_header(text: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    def floats(block: str) -> np.ndarray:
        return np.array([float(v) for v in re.findall(r"(-?[\d.]+(?:e[-+]?\d+)?)f", block)],
                        dtype=np.float32)

    A = re.search(rf"{name}_A\[3\]\[3\] = \{{(.*?)\}};", text, re.S).group(1)
    b = re.search(rf"{name}_b\[3\] = \{{(.*?)\}};", text, re.S).group(1)
    return floats(A).reshape(3, 3), floats(b)


def test_c_header_numbers_reproduce_apply_in_float32():
    cal = sensor()
    text = c_header(cal, "imu_mag", verdict="0.5 % (95th percentile)")
    assert "m = A (y - b), A symmetric positive definite" in text
    assert "(it was a mirror image)" in text and "Verdict: 0.5 %" in text
    A, b = parse_header(text, "imu_mag")
    assert re.search(r"imu_mag_b\[3\] = \{120\.0f, -80\.0f, 40\.0f\}", text)
    y = raw_samples(cal).astype(np.float32)
    np.testing.assert_allclose((y - b) @ A.T, cal.safe().apply(y), **FLOAT32)


def test_c_header_refuses_a_bad_name():
    with pytest.raises(ValueError, match="C identifier"):
        c_header(sensor(), "2bad-name")


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_c_header_compiles_and_runs(tmp_path):
    cal = sensor()
    (tmp_path / "cal.h").write_text(c_header(cal, "mag_cal"))
    y = raw_samples(cal, K=1)[0]
    (tmp_path / "main.c").write_text(
        '#include <stdio.h>\n#include "cal.h"\nint main(void) {\n'
        f"    const float y[3] = {{{y[0]:.9g}f, {y[1]:.9g}f, {y[2]:.9g}f}};\n"
        '    float m[3];\n    mag_cal_apply(y, m);\n'
        '    printf("%.9g %.9g %.9g\\n", m[0], m[1], m[2]);\n    return 0;\n}\n')
    subprocess.run(["cc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-o", "prog", "main.c"],
                   cwd=tmp_path, check=True)
    out = subprocess.run([str(tmp_path / "prog")], capture_output=True, text=True, check=True)
    m = np.array(out.stdout.split(), dtype=float)
    np.testing.assert_allclose(m, cal.safe().apply(y.astype(np.float32)), **FLOAT32)


def parse_params(text: str) -> dict[str, np.float32]:
    pairs = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    return {k: np.float32(v) for k, v in pairs}


def ardupilot_correct(p: dict[str, np.float32], raw: np.ndarray, s: str = "") -> np.ndarray:
    """ArduPilot's correct_field: mag += offsets; mag *= scale; mag = M * mag (float32)."""
    M = np.array([[p[f"COMPASS_DIA{s}_X"], p[f"COMPASS_ODI{s}_X"], p[f"COMPASS_ODI{s}_Y"]],
                  [p[f"COMPASS_ODI{s}_X"], p[f"COMPASS_DIA{s}_Y"], p[f"COMPASS_ODI{s}_Z"]],
                  [p[f"COMPASS_ODI{s}_Y"], p[f"COMPASS_ODI{s}_Z"], p[f"COMPASS_DIA{s}_Z"]]],
                 np.float32)
    ofs = np.array([p[f"COMPASS_OFS{s}_{a}"] for a in "XYZ"], np.float32)
    scaled = (raw.astype(np.float32) + ofs) * p[f"COMPASS_SCALE{s}"]
    return scaled @ M.T


@pytest.mark.parametrize("seed", range(3))
def test_ardupilot_params_reproduce_apply_in_float32(seed):
    cal = sensor(seed=seed)
    params = ardupilot_params(cal, MGAUSS)
    text = ardupilot_param_file(params, "test\nsecond line")
    assert text.startswith("# test\n# second line\nCOMPASS_OFS_X ")
    p = parse_params(text)
    assert p["COMPASS_SCALE"] == 1.0
    np.testing.assert_allclose([p[f"COMPASS_OFS_{a}"] for a in "XYZ"], -cal.h, rtol=1e-7)
    field = field_strength(cal)
    y = raw_samples(cal, seed=seed)
    corrected = ardupilot_correct(p, y)
    np.testing.assert_allclose(corrected / field, cal.safe().apply(y), **FLOAT32)
    # The corrected field keeps the recording's strength in milligauss, as ArduPilot's does.
    np.testing.assert_allclose(np.linalg.norm(corrected, axis=1), field, rtol=1e-5)


@pytest.mark.parametrize(("units", "per_mgauss"), [("gauss", 1e-3), ("uT", 0.1), ("nT", 100.0),
                                                   ("0.0625uT", 1.6), ("counts", None)])
def test_ardupilot_converts_the_recording_unit_to_milligauss(units, per_mgauss):
    cal_mg = sensor()
    p_mg = ardupilot_params(cal_mg, MGAUSS)
    if per_mgauss is None:
        with pytest.raises(ValueError, match=r"^ArduPilot works in milligauss and the "
                           r"recording's unit is counts \(size unknown\): pass units="):
            ardupilot_params(cal_mg, parse_units(units))
        return
    cal = Calibration(cal_mg.T * per_mgauss, cal_mg.h * per_mgauss)
    p = ardupilot_params(cal, parse_units(units))
    assert p.keys() == p_mg.keys()
    np.testing.assert_allclose(list(p.values()), list(p_mg.values()), rtol=1e-12, atol=1e-12)


def test_a_gauss_recording_called_milligauss_is_refused_naming_milligauss():
    cal_g = Calibration(sensor().T / 1000, sensor().h / 1000)
    with pytest.raises(ValueError, match=r"field strength 0\.\d+ mGauss .* \(150, 950\)"):
        ardupilot_params(cal_g, MGAUSS)


@pytest.mark.parametrize(("instance", "suffix"), [(0, ""), (1, "2"), (2, "3")])
def test_ardupilot_second_and_third_compass_have_their_own_names(instance, suffix):
    cal = sensor()
    p = parse_params(ardupilot_param_file(ardupilot_params(cal, MGAUSS, instance=instance)))
    assert sorted(p) == sorted([f"COMPASS_OFS{suffix}_{a}" for a in "XYZ"]
                               + [f"COMPASS_DIA{suffix}_{a}" for a in "XYZ"]
                               + [f"COMPASS_ODI{suffix}_{a}" for a in "XYZ"]
                               + [f"COMPASS_SCALE{suffix}"])
    y = raw_samples(cal)
    np.testing.assert_allclose(ardupilot_correct(p, y, suffix) / field_strength(cal),
                               cal.safe().apply(y), **FLOAT32)
    with pytest.raises(ValueError, match="compasses 0 to 2, got instance 3"):
        ardupilot_params(cal, MGAUSS, instance=3)


@pytest.mark.parametrize(("cal", "message"), [
    (sensor(offset=(2500.0, 0.0, 0.0)), "offset 2500 mGauss exceeds"),
    (Calibration(np.diag([100.0, 100.0, 9000.0]), np.zeros(3)), r"COMPASS_DIA values .*0\.0498"),
    (Calibration(450 * np.array([[1.0, 1.2, 0], [1.2, 2.0, 0], [0, 0, 1.0]]), np.zeros(3)),
     "COMPASS_ODI values"),
])
def test_ardupilot_refuses_values_outside_its_ranges(cal, message):
    with pytest.raises(ValueError, match=message):
        ardupilot_params(cal, MGAUSS)


def parse_qgc(text: str) -> dict[str, np.float32 | int]:
    """QGroundControl's .params rows: vehicle, component, name, value, MAV_PARAM_TYPE."""
    out: dict[str, np.float32 | int] = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        vehicle, component, name, value, kind = line.split("\t")
        assert (vehicle, component) == ("1", "1") and kind in ("6", "9")
        out[name] = int(value) if kind == "6" else np.float32(value)
    return out


def px4_correct(p: dict, raw_gauss: np.ndarray, n: int = 0) -> np.ndarray:
    """PX4's Magnetometer::Correct without rotation: S (raw - offset), float32."""
    d = [p[f"CAL_MAG{n}_{a}SCALE"] for a in "XYZ"]
    o = [p[f"CAL_MAG{n}_{a}ODIAG"] for a in "XYZ"]
    S = np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]], np.float32)
    off = np.array([p[f"CAL_MAG{n}_{a}OFF"] for a in "XYZ"], np.float32)
    return (raw_gauss.astype(np.float32) - off) @ S.T


@pytest.mark.parametrize(("units", "gauss_per_unit"), [("uT", 0.01), ("gauss", 1.0),
                                                       ("0.92mgauss", 0.00092)])
def test_px4_params_reproduce_apply_in_float32(units, gauss_per_unit):
    k = 0.5 / field_strength(sensor()) / gauss_per_unit           # 0.5 gauss in any unit
    cal = Calibration(sensor().T * k, sensor().h * k)
    text = px4_param_file(px4_params(cal, parse_units(units), instance=1, device_id=396809),
                          "from test")
    assert "# Vehicle-Id Component-Id Name Value Type" in text
    assert "1\t1\tCAL_MAG1_ID\t396809\t6" in text and "not set here" not in text
    p = parse_qgc(text)
    y = raw_samples(cal)
    corrected = px4_correct(p, y * gauss_per_unit, n=1)
    F = field_strength(cal) * gauss_per_unit
    np.testing.assert_allclose(F, 0.5, rtol=1e-12)
    np.testing.assert_allclose(corrected / F, cal.safe().apply(y), **FLOAT32)
    np.testing.assert_allclose([p[f"CAL_MAG1_{a}OFF"] for a in "XYZ"], cal.h * gauss_per_unit,
                               rtol=1e-7)


def test_px4_writes_the_rotation_and_says_when_the_id_is_missing():
    text = px4_param_file(px4_params(sensor(), MGAUSS, rotation=2), "x")
    assert "1\t1\tCAL_MAG0_ROT\t2\t6" in text
    assert "# CAL_MAG0_ID is not set here: the slot must already belong to this compass" in text
    with pytest.raises(ValueError, match="compasses 0 to 3"):
        px4_params(sensor(), MGAUSS, instance=4)
    with pytest.raises(ValueError, match=r"^PX4 works in gauss and the recording's unit is "
                       r"unknown:"):
        px4_params(sensor(), parse_units(None))


def inav_correct(text: str, raw: np.ndarray) -> np.ndarray:
    """INAV's compassUpdate: (raw - magzero) * 1024 / maggain in int32 arithmetic."""
    s = dict(re.findall(r"^set (\w+) = (-?\d+)$", text, re.M))
    zero = np.array([int(s[f"magzero_{a}"]) for a in "xyz"])
    gain = np.array([int(s[f"maggain_{a}"]) for a in "xyz"])
    return (raw.astype(np.int32) - zero) * 1024 // gain


def test_inav_and_betaflight_offsets_give_back_calibration_json_up_to_a_count():
    cal = sensor()                          # milligauss figures, taken as raw counts
    counts = parse_units("counts")
    raw = np.round(raw_samples(cal)).astype(np.int32)
    A, b = cal.correction()
    inav = inav_cli(cal, counts, "head")
    assert "holds offsets and per-axis gains only" in inav and inav.rstrip().endswith("save")
    centred = inav_correct(inav, raw)
    gains = np.array(inav_gains(cal), float)
    # INAV applies the diagonal of A up to one overall factor g (gains about 1024) ...
    d = np.diag(A)
    g = np.cbrt(np.prod(d))
    np.testing.assert_allclose(gains, 1024 * g / d, atol=0.5)
    scaled = (raw - b) * 1024 / gains
    assert np.abs(centred - scaled).max() <= 1.0 + 1024 / gains.min()
    # ... and what it cannot hold, A diag(A)^-1 g, applied on top gives back calibration.json's
    # samples up to the rounding of the offsets and the gains.
    rest = A / d[None, :] * g * gains / (1024 * g / d)
    np.testing.assert_allclose(scaled @ rest.T, (raw - b) @ A.T, rtol=1e-12, atol=1e-9)
    assert np.abs(centred @ rest.T - (raw - b) @ A.T).max() <= 2.0 * np.abs(rest).sum(1).max()
    bf = betaflight_cli(cal, counts)
    x, y, z = map(int, re.search(r"^set mag_calibration = (-?\d+),(-?\d+),(-?\d+)$", bf,
                                 re.M).groups())
    np.testing.assert_array_equal([x, y, z], np.round(b))
    assert "holds offsets only" in bf
    with pytest.raises(ValueError, match="raw counts and the recording is in uT"):
        inav_cli(cal, parse_units("uT"))
    with pytest.raises(ValueError, match="int16"):
        betaflight_cli(sensor(offset=(40000.0, 0, 0)), counts)


def test_firmware_files_say_each_reason_once():
    written, refused = firmware_files(sensor(), parse_units(None), comment="v")
    assert written == {}
    assert refused["ardupilot.param"] == refused["px4.params"] and \
        refused["inav.txt"] == refused["betaflight.txt"]
    written, refused = firmware_files(sensor(), parse_units("0.1mgauss"), comment="v")
    # About 45 mGauss: neither autopilot takes it (PX4's file is checked against the same
    # limits), the raw-count files do.
    assert set(written) == set(FIRMWARE_FILES) - {"ardupilot.param", "px4.params"}
    assert "field strength 4" in refused["ardupilot.param"]
    assert "outside PX4's accepted" in refused["px4.params"]
    written, refused = firmware_files(sensor(), MGAUSS, comment="v")
    assert set(written) == {"ardupilot.param", "px4.params"}


def test_heading_true_file_says_so_and_reads_back():
    from scipy.spatial.transform import Rotation

    from magbench.core.exports import GAUGE_HEADING_TRUE

    R = Rotation.from_rotvec([0.02, -0.03, 0.05]).as_matrix()
    T = np.array([[1.1, 0.05, 0.0], [0.0, 0.9, 0.02], [0.0, 0.0, 1.05]])
    cal = Calibration(T, np.array([0.1, -0.2, 0.3]), alignment=R)
    data = json.loads(json.dumps(to_json_dict(cal)))
    assert data["gauge"] == GAUGE_HEADING_TRUE and data["version"] == 2
    A = np.array(data["A"])
    np.testing.assert_allclose(A, R @ np.array(data["S"]), atol=1e-14)
    assert not np.allclose(A, A.T)                    # not the symmetric gauge
    back = from_json_dict(data)
    assert back.gauge == "heading-true"
    np.testing.assert_allclose(back.correction()[0], A, atol=1e-12)
    y = np.array([[0.5, 1.0, -0.3]])
    np.testing.assert_allclose((y - data["b"]) @ A.T, (y - cal.h) @ cal.correction()[0].T,
                               atol=1e-12)
    assert "Heading-true" in c_header(cal)
    bad = dict(data, R=np.diag([1.0, 1.0, -1.0]).tolist())
    with pytest.raises(ValueError, match="proper rotation"):
        from_json_dict(bad)


@pytest.mark.parametrize(("rotation", "instance", "name"), [(6, 0, "COMPASS_ORIENT"),
                                                            (8, 1, "COMPASS_ORIENT2"),
                                                            (38, 2, "COMPASS_ORIENT3")])
def test_ardupilot_with_a_rotation_corrects_in_the_vehicle_axes(rotation, instance, name):
    from magbench.core.mounting import rotation_matrix

    cal = sensor()
    p = parse_params(ardupilot_param_file(ardupilot_params(cal, MGAUSS, instance=instance,
                                                           rotation=rotation)))
    assert p[name] == rotation
    Mr = rotation_matrix(rotation)
    y = raw_samples(cal)
    # ArduPilot turns the raw sample by COMPASS_ORIENT, then corrects it.
    corrected = ardupilot_correct(p, y @ Mr.T, "" if instance == 0 else str(instance + 1))
    np.testing.assert_allclose(corrected / field_strength(cal), cal.safe().apply(y) @ Mr.T,
                               **FLOAT32)
    with pytest.raises(ValueError, match=r"COMPASS_ORIENT, 0 to 43\), got 44"):
        ardupilot_params(cal, MGAUSS, rotation=44)


def test_firmware_files_write_the_rotation_in_both_and_none_without_one():
    written, _ = firmware_files(sensor(), MGAUSS, rotation=6)
    assert "\nCOMPASS_ORIENT 6\n" in written["ardupilot.param"]
    assert "ROTATION_YAW_270" in written["ardupilot.param"]
    assert "1\t1\tCAL_MAG0_ROT\t6\t6" in written["px4.params"]
    plain, _ = firmware_files(sensor(), MGAUSS)
    assert "ORIENT" not in plain["ardupilot.param"] and "_ROT" not in plain["px4.params"]


#: A disturbance of (4, -2, 3) mGauss per ampere in the sensor's axes.
C_PER_AMP = np.array([4.0, -2.0, 3.0])


def compensated_samples(cal: Calibration, u: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Raw samples ``y = T m + h + C u`` of a unit field."""
    return raw_samples(cal, K=len(u)) + u[:, None] * C


def test_motor_compensation_refuses_what_no_firmware_holds():
    with pytest.raises(ValueError, match="per current or throttle, got 'temperature'"):
        MotorCompensation("temperature", C_PER_AMP)
    with pytest.raises(ValueError, match="3 finite numbers"):
        MotorCompensation("current", [1.0, np.nan, 0.0])


@pytest.mark.parametrize(("regressor", "motct", "rotation"), [("current", 2, None),
                                                              ("throttle", 1, None),
                                                              ("current", 2, 6)])
def test_ardupilot_motor_compensation_gives_back_the_time_varying_correction(regressor, motct,
                                                                             rotation):
    from magbench.core.mounting import rotation_matrix

    cal = sensor()
    u = np.linspace(0.0, 20.0 if regressor == "current" else 1.0, 200)
    C = C_PER_AMP * (20.0 if regressor == "throttle" else 1.0)
    y = compensated_samples(cal, u, C)
    p = parse_params(ardupilot_param_file(ardupilot_params(
        cal, MGAUSS, rotation=rotation, motor=MotorCompensation(regressor, C))))
    assert p["COMPASS_MOTCT"] == motct
    Mr = np.eye(3) if rotation is None else rotation_matrix(rotation)
    # correct_field: M (raw + OFS), then + COMPASS_MOT * u (current in A or throttle 0-1).
    mot = np.array([p[f"COMPASS_MOT_{a}"] for a in "XYZ"], np.float32)
    corrected = ardupilot_correct(p, y @ Mr.T) + u[:, None].astype(np.float32) * mot
    expected = cal.safe().apply(y - u[:, None] * C) @ Mr.T
    np.testing.assert_allclose(corrected / field_strength(cal), expected, rtol=1e-5, atol=1e-5)
    # Without the term the field moves by up to 20 A x |C| = 108 mGauss, a quarter of 450.
    static = ardupilot_correct(p, y @ Mr.T)
    assert np.ptp(np.linalg.norm(static, axis=1)) > 50
    assert np.ptp(np.linalg.norm(corrected, axis=1)) < 0.05


def test_ardupilot_refuses_a_motor_term_beyond_its_range():
    with pytest.raises(ValueError, match=r"COMPASS_MOT values .* exceed ArduPilot's range of "
                                         r"\+-1000"):
        ardupilot_params(sensor(), MGAUSS, motor=MotorCompensation("current", [0, 0, 1500.0]))


@pytest.mark.parametrize(("regressor", "comp_typ", "power_per_unit"), [("current", 2, 1e-3),
                                                                       ("throttle", 1, 1.0)])
def test_px4_power_compensation_gives_back_the_time_varying_correction(regressor, comp_typ,
                                                                       power_per_unit):
    cal = Calibration(sensor().T / 1000, sensor().h / 1000)            # gauss
    u = np.linspace(0.0, 20.0 if regressor == "current" else 1.0, 200)
    C = C_PER_AMP / 1000 * (20.0 if regressor == "throttle" else 1.0)
    y = compensated_samples(cal, u, C)
    p = parse_qgc(px4_param_file(px4_params(cal, parse_units("gauss"),
                                            motor=MotorCompensation(regressor, C))))
    assert p["CAL_MAG_COMP_TYP"] == comp_typ
    # Magnetometer::Correct: S ((raw + power COMP) - OFF), power in kA or throttle 0-1.
    comp = np.array([p[f"CAL_MAG0_{a}COMP"] for a in "XYZ"], np.float32)
    power = (u * power_per_unit).astype(np.float32)
    corrected = px4_correct(p, y.astype(np.float32) + power[:, None] * comp)
    expected = cal.safe().apply(y - u[:, None] * C)
    np.testing.assert_allclose(corrected / field_strength(cal), expected, rtol=1e-5, atol=1e-5)


def test_firmware_files_with_a_motor_term_say_where_it_goes():
    written, _ = firmware_files(sensor(), parse_units("counts"), motor=MotorCompensation(
        "current", C_PER_AMP))
    assert set(written) == {"inav.txt", "betaflight.txt"}
    assert all("current term C of calibration.json's time_varying is not applied" in t
               for t in written.values())
    written, _ = firmware_files(sensor(), MGAUSS, motor=MotorCompensation("current", C_PER_AMP))
    assert "+ COMPASS_MOT * u, u the current in A" in written["ardupilot.param"]
    assert "\nCOMPASS_MOTCT 2\n" in written["ardupilot.param"]
    assert "S ((raw + p COMP) - OFF), p the current in kA (while armed)" in written["px4.params"]
    assert "\tCAL_MAG_COMP_TYP\t2\t6" in written["px4.params"]
