"""The peers' calibration functions, as users call them: measuring sticks, never magbench's fits.

navlib (MBARI CoMPAS Lab) and magcal are what a user compares ``calibrate`` with; they are
the optional ``peers`` extra, imported only here and only when a study asks for them. Each
adapter returns ``(T, h)`` of ``y = T m + h``, the form of every magbench fit, so one scoring
serves all; scale-free peers are rescaled to unit mean calibrated norm (a scale changes no
score here, but keeps ``T`` comparable). A gyro-aided peer (its magbench counterpart
``needs_gyro``) also takes ``angular_rate`` and ``time`` (MagFactor3: ``attitude`` and
``reference_field`` too), as keywords; :func:`fit_peer` passes them only to those.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable

import numpy as np

from magbench.methods.registry import get_method

__all__ = ["PEER_FITS", "PEER_NEEDS_FIELD", "PEER_REQUIRES", "available_peers", "fit_peer",
           "missing_module", "needs_gyro"]


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


def _navlib_twostep_hi(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_twostep_hi

    # A unit reference field, as magbench's twostep_hi assumes by default (field_norm=1).
    h = np.asarray(cal_mag_twostep_hi(y, np.array([1.0, 0.0, 0.0]))[0], dtype=float).ravel()
    return np.eye(3), h


def _bias_only(hard_iron: object, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T, h)`` of a peer that estimates the hard iron alone (``T`` a scaled identity)."""
    h = np.asarray(hard_iron, dtype=float).ravel()
    return _normalise(np.eye(3), h, y), h


