"""Geometry of field directions: the Fibonacci lattice (review Algorithm 8, steps 2-3)."""

from __future__ import annotations

import numpy as np

__all__ = ["GOLDEN_RATIO", "fibonacci_sphere"]

GOLDEN_RATIO = (1.0 + np.sqrt(5.0)) / 2.0


def fibonacci_sphere(K: int, radius: float = 1.0,
                     z_range: tuple[float, float] = (-1.0, 1.0)) -> np.ndarray:
    """K nearly uniform directions on a sphere (Algorithm 8, steps 2-3).

    Parameters
    ----------
    K : int
        Number of directions.
    radius : float
        Sphere radius r.
    z_range : (float, float)
        Restrict the lattice to the zone ``z_low <= z / r <= z_high`` (a cap or a band), still
        evenly spread over it. The default is the whole sphere, exactly Algorithm 8.

    Returns
    -------
    ndarray, shape (K, 3)
        ``[r cos(theta) sin(phi), r sin(theta) sin(phi), r cos(phi)]`` with
        ``theta = 2 pi k / golden_ratio`` and ``phi = arccos(1 - 2 (k - 0.5) / K)``, k = 1..K
        (for the whole sphere; a zone maps ``1 - 2 (k - 0.5) / K`` linearly onto it).
    """
    k = np.arange(1, K + 1, dtype=float)
    theta = 2.0 * np.pi * k / GOLDEN_RATIO
    z_low, z_high = z_range
    if (z_low, z_high) == (-1.0, 1.0):
        cos_phi = 1.0 - 2.0 * (k - 0.5) / K
    else:
        cos_phi = z_high - (z_high - z_low) * (k - 0.5) / K
    phi = np.arccos(cos_phi)
    return radius * np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                                     np.cos(phi)])
