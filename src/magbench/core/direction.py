"""Direction metrics of a calibrated field: what a compass needs, which a magnitude cannot show.

A calibration that leaves a rotation in the field passes every magnitude test (J after
Procrustes, J_r, the held-out spread) and still points the wrong way. With a reference attitude
``q`` (scalar first, sensor -> world, :mod:`magbench.core.quaternions`) the calibrated field
``m`` is taken to the world, ``f = q m q*``, and compared with the reference field direction:

* **heading and inclination error**, per sample, by BROAD's definitions (Laidig et al., Data
  6(7):72, 2021, ``example_code/broad_utils.py``): for an error quaternion ``q_err`` in world
  axes, heading error ``2 atan(|z/w|)`` and inclination error ``2 acos(sqrt(w^2 + z^2))``,
  summarised as an RMS over the movement phase. The field's error quaternion
  (:func:`field_error_quaternion`) is the rotation about the world vertical that turns the
  reference field's azimuth into the measured one, followed by the rotation about the
  horizontal axis that turns its elevation into the measured one; BROAD's two angles of it
  are exactly the azimuth and elevation differences (the heading an accelerometer-magnetometer
  filter would lose, and the dip error);
* **direction spread**: the angle of each world-frame field direction to their mean direction
  (median, RMS, 95th percentile): zero for a perfect calibration in a homogeneous field,
  whatever the reference field;
* with a gyroscope only, **gyro consistency** (:func:`gyro_consistency`): over short windows the
  field in sensor axes must turn as the integrated rate says, ``m_end = dR^T m_start``;
* with an accelerometer at rest, the **dip angle** between the specific force (up) and the
  field (:func:`dip_angles`) is constant in a homogeneous field; its spread is the metric.

The world's vertical is its z axis (up or down: every error here is unchanged when z flips).
Angles are in radians except in :func:`direction_score`, which reports degrees.
"""

from __future__ import annotations

import numpy as np

from magbench.core.quaternions import quat_about_axis, quat_conjugate, quat_multiply, quat_rotate
from magbench.core.rotations import cumulative_product, rotation_exp

__all__ = [
    "angles_between",
    "attitude_field",
    "broad_errors",
    "dip_angles",
    "direction_score",
    "direction_spread",
    "field_error_quaternion",
    "field_errors",
    "gyro_consistency",
    "heading_bound",
    "heading_errors",
    "mean_direction",
    "rest_mask",
    "rms",
    "world_field",
]

_Z = np.array([0.0, 0.0, 1.0])


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angles_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (radians) between ``(..., 3)`` vectors, accurate near 0 and pi (atan2 form)."""
    a, b = _unit(a), _unit(b)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def world_field(field: np.ndarray, attitude: np.ndarray) -> np.ndarray:
    """The sensor-frame field in world axes, ``q m q*`` per sample (``(K, 3)``)."""
    return quat_rotate(attitude, field)


def mean_direction(vectors: np.ndarray) -> np.ndarray:
    """The unit mean of the unit directions of ``(K, 3)`` vectors (NaN rows ignored)."""
    u = _unit(vectors)
    return _unit(np.nanmean(u, axis=0))


def _azimuth_difference(f: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Signed angle (radians) about the world vertical from ``r``'s azimuth to each ``f``'s."""
    return np.arctan2(r[0] * f[..., 1] - r[1] * f[..., 0], r[0] * f[..., 0] + r[1] * f[..., 1])