def _navlib_sar_ls(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                   **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_sar_ls

    return _bias_only(cal_mag_sar_ls(y, angular_rate, time)[0], y)


def _navlib_sar_kf(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                   **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_sar_kf

    return _bias_only(cal_mag_sar_kf(y, angular_rate, time)[0], y)


def _navlib_sar_aid(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                    **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_sar_aid

    return _bias_only(cal_mag_sar_aid(y, angular_rate, time)[0], y)


def _magyc(out: tuple, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T, h)`` of a MAGYC result ``(hard_iron, soft_iron, ...)``: navlib's calibrated field
    is ``soft_iron^-1 (y - hard_iron)`` (checked on its own output), so ``soft_iron`` is T."""
    h = np.asarray(out[0], dtype=float).ravel()
    return _normalise(np.asarray(out[1], dtype=float), h, y), h


def _navlib_magyc_ls(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                     **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_magyc_ls

    return _magyc(cal_mag_magyc_ls(y, angular_rate, time), y)


def _navlib_magyc_nls(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                      **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_magyc_nls

    return _magyc(cal_mag_magyc_nls(y, angular_rate, time), y)


def _navlib_magyc_bfg(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                      **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_magyc_bfg

    return _magyc(cal_mag_magyc_bfg(y, angular_rate, time), y)


def _navlib_magyc_ifg(y: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
                      **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_magyc_ifg

    return _magyc(cal_mag_magyc_ifg(y, angular_rate, time), y)


def _rph_deg(attitude: np.ndarray) -> np.ndarray:
    """Roll, pitch and heading (ZYX Euler angles, degrees) of body-to-world rotations."""
    R = np.asarray(attitude, dtype=float)
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    pitch = -np.arcsin(np.clip(R[:, 2, 0], -1.0, 1.0))
    heading = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return np.degrees(np.column_stack([roll, pitch, heading]))


def _navlib_magfactor3(y: np.ndarray, *, attitude: np.ndarray | None = None,
                       reference_field: np.ndarray | None = None,
                       **_: object) -> tuple[np.ndarray, np.ndarray]:
    from navlib.cal.cal_mag import cal_mag_magfactor3

    if attitude is None or reference_field is None:
        raise ValueError("MagFactor3 needs the attitude and the reference field")
    hard_iron, soft_iron = cal_mag_magfactor3(y, _rph_deg(attitude), 0.0,
                                              np.asarray(reference_field, dtype=float))[:2]
    h = np.asarray(hard_iron, dtype=float).ravel()
    return _normalise(np.asarray(soft_iron, dtype=float), h, y), h


#: peer -> (package, fit ``y -> (T, h)``, magbench method it is paired with)
PEER_FITS: dict[str, tuple[str, Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], str]] = {
    "navlib.cal_mag_ellipsoid_fit": ("navlib", _navlib_ellipsoid, "ellipsoid"),
    "navlib.cal_mag_ellipsoid_fit_fang": ("navlib", _navlib_fang, "fang"),
    "navlib.cal_mag_twostep_hsi": ("navlib", _navlib_twostep, "twostep"),
    "navlib.cal_mag_sphere_fit": ("navlib", _navlib_sphere, "sphere"),
    "navlib.cal_mag_twostep_hi": ("navlib", _navlib_twostep_hi, "twostep_hi"),
    "navlib.cal_mag_sar_ls": ("navlib", _navlib_sar_ls, "sar_ls"),
    "navlib.cal_mag_sar_kf": ("navlib", _navlib_sar_kf, "sar_kf"),
    "navlib.cal_mag_sar_aid": ("navlib", _navlib_sar_aid, "sar_aid"),
    "navlib.cal_mag_magyc_ls": ("navlib", _navlib_magyc_ls, "magyc_ls"),
    "navlib.cal_mag_magyc_nls": ("navlib", _navlib_magyc_nls, "magyc_nls"),
    "navlib.cal_mag_magyc_bfg": ("navlib", _navlib_magyc_bfg, "magyc_bfg"),
    "navlib.cal_mag_magyc_ifg": ("navlib", _navlib_magyc_ifg, "magyc_ifg"),
    "navlib.cal_mag_magfactor3": ("navlib", _navlib_magfactor3, "magfactor3"),
    "magcal.ellipsoid_fit": ("magcal", _magcal_ellipsoid, "ellipsoid"),
    "magcal.sphere_fit": ("magcal", _magcal_sphere, "sphere"),
}

#: Modules a peer needs beyond its package: navlib's factor-graph methods import GTSAM only
#: when called (``pip install navlib[calibration]``, Python >= 3.12).
PEER_REQUIRES: dict[str, tuple[str, ...]] = {
    "navlib.cal_mag_magyc_bfg": ("gtsam",),
    "navlib.cal_mag_magyc_ifg": ("gtsam",),
    "navlib.cal_mag_magfactor3": ("gtsam",),
}

#: Peers that need the field's strength given (navlib's TWOSTEP-HI takes a reference field):
#: run with a unit field they suit data in field units only, not a recording in counts.
PEER_NEEDS_FIELD = ("navlib.cal_mag_twostep_hi",)


def missing_module(name: str) -> str | None:
    """The first module peer ``name`` needs that is not installed (None: all are)."""
    for module in (PEER_FITS[name][0], *PEER_REQUIRES.get(name, ())):
        if importlib.util.find_spec(module) is None:
            return module
    return None


def needs_gyro(name: str) -> bool:
    """True if peer ``name`` needs gyro samples and times (as its magbench counterpart)."""
    return get_method(PEER_FITS[name][2]).needs_gyro


def available_peers(gyro: bool = False) -> list[str]:
    """The peers whose modules are installed, in :data:`PEER_FITS` order; the gyro-aided
    ones only with ``gyro`` (a caller with magnetometer samples alone cannot run them)."""
    return [name for name in PEER_FITS
            if missing_module(name) is None and (gyro or not needs_gyro(name))]


def fit_peer(name: str, y: np.ndarray, **inputs: object) -> tuple[np.ndarray, np.ndarray]:
    """``(T, h)`` of peer ``name`` fitted on samples ``y`` (K, 3); ``inputs``
    (``angular_rate``, ``time``, ``attitude``, ``reference_field``) reach a gyro-aided peer
    only."""
    fit = PEER_FITS[name][1]
    y = np.asarray(y, dtype=float)
    return fit(y, **inputs) if needs_gyro(name) else fit(y)
