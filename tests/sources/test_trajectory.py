"""The simulator: kinematic consistency, exact attitude integration, seeded reproducibility."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.rotations import euler_zyx_to_matrix, rotation_exp, skew
from magbench.sources.trajectory import simulate


def central_difference_error(rate_hz: float, motion: str) -> float:
    """max |dm/dt + w x m| with dm/dt from central differences of the true body field."""
    tr = simulate(np.random.default_rng(5), motion=motion, rate_hz=rate_hz, duration_s=10.0)
    dm = (tr.m[2:] - tr.m[:-2]) / (tr.t[2:] - tr.t[:-2])[:, None]
    return float(np.abs(dm + np.cross(tr.w[1:-1], tr.m[1:-1])).max())


@pytest.mark.parametrize("motion", ["random", "euler"])
def test_body_field_obeys_dm_dt_equals_minus_w_cross_m(motion):
    # Central differences are second order: the mismatch must fall ~4x per doubling of the
    # rate, which it can only do if m and w describe the same motion.
    e1, e2 = central_difference_error(100.0, motion), central_difference_error(200.0, motion)
    assert e1 < 1e-2
    assert 3.5 < e1 / e2 < 4.5


def test_attitude_integration_is_fourth_order_and_stays_orthonormal():
    ref = simulate(np.random.default_rng(1), oversample=64).R
    errs = [np.abs(simulate(np.random.default_rng(1), oversample=n).R - ref).max()
            for n in (2, 4)]
    assert 12 < errs[0] / errs[1] < 20          # 2^4 = 16 for a fourth-order scheme
    assert errs[1] < 1e-9
    RtR = np.einsum("kji,kjl->kil", ref, ref)
    assert np.abs(RtR - np.eye(3)).max() < 1e-12


def test_measurements_follow_the_model():
    rng = np.random.default_rng(2)
    T = np.array([[1.1, 0.02, 0.0], [0.02, 0.9, 0.01], [0.0, 0.01, 1.0]])
    h, d = np.array([0.1, -0.2, 0.05]), np.array([0.01, -0.02, 0.03])
    tr = simulate(rng, T=T, h=h, gyro_bias=d)
    np.testing.assert_allclose(tr.y, tr.m @ T.T + h, atol=1e-15)
    np.testing.assert_allclose(tr.angular_rate, tr.w + d, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(tr.m, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(tr.m, np.einsum("kji,j->ki", tr.R, tr.m0), atol=0)
    assert tr.y.shape == (600, 3) and np.all(np.diff(tr.t) > 0)


def test_noise_levels_and_seeding():
    a = simulate(np.random.default_rng(3), mag_noise=0.01, gyro_noise=0.02, duration_s=200.0)
    b = simulate(np.random.default_rng(3), mag_noise=0.01, gyro_noise=0.02, duration_s=200.0)
    np.testing.assert_array_equal(a.y, b.y)
    assert abs(np.std(a.y - a.m) / 0.01 - 1) < 0.05
    assert abs(np.std(a.angular_rate - a.w) / 0.02 - 1) < 0.05


def test_random_motion_rms_rate_and_axis_weights():
    tr = simulate(np.random.default_rng(4), duration_s=2000.0, rate_hz=5.0, rate_rms=0.5,
                  axis_weights=(0.2, 0.2, 1.0), band_hz=(0.05, 0.3))
    rms = np.sqrt(np.mean(tr.w**2, axis=0))
    np.testing.assert_allclose(rms, [0.1, 0.1, 0.5], rtol=0.05)


def test_euler_pattern_is_wu_and_shi():
    N = 400
    tr = simulate(np.random.default_rng(0), motion="euler", rate_hz=N / 20.0, duration_s=20.0)
    k = np.arange(N)
    phi = np.deg2rad(20 * np.sin(20 * np.pi * k / N + np.pi / 2))
    theta = np.deg2rad(20 * np.sin(20 * np.pi * k / N))
    psi = np.deg2rad(360 * k / N)
    np.testing.assert_allclose(tr.R, euler_zyx_to_matrix(phi, theta, psi), atol=1e-12)


def test_rotation_exp_is_rodrigues_and_skew_is_the_cross_product():
    rng = np.random.default_rng(6)
    v, u = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(np.einsum("kij,kj->ki", skew(v), u), np.cross(v, u))
    from scipy.linalg import expm
    for phi in [*v, np.array([1e-6, -2e-6, 3e-7]), np.zeros(3)]:
        np.testing.assert_allclose(rotation_exp(phi), expm(skew(phi)), atol=1e-14)


def test_bad_arguments():
    with pytest.raises(ValueError, match="motion"):
        simulate(np.random.default_rng(0), motion="spin")
    with pytest.raises(ValueError, match="at least 2 samples"):
        simulate(np.random.default_rng(0), rate_hz=1.0, duration_s=1.0)


def test_mounting_rotation_and_accelerometer_follow_the_model():
    from magbench.core.direction import dip_angles
    from magbench.core.rotations import rotation_exp

    M = rotation_exp(np.array([0.05, -0.1, 0.02]))
    T = np.diag([1.1, 0.9, 1.0])
    h = np.array([0.1, -0.2, 0.05])
    tr = simulate(np.random.default_rng(4), T=T, h=h, mount=M)
    assert np.abs(tr.y - (tr.m @ (T @ M).T + h)).max() < 1e-12
    assert np.allclose(np.linalg.norm(tr.acceleration, axis=1), 9.81)
    # the world's z points down: the 60 degree field dips below the horizon
    assert np.allclose(dip_angles(tr.acceleration, tr.m), np.radians(60.0))


def test_a_lag_of_one_sample_reads_the_previous_sample_s_field():
    plain = simulate(np.random.default_rng(6), rate_hz=20.0)
    late = simulate(np.random.default_rng(6), rate_hz=20.0, lag_s=1 / 20.0)
    assert np.abs(late.y[1:] - plain.y[:-1]).max() < 1e-7     # one Magnus step vs eight
    assert np.array_equal(late.R, plain.R) and late.lag_s == 0.05
    euler = simulate(np.random.default_rng(6), motion="euler", rate_hz=20.0)
    euler_late = simulate(np.random.default_rng(6), motion="euler", rate_hz=20.0, lag_s=0.05)
    assert np.abs(euler_late.y[1:] - euler.y[:-1]).max() < 1e-12


def test_the_new_streams_leave_the_old_draws_alone():
    a = simulate(np.random.default_rng(7), mag_noise=0.01, gyro_noise=0.01)
    b = simulate(np.random.default_rng(7), mag_noise=0.01, gyro_noise=0.01, accel_noise=0.1)
    assert np.array_equal(a.y, b.y) and np.array_equal(a.angular_rate, b.angular_rate)
    assert not np.array_equal(a.acceleration, b.acceleration)
