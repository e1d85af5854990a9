"""Semi-synthetic data: a recording with a reference attitude, distorted by a known amount.

The BROAD recordings' magnetometer is already calibrated upstream, so a known distortion
applied to it gives real motion, real noise and a known truth. A recording is first prepared
(:func:`prepare`):

* **time alignment**: the magnetometer's lag behind the attitude reference and the gyro's
  (:mod:`magbench.core.lag`) are measured and removed by resampling both onto the reference's
  times; the magnetometer lag is measured twice, the second time without the disturbed rows
  that the first correction reveals;
* **clean rows**: rows whose world-frame field ``q m q*`` lies within ``tolerance`` (a share of
  the field strength) of its median; a magnet nearby or on the board fails this;
* **reference field**: the median world-frame field over the clean rows (its direction is what
  a perfect calibration gives, its norm the field strength ``B``);
* **movement phase** (:func:`movement_mask`): from the first to the last moment the gyro rate,
  averaged over a second, exceeds a threshold (BROAD computes its errors over that phase).

:func:`distort` then draws ``y = T M (m / B) + h`` from the review's eq. (68) at a point such
as eq. (80) (``T = alpha I + E``, ``h = e``), a mounting rotation ``M`` of a given angle about a
random axis and, for ``distortion="magnet"``, an attached magnet: a constant offset of ``magnet``
field strengths in a random direction (broad33's magnet 2 cm from the sensor is 26.7 uT in a
44 uT field, 0.61).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from magbench.core.direction import world_field
from magbench.core.lag import attitude_rate, gyro_lag, magnetometer_lag, shift
from magbench.core.rotations import rotation_exp
from magbench.sources.recordings import InertialRecording
from magbench.sources.synthetic import Point, draw_distortion

__all__ = ["DISTORTIONS", "Distorted", "Prepared", "clean_mask", "distort", "movement_mask",
           "prepare"]

DISTORTIONS = ("eq80", "magnet")
#: broad33's attached magnet, |b| = 26.7 uT in a 44.0 uT field (its SOURCE.md).
MAGNET_SHARE = 26.7 / 44.0


@dataclass(frozen=True)
class Prepared:
    """A recording with its streams on the attitude's time base and what scoring needs.

    Attributes
    ----------
    rec : InertialRecording
        Magnetometer, gyro and accelerometer resampled onto the reference's times (rows where
        a resampled value would fall outside the recording are dropped).
    lag_s, gyro_lag_s, mag_gyro_lag_s : float
        Magnetometer behind the attitude, gyro behind the attitude, magnetometer behind the
        gyro (s; measured before the correction).
    reference : ndarray, shape (3,)
        World-frame field (recorded units).
    strength : float
        Its norm ``B``.
    clean, movement : ndarray of bool, shape (K,)
        Undisturbed rows with an attitude; the movement phase.
    """

    rec: InertialRecording
    lag_s: float
    gyro_lag_s: float
    mag_gyro_lag_s: float
    reference: np.ndarray
    strength: float
    clean: np.ndarray
    movement: np.ndarray


def movement_mask(t: np.ndarray, angular_rate: np.ndarray, threshold: float = 0.1,
                  window_s: float = 1.0) -> np.ndarray:
    """Rows from the first to the last moment the gyro rate, averaged over ``window_s``,
    exceeds ``threshold`` rad/s."""
    speed = np.linalg.norm(angular_rate, axis=1)
    n = max(1, round(window_s / float(np.median(np.diff(t)))))
    smooth = np.convolve(speed, np.ones(n) / n, mode="same")
    above = np.flatnonzero(smooth > threshold)
    mask = np.zeros(len(t), dtype=bool)
    if above.size:
        mask[above[0]:above[-1] + 1] = True
    return mask


def clean_mask(field: np.ndarray, attitude: np.ndarray,
               tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows whose world field is within ``tolerance`` (share of its strength) of the median,
    and that median (the reference field)."""
    f = world_field(field, attitude)
    median = np.nanmedian(f, axis=0)
    distance = np.linalg.norm(f - median, axis=1)
    return distance <= tolerance * np.linalg.norm(median), median


def prepare(rec: InertialRecording, *, tolerance: float = 0.1, max_lag_s: float = 0.1,
            correct_lag: bool = True) -> Prepared:
    """Measure and remove the lags, find the clean rows, the reference and the movement.

    Raises
    ------
    ValueError
        If the recording has no gyro or no attitude, or a lag cannot be measured.
    """
    if rec.gyro is None or rec.attitude is None:
        raise ValueError(f"{rec.name}: the heading study needs gyro and attitude columns")
    rate = attitude_rate(rec.t, rec.attitude)
    lag, _ = magnetometer_lag(rec.t, rec.y, rate, max_lag_s)
    clean, _ = clean_mask(shift(rec.t, rec.y, lag), rec.attitude, tolerance)
    masked = np.where(clean[:, None], rec.y, np.nan)
    lag, _ = magnetometer_lag(rec.t, masked, rate, max_lag_s)
    g_lag, _ = gyro_lag(rec.t, rec.gyro, rec.attitude, max_lag_s)
    mg_lag, _ = magnetometer_lag(rec.t, masked, rec.gyro, max_lag_s)
    if not (np.isfinite(lag) and np.isfinite(g_lag)):
        raise ValueError(f"{rec.name}: no lag found within {max_lag_s} s")
    if correct_lag:
        acc = None if rec.acceleration is None else shift(rec.t, rec.acceleration, g_lag)
        rec = replace(rec, y=shift(rec.t, rec.y, lag), gyro=shift(rec.t, rec.gyro, g_lag),
                      acceleration=acc)
        rec = rec.rows(np.isfinite(rec.y).all(axis=1) & np.isfinite(rec.gyro).all(axis=1))
    clean, reference = clean_mask(rec.y, rec.attitude, tolerance)
    return Prepared(rec, float(lag), float(g_lag), float(mg_lag), reference,
                    float(np.linalg.norm(reference)), clean, movement_mask(rec.t, rec.gyro))


@dataclass(frozen=True)
class Distorted:
    """Distorted samples and their truth: ``y = T_total (m / B) + h``.

    ``T_total = T M``: the review's ``T`` (eq. 66a) after the mounting rotation ``M``.
    """

    y: np.ndarray
    T: np.ndarray
    h: np.ndarray
    mount: np.ndarray


def random_rotation(rng: np.random.Generator, angle_deg: float) -> np.ndarray:
    """A rotation by ``angle_deg`` about a uniformly random axis."""
    axis = rng.normal(size=3)
    return rotation_exp(np.radians(angle_deg) * axis / np.linalg.norm(axis))


def distort(rng: np.random.Generator, prepared: Prepared, distortion: str = "eq80", *,
            point: Point | None = None, mount_deg: float = 0.0,
            magnet: float = MAGNET_SHARE) -> Distorted:
    """A known distortion of the prepared recording's magnetometer (unit field strength).

    Draws, in order: ``alpha, E, e`` at ``point`` (eq. 68; eq. 80's nominal point by
    default), the mounting rotation's axis, then for ``distortion="magnet"`` the magnet's
    direction.
    """
    if distortion not in DISTORTIONS:
        raise ValueError(f"distortion must be one of {', '.join(DISTORTIONS)}, got "
                         f"{distortion!r}")
    T, h = draw_distortion(rng, point or Point())
    M = random_rotation(rng, mount_deg)
    if distortion == "magnet":
        d = rng.normal(size=3)
        h = h + magnet * d / np.linalg.norm(d)
    G = T @ M
    return Distorted(prepared.rec.y / prepared.strength @ G.T + h, G, h, M)
