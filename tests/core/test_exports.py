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
    GAUGE,
    ardupilot_param_file,
    ardupilot_params,
    c_header,
    from_json_dict,
    to_json_dict,
)
from magbench.core.model import Calibration

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


def ardupilot_correct(p: dict[str, np.float32], raw: np.ndarray) -> np.ndarray:
    """ArduPilot's correct_field: mag += offsets; mag *= scale; mag = M * mag (float32)."""
    M = np.array([[p["COMPASS_DIA_X"], p["COMPASS_ODI_X"], p["COMPASS_ODI_Y"]],
                  [p["COMPASS_ODI_X"], p["COMPASS_DIA_Y"], p["COMPASS_ODI_Z"]],
                  [p["COMPASS_ODI_Y"], p["COMPASS_ODI_Z"], p["COMPASS_DIA_Z"]]], np.float32)
    ofs = np.array([p[f"COMPASS_OFS_{a}"] for a in "XYZ"], np.float32)
    scaled = (raw.astype(np.float32) + ofs) * p["COMPASS_SCALE"]
    return scaled @ M.T


@pytest.mark.parametrize("seed", range(3))
def test_ardupilot_params_reproduce_apply_in_float32(seed):
    cal = sensor(seed=seed)
    params = ardupilot_params(cal)
    text = ardupilot_param_file(params, "test\nsecond line")
    assert text.startswith("# test\n# second line\nCOMPASS_OFS_X ")
    p = parse_params(text)
    assert p["COMPASS_SCALE"] == 1.0
    np.testing.assert_allclose([p[f"COMPASS_OFS_{a}"] for a in "XYZ"], -cal.h, rtol=1e-7)
    field = float(np.cbrt(abs(np.linalg.det(cal.T))))
    y = raw_samples(cal, seed=seed)
    corrected = ardupilot_correct(p, y)
    np.testing.assert_allclose(corrected / field, cal.safe().apply(y), **FLOAT32)
    # The corrected field keeps the recording's strength in milligauss, as ArduPilot's does.
    np.testing.assert_allclose(np.linalg.norm(corrected, axis=1), field, rtol=1e-5)


def test_ardupilot_units_conversion_from_gauss():
    cal_mg = sensor()
    cal_g = Calibration(cal_mg.T / 1000, cal_mg.h / 1000)
    with pytest.raises(ValueError, match=r"field strength 0\.\d+ mGauss .* \(150, 950\)"):
        ardupilot_params(cal_g)
    p_g = ardupilot_params(cal_g, mgauss_per_unit=1000.0)
    p_mg = ardupilot_params(cal_mg)
    assert p_g.keys() == p_mg.keys()
    np.testing.assert_allclose(list(p_g.values()), list(p_mg.values()), rtol=1e-12)


@pytest.mark.parametrize(("cal", "message"), [
    (sensor(offset=(2500.0, 0.0, 0.0)), "offset 2500 mGauss exceeds"),
    (Calibration(np.diag([100.0, 100.0, 9000.0]), np.zeros(3)), r"COMPASS_DIA values .*0\.0498"),
    (Calibration(450 * np.array([[1.0, 1.2, 0], [1.2, 2.0, 0], [0, 0, 1.0]]), np.zeros(3)),
     "COMPASS_ODI values"),
])
def test_ardupilot_refuses_values_outside_its_ranges(cal, message):
    with pytest.raises(ValueError, match=message):
        ardupilot_params(cal)


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
