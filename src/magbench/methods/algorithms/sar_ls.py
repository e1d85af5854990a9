"""SAR-LS (Troni and Whitcomb 2019, section IV.A): hard iron from ``dx/dt = -w x (x - b)``.

For a sensor whose only error is a bias ``b`` (``T = I``), the measured field ``x = m + b``
obeys ``dx/dt = -w x (x - b)``. With ``dx/dt`` from finite differences the residual
``dx/dt + w x x - w x b`` is linear in ``b``, which least squares gives in closed form.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._gyro_common import check_gyro_inputs, midpoint_differences, skew
from magbench.methods.registry import register


def sar_bias(y: np.ndarray, y_dot: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``b`` minimising ``sum_k ||y_dot_k + g_k x (y_k - b)||^2`` (closed form).

    Raises
    ------
    CalibrationFailed
        If the rotation axis hardly changes: the bias along it is then unobservable.
    """
    S = skew(g)
    M = np.einsum("kji,kjl->il", S, S)               # sum_k [g]x^T [g]x
    v = np.einsum("kji,kj->i", S, y_dot + np.cross(g, y))
    ev = np.linalg.eigvalsh(M)
    if ev[0] <= 1e-10 * ev[-1]:
        raise CalibrationFailed(f"SAR: the rotation axis hardly changes (eigenvalues "
                                f"{ev[0]:.3g} of {ev[-1]:.3g}); the bias along it is "
                                "unobservable")
    return np.linalg.solve(M, v)


def scale_of(y: np.ndarray, b: np.ndarray) -> float:
    """RMS of ``||y_k - b||``: the field magnitude for a ``T = r I`` sensor."""
    return float(np.sqrt(np.mean(np.sum((y - b) ** 2, axis=1))))


@register("sar_ls", label="SAR-LS", min_samples=5, family="extra", needs_gyro=True,
          model="sphere")
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        estimate_scale: bool = True) -> Calibration:
    """Calibrate the hard iron with SAR-LS (Troni and Whitcomb 2019, IV.A).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate : ndarray, shape (K, 3)
        Gyro samples in rad/s, in the magnetometer's axes; assumed unbiased.
    time : ndarray, shape (K,)
        Sample times in seconds, strictly increasing.
    estimate_scale : bool
        True (default): ``T = r I`` with ``r`` the RMS of ``||y - b||``, the field magnitude
        in the samples' unit, so the result scales with the samples (scale in, scale out, as
        every method does). False: the paper's ``T = I``, right only for samples in units of
        the field magnitude (the method itself estimates only ``b``).

    Returns
    -------
    Calibration
        ``h = b``; closed form, ``n_iter = 0``.

    Notes
    -----
    The derivative is the midpoint difference (``_gyro_common.midpoint_differences``), a
    second-order estimate, instead of navlib's one-sided difference. The paper's weights
    ``1/sigma_i^2`` are equal for white noise and drop out. A gyro bias is not modelled: it
    biases ``b``.
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    y_mid, y_dot, w_mid = midpoint_differences(samples, w, t)
    b = sar_bias(y_mid, y_dot, w_mid)
    r = scale_of(samples, b) if estimate_scale else 1.0
    return Calibration(r * np.eye(3), b, 0, True, "closed-form SAR least squares")
