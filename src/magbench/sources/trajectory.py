"""Seeded rigid-body trajectories for the gyro-aided methods: magnetometer and gyroscope samples.

A body rotates in a constant, unit-norm Earth field ``m0`` (world axes). Its attitude ``R(t)``
(body to world) obeys ``dR/dt = R [w]x`` with ``w`` the angular velocity in body axes, so the
field seen in body axes, ``m = R^T m0``, obeys ``dm/dt = -w x m`` (Troni and Whitcomb 2019), the
relation every gyro-aided method is built on. The sensors read

    y_k = T m(t_k) + h + eps_k          (review eq. 2, eps ~ N(0, sigma^2 I))
    g_k = w(t_k) + d + nu_k             (gyro bias d in rad/s, nu ~ N(0, sigma_g^2 I))

Two motions are provided:

``"random"``
    Angular velocity a sum of seeded random sinusoids per body axis (smooth, known in closed
    form); the attitude is integrated with a fourth-order Magnus step (two Gauss points, exact
    rotation-vector exponential) at ``oversample`` times the sample rate.
``"euler"``
    Wu and Shi's (2015) sampling pattern, ``phi = A sin(20 pi k/N + pi/2)``,
    ``theta = A sin(20 pi k/N)``, ``psi = 360 k/N`` degrees (A = 20 deg in the paper), read as
    continuous functions of time; attitude and angular velocity are then analytic.

Coverage is set by the motion's parameters: ``axis_weights`` (random motion; e.g. small roll and
pitch weights give a mostly-yaw, low-coverage motion) or ``tilt_deg`` and ``turns`` (Euler).

For the direction (heading) studies the simulator also gives what an inertial unit adds: an
accelerometer reading the specific force ``a_k = R_k^T (0, 0, -g) + noise`` (the world's z axis
points down, so a field of positive inclination has a positive z component, as
:func:`random_field` draws it), a magnetometer mounted with a rotation ``M`` against the inertial
axes, and a magnetometer lag ``L``:

    y_k = T M R(t_k - L)^T m0 + h + eps_k,

with ``R(t_k - L)`` exact (a Magnus step back from ``t_k``, or the Euler pattern at ``t_k - L``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from magbench.core.quaternions import matrix_to_quat
from magbench.core.rotations import cumulative_product, euler_zyx_to_matrix, rotation_exp

__all__ = ["Trajectory", "random_field", "simulate"]


@dataclass(frozen=True)
class Trajectory:
    """Simulated samples and the truth they were made from.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Sample times in seconds (strictly increasing, from 0).
    y : ndarray, shape (K, 3)
        Magnetometer samples ``T m + h + eps``.
    angular_rate : ndarray, shape (K, 3)
        Gyroscope samples ``w + d + nu`` in rad/s, body axes.
    w : ndarray, shape (K, 3)
        True angular velocity in body axes, rad/s.
    R : ndarray, shape (K, 3, 3)
        True attitude, body to world.
    m : ndarray, shape (K, 3)
        True field in body axes, unit norm.
    m0 : ndarray, shape (3,)
        The constant field in world axes, unit norm.
    T, h : ndarray
        True magnetometer distortion, shapes (3, 3) and (3,).
    gyro_bias : ndarray, shape (3,)
        True gyroscope bias in rad/s.
    acceleration : ndarray of shape (K, 3) or None
        Accelerometer samples (specific force, m/s^2, inertial axes).
    mount : ndarray, shape (3, 3)
        Rotation from the inertial axes to the magnetometer's (identity by default).
    lag_s : float
        How late the magnetometer reads the field, s.
    """

    t: np.ndarray
    y: np.ndarray
    angular_rate: np.ndarray
    w: np.ndarray
    R: np.ndarray
    m: np.ndarray
    m0: np.ndarray
    T: np.ndarray
    h: np.ndarray
    gyro_bias: np.ndarray
    acceleration: np.ndarray | None = None
    mount: np.ndarray = field(default_factory=lambda: np.eye(3))
    lag_s: float = 0.0

    @property
    def attitude(self) -> np.ndarray:
        """The true attitude as unit quaternions, ``(K, 4)`` scalar first, body -> world."""
        return matrix_to_quat(self.R)


def _random_rate(rng: np.random.Generator, rate_rms: float, axis_weights: np.ndarray,
                 n_harmonics: int, band_hz: tuple[float, float]):
    """A smooth angular velocity ``w(t)``: per axis, a sum of sinusoids with random frequency,
    phase and amplitude, scaled so that each axis has RMS ``rate_rms * weight``."""
    freq = rng.uniform(band_hz[0], band_hz[1], size=(3, n_harmonics))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(3, n_harmonics))
    amp = rng.uniform(0.5, 1.0, size=(3, n_harmonics))
    # RMS of a sum of sinusoids of distinct frequencies is sqrt(sum a^2 / 2).
    amp *= (rate_rms * axis_weights / np.sqrt(0.5 * np.sum(amp**2, axis=1)))[:, None]

    def rate(t: np.ndarray) -> np.ndarray:
        arg = 2.0 * np.pi * freq[None] * t[:, None, None] + phase[None]
        return np.einsum("kah,ah->ka", np.sin(arg), amp)

    return rate


def _integrate_attitude(rate, t_end: float, n_steps: int, R0: np.ndarray) -> np.ndarray:
    """Attitude at ``n_steps + 1`` equally spaced times on ``[0, t_end]``.

    Fourth-order Magnus step for ``dR/dt = R [w]x``: with the rates ``w1, w2`` at the two
    Gauss-Legendre points of a step of length ``dt``, the body rotation over the step is
    ``exp([Omega]x)`` with ``Omega = dt/2 (w1 + w2) + sqrt(3)/12 dt^2 (w1 x w2)``.
    """
    dt = t_end / n_steps
    omega = _magnus_step(rate, np.arange(n_steps) * dt, dt)
    steps = np.concatenate([R0[None], rotation_exp(omega)])
    return cumulative_product(steps)


def _magnus_step(rate, t0: np.ndarray, dt: float) -> np.ndarray:
    """The body rotation vectors of fourth-order Magnus steps of length ``dt`` (may be
    negative) from the times ``t0`` (see :func:`_integrate_attitude`)."""
    c = np.sqrt(3.0) / 6.0
    w1, w2 = rate(t0 + (0.5 - c) * dt), rate(t0 + (0.5 + c) * dt)
    return 0.5 * dt * (w1 + w2) + (np.sqrt(3.0) / 12.0) * dt**2 * np.cross(w1, w2)


def _euler_pattern(t: np.ndarray, duration: float, tilt_deg: float, turns: float,
                   wobbles: float) -> tuple[np.ndarray, np.ndarray]:
    """Attitude and body rates of the Wu-Shi pattern read as functions of ``s = t/duration``:
    ``phi = A sin(2 pi n s + pi/2)``, ``theta = A sin(2 pi n s)``, ``psi = 2 pi turns s``
    (the paper: A = 20 deg, n = 10 wobbles, one turn)."""
    A = np.deg2rad(tilt_deg)
    nu = 2.0 * np.pi * wobbles / duration
    arg = nu * t
    phi, dphi = A * np.sin(arg + np.pi / 2), A * nu * np.cos(arg + np.pi / 2)
    theta, dtheta = A * np.sin(arg), A * nu * np.cos(arg)
    psi, dpsi = 2.0 * np.pi * turns * t / duration, np.full_like(t, 2.0 * np.pi * turns / duration)
    # Body rates of Z-Y-X Euler angles.
    w = np.column_stack([
        dphi - dpsi * np.sin(theta),
        dtheta * np.cos(phi) + dpsi * np.cos(theta) * np.sin(phi),
        -dtheta * np.sin(phi) + dpsi * np.cos(theta) * np.cos(phi),
    ])
    return euler_zyx_to_matrix(phi, theta, psi), w


def random_field(rng: np.random.Generator, inclination_deg: float = 60.0) -> np.ndarray:
    """A unit field with the given inclination (dip below the horizon) and random declination."""
    inc = np.deg2rad(inclination_deg)
    dec = rng.uniform(0.0, 2.0 * np.pi)
    return np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), np.sin(inc)])


def _motion(rng: np.random.Generator, t: np.ndarray, motion: str, lag_s: float,
            oversample: int, random: dict, euler: dict,
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Attitude and body rate at the sample times, and the attitude at ``t - lag_s`` (the
    moments the magnetometer reads)."""
    K = len(t)
    if motion == "random":
        rate = _random_rate(rng, random["rate_rms"], np.asarray(random["axis_weights"], float),
                            random["n_harmonics"], random["band_hz"])
        R0 = rotation_exp(rng.normal(size=3) * np.pi / np.sqrt(3.0))
        # Attitude on a fine grid that contains every sample time.
        R = _integrate_attitude(rate, t[-1], (K - 1) * oversample, R0)[::oversample]
        R_read = R if not lag_s else R @ rotation_exp(_magnus_step(rate, t, -lag_s))
        return R, rate(t), R_read
    if motion == "euler":
        R, w = _euler_pattern(t, **euler)
        R_read = R if not lag_s else _euler_pattern(t - lag_s, **euler)[0]
        return R, w, R_read
    raise ValueError(f"motion must be 'random' or 'euler', got {motion!r}")


