"""Seeded synthetic datasets: review Algorithm 8 with the perturbation model of eqs. (66)-(68).

Every dataset is drawn from a ``numpy.random.Generator`` built from a
``numpy.random.SeedSequence`` keyed by (base seed, sweep point, trial index): a trial can be
regenerated alone, whatever the number of workers or the order in which trials run.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from magbench.core.geometry import fibonacci_sphere

__all__ = ["Dataset", "Point", "draw_distortion", "make_dataset", "trial_seed_sequence"]

@dataclass(frozen=True)
class Point:
    """One setting of the Monte Carlo experiment (eq. 80 is the nominal one).

    Attributes
    ----------
    K : int
        Samples per dataset.
    sigma : float
        Standard deviation of the white measurement noise (eq. 67).
    beta : float
        Half-width of the uniform distribution of the elements of E (eq. 68b).
    gamma : float
        Half-width of the uniform distribution of the elements of e (eq. 68c).
    alpha_low, alpha_high : float
        Range of the uniform gross scale alpha (eq. 68a).
    cap_deg : float
        Half-angle of the polar cap the field directions cover; 180 is the whole sphere (the
        review's setting). Beyond the review: partial coverage, as when a sensor cannot be
        turned every way.
    band_deg : float
        Half-width, in latitude, of the equatorial band the directions cover; 90 is the whole
        sphere. A narrow band is a land vehicle that mostly yaws.
    """

    K: int = 300
    sigma: float = 0.005
    beta: float = 0.05
    gamma: float = 0.05
    alpha_low: float = 0.8
    alpha_high: float = 1.2
    cap_deg: float = 180.0
    band_deg: float = 90.0

    def __post_init__(self) -> None:
        if int(self.K) != self.K or self.K < 1:
            raise ValueError(f"K must be a positive integer, got {self.K}")
        if not self.sigma >= 0:
            raise ValueError(f"sigma must be >= 0, got {self.sigma}")
        if not (self.beta >= 0 and self.gamma >= 0):
            raise ValueError(f"beta and gamma must be >= 0, got {self.beta} and {self.gamma}")
        if not 0 < self.alpha_low <= self.alpha_high:
            raise ValueError(f"alpha range must satisfy 0 < low <= high, got "
                             f"[{self.alpha_low}, {self.alpha_high}]")
        if not (0 < self.cap_deg <= 180 and 0 < self.band_deg <= 90):
            raise ValueError(f"cap_deg must be in (0, 180] and band_deg in (0, 90], got "
                             f"{self.cap_deg} and {self.band_deg}")

    @property
    def z_range(self) -> tuple[float, float]:
        """The range of the directions' z component that the cap and band allow."""
        z_low = max(np.cos(np.radians(self.cap_deg)), -np.sin(np.radians(self.band_deg)))
        z_high = min(1.0, np.sin(np.radians(self.band_deg)))
        return float(z_low), float(z_high)

    @property
    def covered_fraction(self) -> float:
        """Fraction of the sphere's area the directions cover (uniform in z on a sphere)."""
        z_low, z_high = self.z_range
        return (z_high - z_low) / 2.0

    @property
    def key(self) -> int:
        """A stable 32-bit identity of this point, used to key its random streams.

        Keyed by value (not by position in a sweep) so the nominal point draws the same
        datasets in every sweep that contains it.
        """
        text = (f"K={int(self.K)};sigma={self.sigma!r};beta={self.beta!r};gamma={self.gamma!r};"
                f"alpha={self.alpha_low!r},{self.alpha_high!r}")
        # Coverage joins the key only when partial, so full-sphere points keep their streams.
        if self.cap_deg < 180:
            text += f";cap={float(self.cap_deg)!r}"
        if self.band_deg < 90:
            text += f";band={float(self.band_deg)!r}"
        return zlib.crc32(text.encode())

    @property
    def directions(self) -> np.ndarray:
        """The K field directions of this point (the Fibonacci lattice over its coverage)."""
        return fibonacci_sphere(self.K, z_range=self.z_range)


@dataclass(frozen=True)
class Dataset:
    """A synthetic dataset and the truth it was made from.

    Attributes
    ----------
    y : ndarray, shape (K, 3)
        Measurements ``T m + h + eps`` (eq. 67).
    m : ndarray, shape (K, 3)
        True unit field directions.
    T : ndarray, shape (3, 3)
        True ``alpha I + E`` (eq. 66a).
    h : ndarray, shape (3,)
        True ``e`` (eq. 66b).
    """

    y: np.ndarray
    m: np.ndarray
    T: np.ndarray
    h: np.ndarray


def draw_distortion(rng: np.random.Generator, point: Point) -> tuple[np.ndarray, np.ndarray]:
    """Draw ``T = alpha I + E`` and ``h = e`` (eqs. 66 and 68)."""
    alpha = rng.uniform(point.alpha_low, point.alpha_high)
    E = rng.uniform(-point.beta, point.beta, size=(3, 3))
    e = rng.uniform(-point.gamma, point.gamma, size=3)
    return alpha * np.eye(3) + E, e


def make_dataset(rng: np.random.Generator, point: Point,
                 directions: np.ndarray | None = None) -> Dataset:
    """One dataset of Algorithm 8: directions, distortion (66), noise and measurements (67).

    Parameters
    ----------
    rng : numpy.random.Generator
        The trial's generator; draws alpha, E, e, then the noise, in that order.
    point : Point
        The experiment setting.
    directions : ndarray of shape (K, 3), optional
        Unit field directions; by default ``point.directions``, the Fibonacci lattice of
        ``point.K`` points over the point's coverage (the whole sphere unless cap/band say).
    """
    m = point.directions if directions is None else np.asarray(directions, float)
    T, h = draw_distortion(rng, point)
    noise = rng.normal(0.0, point.sigma, size=m.shape)
    return Dataset(y=m @ T.T + h + noise, m=m, T=T, h=h)


def trial_seed_sequence(seed: int, point: Point, trial: int) -> np.random.SeedSequence:
    """The SeedSequence of one trial, from (base seed, sweep point, trial index)."""
    return np.random.SeedSequence(entropy=int(seed), spawn_key=(point.key, int(trial)))
