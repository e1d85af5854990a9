"""What a flight log adds to a calibration: the compass's mounting rotation.

After the static calibration ``m = A (y - b)`` (the safe gauge, so ``m`` stays in the
compass's own axes), the logged attitude (or, without one, the accelerometer at rest) ranks
the autopilots' standard rotations by how constant the field is in world axes
(:func:`magbench.core.mounting.detect_mounting`).
"""

from __future__ import annotations

import numpy as np

from magbench.core.mounting import MountingResult, detect_mounting
from magbench.core.rotations import quaternion_to_matrix
from magbench.sources.recordings import Recording

__all__ = ["QUATERNION", "mounting_rotation"]

QUATERNION = ["qw", "qx", "qy", "qz"]
ACCEL = ["ax", "ay", "az"]


def mounting_rotation(rec: Recording, A: np.ndarray, b: np.ndarray,
                      keep: np.ndarray | None = None) -> MountingResult | None:
    """The mounting rotation of a recording's compass, or None without attitude or accelerometer.

    Parameters
    ----------
    rec : Recording
        With ``extra`` holding ``qw..qz`` (preferred) or ``ax..az``.
    A, b : ndarray
        The correction ``m = A (y - b)``.
    keep : ndarray of bool, optional
        Samples to use (the calibration's inliers); rows without attitude are left out too.
    """
    if rec.extra is None:
        return None
    base = np.ones(rec.K, bool) if keep is None else np.asarray(keep, bool)
    m = (rec.y - b) @ np.asarray(A).T
    if all(c in rec.extra for c in QUATERNION):
        q = rec.extra[QUATERNION].to_numpy(float)
        use = base & np.isfinite(q).all(axis=1)
        if use.sum() >= 2:
            return detect_mounting(m[use], attitude=quaternion_to_matrix(q[use]))
    if all(c in rec.extra for c in ACCEL):
        a = rec.extra[ACCEL].to_numpy(float)
        use = base & np.isfinite(a).all(axis=1)
        if use.sum() >= 2:
            return detect_mounting(m[use], accel=a[use])
    return None
