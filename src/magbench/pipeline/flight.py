"""What a flight log adds to a calibration: the compass's mounting rotation and its
time-varying terms.

After the static calibration ``m = A (y - b)`` (the safe gauge, so ``m`` stays in the
compass's own axes), the logged attitude (or, without one, the accelerometer at rest) ranks
the autopilots' standard rotations by how constant the field is in world axes
(:func:`magbench.core.mounting.detect_mounting`). The current (or throttle) and temperature
streams are the regressors of ``y = T m + h + C u(t)``, kept only when they lower the
held-out error (:mod:`magbench.methods.regressors`).
"""

from __future__ import annotations

import numpy as np

from magbench.core import geometry
from magbench.core.blockwise import affine_rows
from magbench.core.mounting import MountingResult, detect_mounting
from magbench.core.quaternions import UnitRows, finite_rows
from magbench.methods.regressors import HeldOutChoice, StaticFit, held_out_choice
from magbench.sources.recordings import Recording

__all__ = ["QUATERNION", "REGRESSORS", "check_regressors", "compact_rows", "mounting_rotation",
           "time_varying_terms",
           "unused_regressors", "usable_regressors"]

QUATERNION = ["qw", "qx", "qy", "qz"]
ACCEL = ["ax", "ay", "az"]


def compact_rows(x: np.ndarray, use: np.ndarray, block: int = 1 << 14) -> np.ndarray:
    """``x[use]`` made in ``x`` itself (its first rows; ``x`` is overwritten), a block at a
    time: the same numbers without a second array of every row."""
    n = 0
    for start in range(0, len(x), block):
        rows = x[start:start + block][use[start:start + block]]   # a copy, then written
        x[n:n + len(rows)] = rows                                 # at or before ``start``
        n += len(rows)
    return x[:n]


def mounting_rotation(rec: Recording, A: np.ndarray, b: np.ndarray,
                      keep: np.ndarray | None = None,
                      corrected: np.ndarray | None = None) -> MountingResult | None:
    """The mounting rotation of a recording's compass, or None without attitude or accelerometer.

    Parameters
    ----------
    rec : Recording
        With ``extra`` holding ``qw..qz`` (preferred) or ``ax..az``.
    A, b : ndarray
        The correction ``m = A (y - b)``.
    keep : ndarray of bool, optional
        Samples to use (the calibration's inliers); rows without attitude are left out too.
    corrected : ndarray of shape (K, 3), optional
        The corrected samples to use instead of ``A (y - b)`` (with time-varying terms).
    """
    if rec.extra is None or not (all(c in rec.extra for c in QUATERNION)
                                 or all(c in rec.extra for c in ACCEL)):
        return None         # before the corrected samples, a (K, 3) array, are built
    base = np.ones(rec.K, bool) if keep is None else np.asarray(keep, bool)
    m = (affine_rows(rec.y, A, b, geometry.BLOCK_ROWS) if corrected is None    # no temporary
         else np.asarray(corrected))
    base = base & np.isfinite(m).all(axis=1)
    if all(c in rec.extra for c in QUATERNION):
        view = UnitRows([rec.extra[c] for c in QUATERNION])
        use = base & finite_rows(view)
        if use.sum() >= 2:
            # the used rows of the field moved to the front of its fresh array, those of
            # the attitude normalised as read (the detection turns them into matrices a
            # block at a time): no copies of a long log's samples or attitude
            if use.all():
                return detect_mounting(m, attitude=view)
            field = compact_rows(m, use) if corrected is None else m[use]
            return detect_mounting(field, attitude=view.take(np.flatnonzero(use)))
    if all(c in rec.extra for c in ACCEL):
        a = rec.stack(ACCEL)
        use = base & np.isfinite(a).all(axis=1)
        if use.sum() >= 2:
            return detect_mounting(m[use], accel=a[use])
    return None


#: Regressors of the time-varying terms, in the order ``compensate=auto`` looks for them: the
#: current (else the throttle, its stand-in, as ArduPilot's COMPASS_MOTCT allows) and the
#: temperature.
REGRESSORS = ("current", "throttle", "temperature")


#: Share of the samples a regressor must have a value in for ``compensate=auto`` to fit it.
MIN_REGRESSOR_SHARE = 0.9


def _survey_regressors(rec: Recording) -> tuple[list[str], list[str]]:
    """Those of :data:`REGRESSORS` ``compensate=auto`` fits (a value in
    :data:`MIN_REGRESSOR_SHARE` of the samples, not constant; the throttle only without a
    usable current), and each other column it has, with why it was left out."""
    used: list[str] = []
    left_out: list[str] = []
    for name in REGRESSORS if rec.extra is not None else ():
        if name not in rec.extra or (name == "throttle" and "current" in used):
            continue
        values = np.asarray(rec.extra[name], dtype=float)
        finite = values[np.isfinite(values)]
        if finite.size < MIN_REGRESSOR_SHARE * rec.K:
            left_out.append(f"{name} (values in {100 * finite.size / rec.K:.0f} % of the "
                            f"samples, {100 * MIN_REGRESSOR_SHARE:.0f} % needed)")
        elif np.ptp(finite) == 0:
            left_out.append(f"{name} (constant)")
        else:
            used.append(name)
    return used, left_out


def usable_regressors(rec: Recording, wanted: list[str] | None = None) -> list[str]:
    """The regressors to fit: ``wanted`` as given, or (None) those of :data:`REGRESSORS` the
    recording has with values in at least 90 % of its samples and not constant (current
    before throttle: one of them)."""
    return list(wanted) if wanted is not None else _survey_regressors(rec)[0]


def unused_regressors(rec: Recording) -> list[str]:
    """Why each regressor column ``compensate=auto`` leaves out was left out (a value in too
    few samples, or constant), as ``"current (values in 50 % of the samples, 90 % needed)"``;
    the throttle is not listed when the current stands in for it."""
    return _survey_regressors(rec)[1]


def check_regressors(rec: Recording, names: list[str]) -> None:
    """:class:`ValueError` (one line) if the recording lacks one of ``names``."""
    missing = [n for n in names if rec.extra is None or n not in rec.extra]
    if missing:
        have = ", ".join(c for c in REGRESSORS if rec.extra is not None and c in rec.extra)
        raise ValueError(f"compensate: the recording has no {', '.join(missing)} column "
                         f"(it has: {have or 'none of current, throttle, temperature'})")


def time_varying_terms(rec: Recording, names: list[str], static_fit: StaticFit,
                       keep: np.ndarray | None = None) -> HeldOutChoice:
    """:func:`magbench.methods.regressors.held_out_choice` on the samples (``keep``, default
    all) where every regressor in ``names`` has a value.

    Raises
    ------
    ValueError
        If the recording lacks one of ``names``.
    """
    check_regressors(rec, names)
    u = rec.stack(names)
    use = np.isfinite(u).all(axis=1) & (np.ones(rec.K, bool) if keep is None else keep)
    return held_out_choice(rec.y[use], u[use], static_fit)
