"""The peers' calibration functions, as users call them: measuring sticks, never magbench's fits.

navlib (MBARI CoMPAS Lab) and magcal are what a user compares ``calibrate`` with; they are
the optional ``peers`` extra, imported only here and only when a study asks for them. Each
adapter returns ``(T, h)`` of ``y = T m + h``, the form of every magbench fit, so one scoring
serves all; scale-free peers are rescaled to unit mean calibrated norm (a scale changes no
score here, but keeps ``T`` comparable).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable

import numpy as np

__all__ = ["PEER_FITS", "available_peers", "fit_peer"]


def _normalise(T: np.ndarray, h: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``T`` rescaled so the calibrated samples have unit mean norm."""
    m = np.linalg.solve(T, (y - h).T)
    return T * float(np.mean(np.linalg.norm(m, axis=0)))


def _navlib_ellipsoid(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_ellipsoid_fit

    hard_iron, soft_iron = cal_mag_ellipsoid_fit(y)[:2]
    h = np.asarray(hard_iron, dtype=float).ravel()
    return _normalise(np.asarray(soft_iron, dtype=float), h, y), h   # navlib's soft_iron is T


def _navlib_fang(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_ellipsoid_fit_fang

    hard_iron, soft_iron = cal_mag_ellipsoid_fit_fang(y)[:2]
    h = np.asarray(hard_iron, dtype=float).ravel()
    return _normalise(np.asarray(soft_iron, dtype=float), h, y), h


def _navlib_twostep(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_twostep_hsi

    hard_iron, soft_iron = cal_mag_twostep_hsi(y, np.array([1.0, 0.0, 0.0]))[:2]
    return np.asarray(soft_iron, dtype=float), np.asarray(hard_iron, dtype=float).ravel()


def _navlib_sphere(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_sphere_fit

    h = np.asarray(cal_mag_sphere_fit(y)[0], dtype=float).ravel()
    return _normalise(np.eye(3), h, y), h


def _magcal_ellipsoid(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from magcal.core import MagnetometerCalibrator

    params = MagnetometerCalibrator.ellipsoid_fit(None, y)
    h = np.asarray(params["center"], dtype=float).ravel()
    # magcal applies m = W (y - c), so its matrix is T^-1.
    return _normalise(np.linalg.inv(params["transform_matrix"]), h, y), h


def _magcal_sphere(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from magcal.core import MagnetometerCalibrator

    h = np.asarray(MagnetometerCalibrator.sphere_fit(None, y)["center"], dtype=float).ravel()
    return _normalise(np.eye(3), h, y), h


#: peer -> (package, fit ``y -> (T, h)``, magbench method it is paired with)
PEER_FITS: dict[str, tuple[str, Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], str]] = {
    "navlib.cal_mag_ellipsoid_fit": ("navlib", _navlib_ellipsoid, "ellipsoid"),
    "navlib.cal_mag_ellipsoid_fit_fang": ("navlib", _navlib_fang, "fang"),
    "navlib.cal_mag_twostep_hsi": ("navlib", _navlib_twostep, "twostep"),
    "navlib.cal_mag_sphere_fit": ("navlib", _navlib_sphere, "sphere"),
    "magcal.ellipsoid_fit": ("magcal", _magcal_ellipsoid, "ellipsoid"),
    "magcal.sphere_fit": ("magcal", _magcal_sphere, "sphere"),
}


def available_peers() -> list[str]:
    """The peers whose package is installed, in :data:`PEER_FITS` order."""
    return [name for name, (package, _, _) in PEER_FITS.items()
            if importlib.util.find_spec(package) is not None]


def fit_peer(name: str, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T, h)`` of peer ``name`` fitted on samples ``y`` (K, 3)."""
    return PEER_FITS[name][1](np.asarray(y, dtype=float))
