"""Wu and Shi's (2015) simulated magnetometer, section IV:

    y_k = S C_k m_n + h + e_k,   e_k ~ N(0, sigma^2 I),   k = 1..N          (their eq. 1)

with the Changsha field ``m_n``, ``S`` and ``h`` of their eq. (24) and the Euler-angle attitude
pattern of section IV (roll and pitch within +-20 deg, one yaw turn: only a band of the sphere
is covered).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magbench.core.reference import paper_values

__all__ = ["WuShiData", "attitude_angles", "attitude_matrices", "simulate", "truth"]


@dataclass(frozen=True)
class WuShiData:
    """One simulated data set: samples and the truth they were made from.

    Attributes
    ----------
    y : ndarray, shape (N, 3)
        Measurements ``S C_k m_n + h + e_k`` in gauss.
    m : ndarray, shape (N, 3)
        True field in body axes, ``C_k m_n`` (unit norm).
    C : ndarray, shape (N, 3, 3)
        Attitude matrices ``C_n^b`` of section IV.
    S, h : ndarray
        True soft and hard iron of eq. (24); ``S`` plays the role of the review's ``T``.
    """

    y: np.ndarray
    m: np.ndarray
    C: np.ndarray
    S: np.ndarray
    h: np.ndarray


def truth() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(m_n, S, h)`` of section IV and eq. (24), from ``paper_values.yaml``.

    The printed ``m_n = [0.7388, 0.0409, -0.6727]`` has norm 1.0000118 (four-decimal rounding of
    a unit vector); it is rescaled to unit norm, as the paper states it is a unit vector.
    """
    sim = paper_values()["wu_shi"]["simulation"]
    m_n = np.array(sim["m_n"], dtype=float)
    return m_n / np.linalg.norm(m_n), np.array(sim["S"], dtype=float), np.array(sim["h"],
                                                                                 dtype=float)


def attitude_angles(N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(phi, psi, theta)`` in radians for k = 1..N (section IV; their ``f`` in theta is k)."""
    k = np.arange(1, N + 1, dtype=float)
    phi = np.deg2rad(20.0 * np.sin(20.0 * np.pi * k / N + np.pi / 2.0))
    psi = np.deg2rad(360.0 * k / N)
    theta = np.deg2rad(20.0 * np.sin(20.0 * np.pi * k / N))
    return phi, psi, theta


def attitude_matrices(N: int) -> np.ndarray:
    """The matrices ``C_n^b`` of section IV as printed, shape ``(N, 3, 3)``."""
    phi, psi, theta = attitude_angles(N)
    cf, sf, cp, sp, ct, st = (np.cos(phi), np.sin(phi), np.cos(psi), np.sin(psi),
                              np.cos(theta), np.sin(theta))
    C = np.empty((N, 3, 3))
    C[:, 0, 0] = ct * cp
    C[:, 0, 1] = sf * sp - cf * cp * st
    C[:, 0, 2] = cf * sp + cp * sf * st
    C[:, 1, 0] = st
    C[:, 1, 1] = cf * ct
    C[:, 1, 2] = -ct * sf
    C[:, 2, 0] = -ct * sp
    C[:, 2, 1] = cp * sf + cf * st * sp
    C[:, 2, 2] = cf * cp - sf * st * sp
    return C


def simulate(rng: np.random.Generator, N: int = 300, sigma: float = 0.003) -> WuShiData:
    """Samples of the model (1) with the truth of eq. (24) and the attitude pattern."""
    m_n, S, h = truth()
    C = attitude_matrices(N)
    m = C @ m_n
    y = m @ S.T + h + sigma * rng.standard_normal((N, 3))
    return WuShiData(y, m, C, S, h)