def heading_errors(f_world: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """BROAD's heading errors (radians) of world-frame field directions against a reference:
    the azimuth differences, which :func:`field_errors` gives through the error quaternion
    (the same angle, without building it)."""
    f = np.asarray(f_world, dtype=float)
    return np.abs(_azimuth_difference(f, np.asarray(reference, dtype=float)))


def field_error_quaternion(f_world: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Error quaternions (world axes) of measured field directions against a reference one.

    ``q_err = q_tilt q_z``: ``q_z`` turns the reference about the world vertical by the
    azimuth difference ``psi``, ``q_tilt`` then turns it about the horizontal axis
    ``u x z`` (``u`` the measured field's horizontal direction) by the elevation difference
    ``d``. Then ``q_err reference q_err* = f_world`` (directions) and BROAD's heading and
    inclination errors of ``q_err`` (:func:`broad_errors`) are ``|psi|`` and ``|d|``.

    Parameters
    ----------
    f_world : ndarray, shape (K, 3)
        Measured field in world axes (any length).
    reference : ndarray, shape (3,)
        Reference field in world axes (any length, not vertical).

    Returns
    -------
    ndarray, shape (K, 4)
    """
    f, r = _unit(f_world), _unit(reference)
    psi = _azimuth_difference(f, r)
    elev_f = np.arctan2(f[..., 2], np.hypot(f[..., 0], f[..., 1]))
    elev_r = np.arctan2(r[2], np.hypot(r[0], r[1]))
    q_z = quat_about_axis(np.broadcast_to(_Z, f.shape), psi)
    u = np.stack([f[..., 0], f[..., 1], np.zeros(f.shape[:-1])], axis=-1)
    q_tilt = quat_about_axis(np.cross(u, _Z), elev_f - elev_r)
    return quat_multiply(q_tilt, q_z)


def broad_errors(q_err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BROAD's heading and inclination errors of world-frame error quaternions (radians).

    Heading ``2 atan(|z/w|)`` and inclination ``2 acos(sqrt(w^2 + z^2))`` (Laidig et al. 2021,
    ``broad_utils.py``); the heading part is the rotation about the world vertical, the
    inclination part the remaining tilt, and both are in ``[0, pi]``.
    """
    q = np.asarray(q_err, dtype=float)
    w, z = q[..., 0], q[..., 3]
    heading = 2.0 * np.arctan2(np.abs(z), np.abs(w))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return heading, inclination


def field_errors(field: np.ndarray, attitude: np.ndarray,
                 reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample heading and inclination errors (radians) of a calibrated field.

    Parameters
    ----------
    field : ndarray, shape (K, 3)
        Calibrated field in sensor axes.
    attitude : ndarray, shape (K, 4)
        Reference attitude, sensor -> world (NaN rows give NaN errors).
    reference : ndarray, shape (3,)
        The field in world axes that a perfect calibration would give.
    """
    return broad_errors(field_error_quaternion(world_field(field, attitude), reference))


def rms(values: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Root mean square of the finite values (under ``mask``); NaN if there are none."""
    v = np.asarray(values, dtype=float)
    if mask is not None:
        v = v[np.asarray(mask, dtype=bool)]
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else np.nan


def attitude_field(y: np.ndarray, attitude: np.ndarray, *, keep: float = 0.5,
                   passes: int = 5) -> np.ndarray | None:
    """The world-frame field a recording's reference attitude implies: ``h`` of
    ``y_k = R_k^T h + b`` fitted by least squares on the rows that fit best.

    The raw samples are modelled with an offset and no soft iron, which is enough to find
    where the field points in the world (a few uT of shape error do not turn it). Each pass
    refits on the ``keep`` share of rows with the smallest residual, so a disturbed stretch
    does not move the answer. It uses the attitude, which no magnetometer-only fit sees: it
    is the truth a fit's heading is scored against, not a calibration.

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        Raw samples in sensor axes.
    attitude : ndarray, shape (K, 4)
        Reference attitude, sensor -> world (NaN rows are left out).
    keep : float
        Share of rows each refit keeps.
    passes : int
        Number of refits.

    Returns
    -------
    ndarray, shape (3,), or None
        The field in world axes, or None when fewer than 10 rows have an attitude.
    """
    y, q = np.asarray(y, dtype=float), np.asarray(attitude, dtype=float)
    ok = np.isfinite(q).all(axis=1) & np.isfinite(y).all(axis=1)
    if ok.sum() < 10:
        return None
    y, qc = y[ok], quat_conjugate(q[ok])
    K = len(y)
    # Row k of the design: [R_k^T | I]; R_k^T e_j is e_j turned by the conjugate.
    cols = [quat_rotate(qc, np.broadcast_to(e, (K, 3))) for e in np.eye(3)]
    X = np.concatenate([np.stack(cols, axis=2), np.broadcast_to(np.eye(3), (K, 3, 3))],
                       axis=2)
    use = np.ones(K, dtype=bool)
    for _ in range(passes):
        p, *_ = np.linalg.lstsq(X[use].reshape(-1, 6), y[use].reshape(-1), rcond=None)
        residual = np.linalg.norm(X @ p - y, axis=1)
        use = residual <= np.quantile(residual, keep)
    return p[:3]


def direction_spread(f_world: np.ndarray) -> np.ndarray:
    """Angles (radians) of world-frame field directions to their mean direction."""
    f = np.asarray(f_world, dtype=float)
    return angles_between(f, mean_direction(f))


def gyro_consistency(t: np.ndarray, field: np.ndarray, angular_rate: np.ndarray,
                     window_s: float = 0.5, gyro_bias: np.ndarray | None = None) -> np.ndarray:
    """Angles (radians) between the field at each window's end and the field at its start
    turned by the integrated gyro rate, over consecutive windows of ``window_s``.

    In a homogeneous field the sensor-frame field obeys ``dm/dt = -w x m`` (the relation of
    the gyro-aided methods), so ``m(t1) = dR^T m(t0)`` with ``dR`` the body rotation from
    ``t0`` to ``t1``; the rotation is integrated by the trapezoid rule on the rate samples. A
    field that is rotated against the gyro's axes (an unknown mounting rotation) or distorted
    turns differently.
    """
    t = np.asarray(t, dtype=float)
    w = np.asarray(angular_rate, dtype=float)
    if gyro_bias is not None:
        w = w - np.asarray(gyro_bias, dtype=float)
    dt = np.diff(t)
    steps = rotation_exp(0.5 * (w[:-1] + w[1:]) * dt[:, None])
    P = cumulative_product(np.concatenate([np.eye(3)[None], steps]))
    n = max(1, round(window_s / float(np.median(dt))))
    start = np.arange(0, len(t) - n, n)
    end = start + n
    dR = np.einsum("kji,kjl->kil", P[start], P[end])           # P_s^T P_e
    predicted = np.einsum("kji,kj->ki", dR, field[start])      # dR^T m_s
    return angles_between(field[end], predicted)


def rest_mask(angular_rate: np.ndarray | None, acceleration: np.ndarray, *,
              gyro_tol: float = 0.05, acc_tol: float = 0.3, gravity: float = 9.81) -> np.ndarray:
    """Samples at rest: rate below ``gyro_tol`` rad/s (if a gyro is given) and specific force
    within ``acc_tol`` m/s^2 of ``gravity``."""
    a = np.linalg.norm(np.asarray(acceleration, dtype=float), axis=-1)
    still = np.abs(a - gravity) < acc_tol
    if angular_rate is not None:
        still &= np.linalg.norm(np.asarray(angular_rate, dtype=float), axis=-1) < gyro_tol
    return still


def dip_angles(acceleration: np.ndarray, field: np.ndarray) -> np.ndarray:
    """Dip of the field below the horizontal, ``asin(-a.m / (|a| |m|))`` (radians), with the
    specific force ``a`` pointing up (an accelerometer at rest)."""
    a, m = _unit(acceleration), _unit(field)
    return np.arcsin(np.clip(-np.sum(a * m, axis=-1), -1.0, 1.0))


def _percentiles_deg(angles: np.ndarray) -> tuple[float, float, float]:
    """Median, RMS and 95th percentile of the finite angles, in degrees."""
    a = np.asarray(angles, dtype=float)
    a = a[np.isfinite(a)]
    if not a.size:
        return np.nan, np.nan, np.nan
    d = np.degrees(a)
    return float(np.median(d)), float(np.sqrt(np.mean(d * d))), float(np.percentile(d, 95))


def direction_score(field: np.ndarray, *, attitude: np.ndarray | None = None,
                    reference: np.ndarray | None = None, mask: np.ndarray | None = None,
                    t: np.ndarray | None = None, angular_rate: np.ndarray | None = None,
                    acceleration: np.ndarray | None = None, window_s: float = 0.5,
                    gyro_bias: np.ndarray | None = None) -> dict[str, float]:
    """Every direction metric the given data allow, in degrees (NaN where they do not).

    Parameters
    ----------
    field : ndarray, shape (K, 3)
        Calibrated field in sensor axes.
    attitude : ndarray of shape (K, 4), optional
        Reference attitude, sensor -> world; NaN rows are left out.
    reference : ndarray of shape (3,), optional
        Reference field in world axes (heading and inclination errors need it).
    mask : ndarray of shape (K,) bool, optional
        Rows scored with the attitude (the movement phase); all rows by default.
    t, angular_rate : ndarray, optional
        Times (s) and gyro rate (rad/s) for :func:`gyro_consistency`.
    acceleration : ndarray of shape (K, 3), optional
        Specific force for :func:`dip_angles` on the rows at rest (:func:`rest_mask`).
    window_s, gyro_bias
        Passed to :func:`gyro_consistency`.

    Returns
    -------
    dict
        ``heading_rms``, ``heading_median``, ``heading_p95``, ``inclination_rms`` (BROAD's
        errors, RMS over ``mask``); ``spread_median``, ``spread_rms``, ``spread_p95`` (world
        directions about their mean); ``gyro_median``, ``gyro_rms`` (per window);
        ``dip_median``, ``dip_spread`` (standard deviation) and ``n_rest``.
    """
    field = np.asarray(field, dtype=float)
    out = dict.fromkeys(["heading_rms", "heading_median", "heading_p95", "inclination_rms",
                         "spread_median", "spread_rms", "spread_p95", "gyro_median",
                         "gyro_rms", "dip_median", "dip_spread"], np.nan)
    out["n_rest"] = 0
    if attitude is not None:
        keep = np.isfinite(attitude).all(axis=1) & np.isfinite(field).all(axis=1)
        if mask is not None:
            keep &= np.asarray(mask, dtype=bool)
        f_world = world_field(field[keep], attitude[keep])
        if len(f_world):
            out["spread_median"], out["spread_rms"], out["spread_p95"] = _percentiles_deg(
                direction_spread(f_world))
        if reference is not None and len(f_world):
            heading, inclination = broad_errors(field_error_quaternion(f_world, reference))
            median, _, p95 = _percentiles_deg(heading)
            out.update(heading_rms=float(np.degrees(rms(heading))), heading_median=median,
                       heading_p95=p95, inclination_rms=float(np.degrees(rms(inclination))))
    if t is not None and angular_rate is not None and len(field) > 2:
        median, root, _ = _percentiles_deg(gyro_consistency(t, field, angular_rate, window_s,
                                                            gyro_bias))
        out.update(gyro_median=median, gyro_rms=root)
    if acceleration is not None:
        still = rest_mask(angular_rate, acceleration)
        out["n_rest"] = int(still.sum())
        if still.sum() >= 2:
            dip = np.degrees(dip_angles(acceleration[still], field[still]))
            out.update(dip_median=float(np.median(dip)), dip_spread=float(np.std(dip)))
    return out


def heading_bound(G: np.ndarray, attitude: np.ndarray, reference: np.ndarray,
                  sigma: float) -> tuple[float, float]:
    """Cramer-Rao-type floor of the RMS heading error of a calibration that knows the attitude.

    With the attitude ``R_k`` and the unit world field ``m0`` known, the model
    ``y_k = G u_k + h + e_k``, ``u_k = R_k^T m0``, ``e_k ~ N(0, sigma^2 I)`` is linear in
    ``D = [G h]`` (12 numbers; ``G = T M`` holds the mounting rotation, which the attitude
    makes identifiable). Its Fisher information gives every row of ``D`` the covariance
    ``sigma^2 S^-1``, ``S = sum_k x_k x_k^T``, ``x_k = (u_k, 1)``, reached by least squares.
    The heading of the world field ``R_k G^-1 (y_k - h)`` moves, to first order, by
    ``v_k . (e_k - dD x_k)`` with ``v_k = G^-T R_k^T p_k / c``, ``p_k`` the horizontal unit
    vector across the field and ``c`` the horizontal share of the unit field. So

        E[dpsi_k^2] >= sigma^2 |v_k|^2 (1 + x_k^T S^-1 x_k)

    for a sample not used in the fit (the sample's own noise, then the calibration's share).

    Parameters
    ----------
    G : ndarray, shape (3, 3)
        True ``T M``.
    attitude : ndarray, shape (K, 4)
        True attitude, sensor (inertial axes) -> world.
    reference : ndarray, shape (3,)
        The world field (normalised here).
    sigma : float
        Magnetometer noise, in units of the field.

    Returns
    -------
    total, calibration : float
        The bound's RMS over the samples (radians), and the calibration's share alone
        (``sigma |v_k| sqrt(x_k^T S^-1 x_k)``, RMS).
    """
    m0 = _unit(reference)
    to_sensor = quat_conjugate(attitude)
    u = quat_rotate(to_sensor, np.broadcast_to(m0, (len(attitude), 3)))
    x = np.column_stack([u, np.ones(len(u))])
    leverage = np.einsum("ki,ij,kj->k", x, np.linalg.inv(x.T @ x), x)
    across = np.cross(_Z, m0)
    c = np.linalg.norm(across)
    p = quat_rotate(to_sensor, np.broadcast_to(across / c, u.shape))
    v = np.linalg.solve(np.asarray(G, dtype=float).T, p.T).T / c
    v2 = sigma**2 * np.einsum("ki,ki->k", v, v)
    return float(np.sqrt(np.mean(v2 * (1.0 + leverage)))), float(np.sqrt(np.mean(v2 * leverage)))