def simulate(rng: np.random.Generator, *, motion: str = "random", rate_hz: float = 25.0,
             duration_s: float = 24.0, T: np.ndarray | None = None,
             h: np.ndarray | None = None, mag_noise: float = 0.0, gyro_noise: float = 0.0,
             gyro_bias: np.ndarray | None = None, m0: np.ndarray | None = None,
             rate_rms: float = 0.8, axis_weights: tuple[float, float, float] = (1.0, 1.0, 1.0),
             n_harmonics: int = 3, band_hz: tuple[float, float] = (0.02, 0.3),
             tilt_deg: float = 20.0, turns: float = 1.0, wobbles: float = 10.0,
             oversample: int = 8, mount: np.ndarray | None = None, lag_s: float = 0.0,
             accel_noise: float = 0.0, gravity: float = 9.81) -> Trajectory:
    """Simulate one calibration manoeuvre.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws, in this order: the field's declination (if ``m0`` is None), the random motion
        (if ``motion="random"``), the initial attitude, then magnetometer, gyro and
        accelerometer noise.
    motion : {"random", "euler"}
        Sum of random sinusoids, or Wu and Shi's Euler-angle pattern.
    rate_hz, duration_s : float
        Sample rate and length; ``K = round(rate_hz * duration_s)`` samples at ``k / rate_hz``.
    T, h : array_like, optional
        Magnetometer distortion (identity and zero by default).
    mag_noise, gyro_noise, accel_noise : float
        Standard deviations of the white magnetometer (field units), gyro (rad/s) and
        accelerometer (m/s^2) noise.
    gyro_bias : array_like of shape (3,), optional
        Constant gyro bias in rad/s (zero by default).
    m0 : array_like of shape (3,), optional
        Field in world axes (normalised); 60 deg inclination, random declination by default.
    rate_rms, axis_weights, n_harmonics, band_hz
        Random motion: per-axis RMS angular rate ``rate_rms * weight`` (rad/s) from
        ``n_harmonics`` sinusoids with frequencies uniform in ``band_hz``.
    tilt_deg, turns, wobbles
        Euler motion: roll and pitch amplitude, yaw turns and roll/pitch cycles over the run.
    oversample : int
        Magnus steps per sample interval for the random motion.
    mount : array_like of shape (3, 3), optional
        Rotation from the inertial axes to the magnetometer's (identity by default).
    lag_s : float
        The magnetometer reads the field of ``t_k - lag_s`` (see the module notes).
    gravity : float
        Magnitude of the specific force at rest, m/s^2.

    Returns
    -------
    Trajectory
    """
    K = round(rate_hz * duration_s)
    if K < 2 or not rate_hz > 0:
        raise ValueError(f"need rate_hz > 0 and at least 2 samples, got K={K}")
    T = np.eye(3) if T is None else np.asarray(T, dtype=float)
    h = np.zeros(3) if h is None else np.asarray(h, dtype=float)
    M = np.eye(3) if mount is None else np.asarray(mount, dtype=float)
    bias = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, dtype=float)
    m0 = random_field(rng) if m0 is None else np.asarray(m0, dtype=float)
    m0 = m0 / np.linalg.norm(m0)
    t = np.arange(K) / rate_hz
    R, w, R_read = _motion(
        rng, t, motion, float(lag_s), oversample,
        {"rate_rms": rate_rms, "axis_weights": axis_weights, "n_harmonics": n_harmonics,
         "band_hz": band_hz},
        {"duration": K / rate_hz, "tilt_deg": tilt_deg, "turns": turns, "wobbles": wobbles})
    m = np.einsum("kji,j->ki", R, m0)                 # m = R^T m0
    m_read = m if R_read is R else np.einsum("kji,j->ki", R_read, m0)
    y = m_read @ (T @ M).T + h + rng.normal(0.0, mag_noise, size=(K, 3))
    g = w + bias + rng.normal(0.0, gyro_noise, size=(K, 3))
    a = np.einsum("kji,j->ki", R, [0.0, 0.0, -gravity]) + rng.normal(0.0, accel_noise,
                                                                      size=(K, 3))
    return Trajectory(t=t, y=y, angular_rate=g, w=w, R=R, m=m, m0=m0, T=T, h=h,
                      gyro_bias=bias, acceleration=a, mount=M, lag_s=float(lag_s))
