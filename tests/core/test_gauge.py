"""The safe gauge: ``m = A (y - b)`` with A symmetric positive definite, rotation removed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magbench.core.gauge import removed_rotation, rotation_angle_deg, safe_gauge, symmetric_T
from magbench.core.model import Calibration, CalibrationFailed

MIRROR = np.diag([1.0, 1.0, -1.0])


def random_orthogonal(rng: np.random.Generator) -> np.ndarray:
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    return Q * np.sign(np.diag(R))


def distorted(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    return np.eye(3) + 0.2 * rng.standard_normal((3, 3)), rng.standard_normal(3)


@pytest.mark.parametrize("seed", range(5))
def test_corrected_norms_equal_those_of_the_methods_own_T(seed):
    rng = np.random.default_rng(seed)
    T, h = distorted(rng)
    y = rng.standard_normal((100, 3)) * 3
    g = safe_gauge(T, h)
    own = np.linalg.solve(T, (y - h).T).T
    np.testing.assert_allclose(np.linalg.norm((y - g.b) @ g.A.T, axis=1),
                               np.linalg.norm(own, axis=1), rtol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_A_is_symmetric_positive_definite_even_for_a_mirrored_T(seed):
    rng = np.random.default_rng(seed)
    T, h = distorted(rng)
    for candidate in (T, T @ MIRROR):
        A = safe_gauge(candidate, h).A
        np.testing.assert_array_equal(A, A.T)
        assert np.linalg.eigvalsh(A).min() > 0 and np.linalg.det(A) > 0


def test_rotated_and_mirrored_T_give_the_same_A_and_the_flag():
    rng = np.random.default_rng(7)
    S = np.array([[1.2, 0.1, 0.0], [0.1, 0.9, 0.05], [0.0, 0.05, 1.1]])   # symmetric, SPD
    h = rng.standard_normal(3)
    Q = Rotation.from_rotvec(np.radians(38.8) * np.array([0.0, 0.6, 0.8])).as_matrix()
    plain, rotated, mirrored = (safe_gauge(S, h), safe_gauge(S @ Q, h),
                                safe_gauge(S @ Q @ MIRROR, h))
    np.testing.assert_allclose(rotated.A, plain.A, atol=1e-13)
    np.testing.assert_allclose(mirrored.A, plain.A, atol=1e-13)
    np.testing.assert_allclose(plain.A, np.linalg.inv(S), atol=1e-13)
    assert plain.rotation_deg == pytest.approx(0.0, abs=1e-6) and not plain.mirrored
    assert rotated.rotation_deg == pytest.approx(38.8, abs=1e-9) and not rotated.mirrored
    assert mirrored.mirrored and not rotated.mirrored


@pytest.mark.parametrize("seed", range(10))
def test_A_is_invariant_to_any_orthogonal_factor(seed):
    rng = np.random.default_rng(100 + seed)
    T, h = distorted(rng)
    Q = random_orthogonal(rng)
    np.testing.assert_allclose(safe_gauge(T @ Q, h).A, safe_gauge(T, h).A, atol=1e-12)


def test_removed_rotation_recovers_the_inverse():
    rng = np.random.default_rng(3)
    T, _ = distorted(rng)
    R = removed_rotation(T)
    np.testing.assert_allclose(R @ safe_gauge(T, np.zeros(3)).A, np.linalg.inv(T), atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(symmetric_T(T) @ safe_gauge(T, np.zeros(3)).A, np.eye(3),
                               atol=1e-12)


def test_rotation_angle_known_answers():
    assert rotation_angle_deg(np.eye(3)) == 0.0
    assert rotation_angle_deg(-np.eye(3)) == 0.0                  # pure inversion
    Rz = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    assert rotation_angle_deg(Rz) == pytest.approx(90.0)
    assert rotation_angle_deg(-Rz) == pytest.approx(90.0)


@pytest.mark.parametrize(("T", "message"), [
    (np.diag([1.0, 1.0, 0.0]), "T is singular"),
    (np.full((3, 3), np.nan), "T is not finite"),
])
def test_singular_or_nan_T_is_refused(T, message):
    with pytest.raises(ValueError, match=message):
        safe_gauge(T, np.zeros(3))
    with pytest.raises(CalibrationFailed, match=message):
        Calibration(T, np.zeros(3)).correction()


def test_calibration_correction_and_safe_agree_with_apply_norms():
    rng = np.random.default_rng(11)
    T, h = distorted(rng)
    cal = Calibration(T @ MIRROR, h)
    y = rng.standard_normal((20, 3))
    A, b = cal.correction()
    safe = cal.safe()
    np.testing.assert_allclose(safe.apply(y), (y - b) @ A.T, atol=1e-12)
    np.testing.assert_allclose(safe.T, safe.T.T, atol=0)
    assert np.linalg.det(safe.T) > 0
    np.testing.assert_allclose(np.linalg.norm(safe.apply(y), axis=1),
                               np.linalg.norm(cal.apply(y), axis=1), rtol=1e-12)


def test_to_dict_from_dict_round_trip_through_json_is_exact():
    rng = np.random.default_rng(5)
    T, h = distorted(rng)
    for bias in (None, rng.standard_normal(3) * 1e-3):
        cal = Calibration(T, h, 7, False, "stopped at cap", bias)
        back = Calibration.from_dict(json.loads(json.dumps(cal.to_dict())))
        np.testing.assert_array_equal(back.T, cal.T)
        np.testing.assert_array_equal(back.h, cal.h)
        assert (back.n_iter, back.converged, back.message) == (7, False, "stopped at cap")
        if bias is None:
            assert back.gyro_bias is None
        else:
            np.testing.assert_array_equal(back.gyro_bias, bias)


def test_from_dict_names_what_is_missing():
    with pytest.raises(ValueError, match="lacks h"):
        Calibration.from_dict({"T": np.eye(3).tolist()})


# --- The heading-true gauge: A = R S with the alignment R known ------------------------------

def small_rotation(rng: np.random.Generator, deg: float = 3.0) -> np.ndarray:
    axis = rng.standard_normal(3)
    return Rotation.from_rotvec(np.deg2rad(deg) * axis / np.linalg.norm(axis)).as_matrix()


@pytest.mark.parametrize("seed", range(3))
def test_heading_true_correction_is_R_times_the_symmetric_one(seed):
    rng = np.random.default_rng(seed)
    T, h = distorted(rng)
    R = small_rotation(rng)
    sym = safe_gauge(T, h)
    aligned = safe_gauge(T, h, R)
    assert sym.label == "symmetric" and aligned.label == "heading-true"
    np.testing.assert_allclose(aligned.A, R @ sym.A, rtol=0, atol=1e-14)
    cal = Calibration(T, h, alignment=R)
    assert cal.gauge == "heading-true" and Calibration(T, h).gauge == "symmetric"
    A, _ = cal.correction()
    np.testing.assert_allclose(A, R @ sym.A, rtol=0, atol=1e-14)
    # safe() keeps the alignment (it is defined relative to the symmetric gauge).
    np.testing.assert_allclose(cal.safe().correction()[0], A, rtol=0, atol=1e-13)
    back = Calibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    np.testing.assert_array_equal(back.alignment, cal.alignment)


def test_an_alignment_must_be_a_proper_rotation():
    with pytest.raises(ValueError, match="proper rotation"):
        Calibration(np.eye(3), np.zeros(3), alignment=MIRROR)
    with pytest.raises(ValueError, match="proper rotation"):
        Calibration(np.eye(3), np.zeros(3), alignment=1.1 * np.eye(3))
    with pytest.raises(ValueError, match="3x3"):
        Calibration(np.eye(3), np.zeros(3), alignment=np.eye(2))
