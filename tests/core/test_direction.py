"""Direction metrics: exact answers on constructed fields, invariances, zero on the truth."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.direction import (
    broad_errors,
    dip_angles,
    direction_score,
    direction_spread,
    field_error_quaternion,
    field_errors,
    gyro_consistency,
    rms,
)
from magbench.core.quaternions import (
    matrix_to_quat,
    quat_about_axis,
    quat_conjugate,
    quat_multiply,
    quat_rotate,
)
from magbench.core.rotations import rotation_exp

#: BROAD's world: +z up, +y magnetic north, the field dipping 68 degrees.
INC = np.radians(68.0)
REFERENCE = 44.0 * np.array([0.0, np.cos(INC), -np.sin(INC)])


def attitudes(n: int = 300, seed: int = 0) -> np.ndarray:
    return matrix_to_quat(rotation_exp(np.random.default_rng(seed).normal(size=(n, 3)) * 1.5))


def sensor_field(q: np.ndarray, f_world: np.ndarray) -> np.ndarray:
    """The sensor-frame field that the attitude ``q`` turns into ``f_world``."""
    return quat_rotate(quat_conjugate(q), f_world)


def about_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_broad_errors_split_a_rotation_about_z_from_a_tilt():
    h, i = broad_errors(quat_about_axis(np.array([0.0, 0.0, 1.0]), np.radians(7.0)))
    assert h == pytest.approx(np.radians(7.0), abs=1e-14) and i == pytest.approx(0.0, abs=1e-7)
    h, i = broad_errors(quat_about_axis(np.array([1.0, 1.0, 0.0]), np.radians(-4.0)))
    assert h == pytest.approx(0.0, abs=1e-14) and i == pytest.approx(np.radians(4.0), abs=1e-12)


@pytest.mark.parametrize("psi_deg", [-30.0, 3.0, 170.0])
def test_a_field_turned_about_z_gives_that_heading_error_and_no_inclination_error(psi_deg):
    q = attitudes()
    m = sensor_field(q, about_z(np.radians(psi_deg)) @ REFERENCE)
    heading, inclination = field_errors(m, q, REFERENCE)
    assert np.allclose(heading, np.radians(abs(psi_deg)), atol=1e-12)
    assert np.allclose(inclination, 0.0, atol=1e-7)


def test_a_steeper_field_gives_that_inclination_error_and_no_heading_error():
    q = attitudes()
    steeper = 44.0 * np.array([0.0, np.cos(INC + 0.05), -np.sin(INC + 0.05)])
    heading, inclination = field_errors(sensor_field(q, steeper), q, REFERENCE)
    assert np.allclose(heading, 0.0, atol=1e-12)
    assert np.allclose(inclination, 0.05, atol=1e-10)


def test_the_error_quaternion_maps_the_reference_onto_the_measured_direction():
    f = np.random.default_rng(3).normal(size=(100, 3))
    q_err = field_error_quaternion(f, REFERENCE)
    turned = quat_rotate(q_err, np.broadcast_to(REFERENCE / 44.0, f.shape))
    assert np.abs(turned - f / np.linalg.norm(f, axis=1, keepdims=True)).max() < 1e-12


def test_errors_do_not_change_when_world_and_reference_turn_together_about_z():
    q = attitudes(seed=4)
    m = sensor_field(q, REFERENCE) + np.random.default_rng(5).normal(0, 3.0, size=(300, 3))
    before = field_errors(m, q, REFERENCE)
    turn = np.radians(40.0)
    q_turned = quat_multiply(quat_about_axis(np.array([0.0, 0.0, 1.0]), turn), q)
    after = field_errors(m, q_turned, about_z(turn) @ REFERENCE)
    assert np.allclose(before, after, atol=1e-12)
    # a turn of the world alone is a heading error of that size, no inclination error
    h, i = field_errors(sensor_field(q, REFERENCE), q_turned, REFERENCE)
    assert np.allclose(h, turn, atol=1e-12) and np.allclose(i, 0.0, atol=1e-7)


def constant_turn(n: int = 400, rate: float = 0.9):
    """A body turning at a constant rate (exact trapezoid), with the field and gravity."""
    t = np.arange(n) * 0.02
    w = np.array([0.3, -0.5, 0.8]) * rate
    R = rotation_exp(np.array([0.2, 1.0, -0.4])) @ rotation_exp(t[:, None] * w[None])
    q = matrix_to_quat(R)
    m = np.einsum("kji,j->ki", R, REFERENCE)
    acc = np.einsum("kji,j->ki", R, [0.0, 0.0, 9.81])
    return t, np.tile(w, (n, 1)), q, m, acc


def test_noise_free_truth_scores_zero_everywhere():
    t, w, q, m, acc = constant_turn()
    score = direction_score(m, attitude=q, reference=REFERENCE, t=t, angular_rate=w * 0,
                            acceleration=acc)
    assert score["heading_rms"] < 1e-10 and score["inclination_rms"] < 1e-5
    assert score["spread_p95"] < 1e-5
    assert score["dip_spread"] < 1e-10 and score["dip_median"] == pytest.approx(68.0)
    assert np.abs(gyro_consistency(t, m, w)).max() < 1e-10
    assert np.abs(direction_spread(quat_rotate(q, m))).max() < 1e-7


def test_gyro_consistency_sees_a_mounting_rotation_the_magnitude_cannot():
    t, w, _, m, _ = constant_turn()
    M = rotation_exp(np.array([np.radians(5.0), 0.0, 0.0]))
    rotated = m @ M.T
    assert np.allclose(np.linalg.norm(rotated, axis=1), np.linalg.norm(m, axis=1))
    assert np.median(gyro_consistency(t, rotated, w)) > np.radians(0.2)


def test_dip_angles_and_rms():
    a = np.array([[0.0, 0.0, 9.81]])
    assert dip_angles(a, REFERENCE[None])[0] == pytest.approx(INC)
    assert rms(np.array([3.0, 4.0, np.nan])) == pytest.approx(np.sqrt(12.5))
    assert np.isnan(rms(np.array([np.nan])))


def test_missing_attitude_rows_are_left_out_and_unknown_metrics_are_nan():
    _, _, q, m, _ = constant_turn()
    q = q.copy()
    q[:50] = np.nan
    score = direction_score(m, attitude=q, reference=REFERENCE)
    assert score["heading_rms"] < 1e-10
    assert np.isnan(score["gyro_median"]) and np.isnan(score["dip_spread"])


def test_heading_bound_is_met_by_least_squares_with_the_attitude_known():
    from magbench.core.direction import heading_bound

    rng = np.random.default_rng(8)
    K, sigma = 150, 0.01
    q = attitudes(K, seed=9)
    m0 = REFERENCE / 44.0
    u = sensor_field(q, np.broadcast_to(m0, (K, 3)))
    G = np.array([[1.1, 0.03, -0.02], [0.0, 0.95, 0.04], [0.02, -0.01, 1.02]])
    h = np.array([0.1, -0.05, 0.2])
    total, share = heading_bound(G, q, m0, sigma)
    x = np.column_stack([u, np.ones(K)])
    errors = []
    for _ in range(300):
        y = u @ G.T + h + rng.normal(0, sigma, (K, 3))
        D = np.linalg.lstsq(x, y, rcond=None)[0].T            # [G h], the efficient fit
        held_out = u @ G.T + h + rng.normal(0, sigma, (K, 3))
        m = np.linalg.solve(D[:, :3], (held_out - D[:, 3]).T).T
        errors.append(field_errors(m, q, m0)[0])
    measured = rms(np.concatenate(errors))
    assert measured == pytest.approx(total, rel=0.03)
    # with G = I the floor is the noise across the horizontal field, sigma / cos(inclination)
    alone, _ = heading_bound(np.eye(3), q, m0, sigma)
    assert alone == pytest.approx(sigma / np.cos(INC) * np.sqrt(1 + 4 / K), rel=0.02)
    assert 0 < share < 0.3 * total


def test_attitude_field_recovers_the_world_field_past_disturbed_rows():
    from magbench.core.direction import attitude_field
    from magbench.core.quaternions import quat_conjugate, quat_rotate

    gen = np.random.default_rng(3)
    q = gen.normal(size=(600, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    h, b = np.array([0.5, 20.0, -35.0]), np.array([300.0, -100.0, 50.0])
    y = quat_rotate(quat_conjugate(q), np.broadcast_to(h, (600, 3))) + b
    y += gen.normal(0.0, 0.2, y.shape)
    y[:150] += gen.normal(0.0, 60.0, (150, 3))       # a quarter of the rows disturbed
    q[:5] = np.nan                                    # rows without attitude are left out
    assert np.allclose(attitude_field(y, q), h, atol=0.1)
    assert attitude_field(y[:9], q[5:14]) is None     # too few rows to say


def test_heading_errors_are_the_error_quaternions_heading():
    from magbench.core.direction import heading_errors, world_field

    gen = np.random.default_rng(5)
    q = gen.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    m, ref = gen.normal(size=(500, 3)), np.array([0.3, 20.0, -35.0])
    heading, _ = field_errors(m, q, ref)
    assert np.allclose(heading_errors(world_field(m, q), ref), heading, atol=1e-12)
    # a field turned 40 deg about the vertical from the reference: 40 deg, whatever its dip
    a = np.radians(40.0)
    f = np.array([[20 * -np.sin(a), 20 * np.cos(a), -80.0]])
    assert heading_errors(f, np.array([0.0, 1.0, -0.2]))[0] == pytest.approx(a)
