"""Closed-form least-squares sphere fit: hard iron and one scale (extra method).

Minimises the algebraic residual

    sum_k (||y_k - c||^2 - r^2)^2

over the centre ``c`` and radius ``r`` (Jennings' "sphere fit (least squared)", MATLAB File
Exchange 34129). Expanding, ``||y_k||^2 = 2 c^T y_k + (r^2 - ||c||^2)`` is linear in ``c`` and
``d = r^2 - ||c||^2``; eliminating ``d`` by centring the data leaves

    ||y_k||^2 - mean ||y||^2 = 2 c^T (y_k - mean y),

a three-unknown linear least-squares problem, and then ``r^2 = mean ||y_k - c||^2``. The model
is ``y = r m + c``: ``T = r I``, ``h = c``. It cannot represent soft iron (``T`` not a multiple of
``I``), so on general data its error is limited by the off-diagonal and unequal-scale parts of
``T``.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.registry import register


@register("sphere", label="Sphere fit", min_samples=5, family="extra", model="sphere")
def fit(samples: np.ndarray) -> Calibration:
    """Calibrate with the closed-form least-squares sphere fit.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.

    Returns
    -------
    Calibration
        ``T = r I`` and ``h = c``; closed form, ``n_iter = 0``.

    Raises
    ------
    CalibrationFailed
        If the centred samples do not span three dimensions (the centre is undetermined).
    """
    mean = samples.mean(axis=0)
    centred = samples - mean
    squared = np.einsum("ij,ij->i", samples, samples)
    c, _, rank, _ = np.linalg.lstsq(2.0 * centred, squared - squared.mean(), rcond=None)
    if rank < 3:
        raise CalibrationFailed("sphere fit: samples do not span three dimensions, so the "
                                "centre is undetermined")
    offsets = samples - c
    r = float(np.sqrt(np.mean(np.einsum("ij,ij->i", offsets, offsets))))
    return Calibration(r * np.eye(3), c, 0, True, f"sphere radius {r:.6g}")
