"""Time-varying terms y = T m + h + C u: noise-free recovery, the held-out choice."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.methods.regressors import fit_time_varying, held_out_choice
from magbench.sources.trajectory import simulate

T_TRUE = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, 0.02], [0.0, 0.02, 1.0]])
H_TRUE = np.array([0.1, -0.2, 0.05])
C_TRUE = np.array([[0.004, 0.002], [-0.002, 0.0], [0.003, -0.003]])   # per A, per degree C


def fang(samples):
    return magbench.calibrate(samples, "fang").correction()


def manoeuvre(noise: float, seed: int = 0):
    traj = simulate(np.random.default_rng(seed), duration_s=20.0, rate_hz=20.0, T=T_TRUE,
                    h=H_TRUE, mag_noise=noise)
    t = traj.t
    current = 20 * np.clip(0.5 + 0.3 * np.sin(0.44 * t + 1) + 0.2 * np.sin(1.45 * t), 0, 1)
    temperature = 25 + 4 * np.sin(0.3 * t) + 0.1 * t
    return traj, np.column_stack([current, temperature])


def test_noise_free_terms_are_recovered_exactly():
    traj, u = manoeuvre(0.0)
    y = traj.y + u @ C_TRUE.T
    fit = fit_time_varying(y, u, fang)
    np.testing.assert_allclose(fit.C, C_TRUE, atol=1e-9)
    np.testing.assert_allclose(fit.b, H_TRUE, atol=1e-8)
    # A is the safe gauge of T: (T T^T)^(-1/2), so A^-2 = T T^T.
    np.testing.assert_allclose(np.linalg.inv(fit.A @ fit.A), T_TRUE @ T_TRUE.T, atol=1e-8)
    np.testing.assert_allclose(np.linalg.norm(fit.apply(y, u), axis=1), 1.0, atol=1e-9)


def test_kept_when_they_lower_the_held_out_error_and_not_otherwise():
    traj, u = manoeuvre(0.005)
    disturbed = held_out_choice(traj.y + u[:, :1] @ C_TRUE[:, :1].T, u[:, :1], fang)
    assert disturbed.kept and disturbed.varying_out < 0.5 * disturbed.static_out
    np.testing.assert_allclose(disturbed.fit.C[:, 0], C_TRUE[:, 0], atol=4e-4)
    clean = held_out_choice(traj.y, u[:, :1], fang)
    assert not clean.kept and clean.reason == "the terms did not lower the held-out error"
    assert clean.to_dict(["current"])["regressors"] == ["current"]


def test_a_constant_regressor_is_refused():
    traj, _ = manoeuvre(0.005)
    with pytest.raises(ValueError, match="does not vary"):
        fit_time_varying(traj.y, np.ones((len(traj.y), 1)), fang)
    choice = held_out_choice(traj.y, np.ones((len(traj.y), 1)), fang)
    assert not choice.kept and choice.fit is None and "does not vary" in choice.reason


def test_a_static_fit_that_fails_is_a_reason_not_a_traceback():
    from magbench.core.model import CalibrationFailed

    traj, u = manoeuvre(0.005)
    y = traj.y + u[:, :1] @ C_TRUE[:, :1].T
    calls = []

    def fails_after_the_first(samples):
        calls.append(len(samples))
        if len(calls) > 1:                  # the algebraic start's refit: that start only
            raise CalibrationFailed("fang: fitted quadric is not an ellipsoid")
        return fang(samples)

    fit = fit_time_varying(y, u[:, :1], fails_after_the_first)
    np.testing.assert_allclose(fit.C[:, 0], C_TRUE[:, 0], atol=4e-4)

    def always_fails(samples):
        raise CalibrationFailed("fang: fitted quadric is not an ellipsoid")

    with pytest.raises(CalibrationFailed, match="not an ellipsoid"):
        fit_time_varying(y, u[:, :1], always_fails)
    choice = held_out_choice(y, u[:, :1], always_fails)
    assert not choice.kept and choice.fit is None
    assert choice.reason == "not fitted: fang: fitted quadric is not an ellipsoid"
