"""The autopilots' standard sensor rotations and the detection of a compass's mounting.

The rotations are ArduPilot's ``enum Rotation`` (``libraries/AP_Math/rotations.h``), ids 0 to
40, which are also MAVLink's ``MAV_SENSOR_ORIENTATION`` and PX4's ``enum Rotation``
(``src/lib/conversion/rotation.h``, the values of ``CAL_MAGn_ROT``); 40
(``ROTATION_ROLL_90_PITCH_315``) is ArduPilot's ``ROTATION_MAX_AUTO_ROTATION``, the last one its
compass calibration tries. Each is named by its Euler angles, and ``v_body = M v_sensor`` with
``M = Rz(yaw) Ry(pitch) Rx(roll)``: ArduPilot's ``Vector3::rotate`` equals
``Matrix3::from_euler`` of the named angles (its test ``test_rotations.cpp``, whose odd entry 38
is roll 90, pitch 68.8, yaw 293.3; PX4's table rounds it to 68 and 293).

Detection follows ArduPilot's ``CompassCalibrator::calculate_orientation``: for each rotation,
the corrected samples are turned into world axes with the logged attitude, and the variance of
that world-frame field about its mean is the rotation's cost; the best rotation is the one of
least cost, and its confidence is the cost of the second best (the best among rotations that
are not the same matrix) over its own. ArduPilot accepts a new rotation above a confidence of
2 (``variance_threshold``); PX4's ``CAL_MAG_ROT_AUTO`` compares with the internal compass
instead. Without an attitude, the accelerometer at rest gives the down direction, and the cost
is the variance of the dip (the cosine between down and the field), which is constant for the
right rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magbench.core.quaternions import MatrixView, UnitRows, blocks, quat_span_deg
from magbench.core.rotations import euler_zyx_to_matrix, span_deg

__all__ = ["AUTO_ROTATIONS", "MIN_CONFIDENCE", "ROTATIONS", "MountingResult", "detect_mounting",
           "rotation_matrix"]

#: ``id -> (name, roll, pitch, yaw)`` in degrees, ArduPilot's ``enum Rotation`` 0-43.
ROTATIONS: dict[int, tuple[str, float, float, float]] = {
    0: ("ROTATION_NONE", 0, 0, 0), 1: ("ROTATION_YAW_45", 0, 0, 45),
    2: ("ROTATION_YAW_90", 0, 0, 90), 3: ("ROTATION_YAW_135", 0, 0, 135),
    4: ("ROTATION_YAW_180", 0, 0, 180), 5: ("ROTATION_YAW_225", 0, 0, 225),
    6: ("ROTATION_YAW_270", 0, 0, 270), 7: ("ROTATION_YAW_315", 0, 0, 315),
    8: ("ROTATION_ROLL_180", 180, 0, 0), 9: ("ROTATION_ROLL_180_YAW_45", 180, 0, 45),
    10: ("ROTATION_ROLL_180_YAW_90", 180, 0, 90), 11: ("ROTATION_ROLL_180_YAW_135", 180, 0, 135),
    12: ("ROTATION_PITCH_180", 0, 180, 0), 13: ("ROTATION_ROLL_180_YAW_225", 180, 0, 225),
    14: ("ROTATION_ROLL_180_YAW_270", 180, 0, 270),
    15: ("ROTATION_ROLL_180_YAW_315", 180, 0, 315), 16: ("ROTATION_ROLL_90", 90, 0, 0),
    17: ("ROTATION_ROLL_90_YAW_45", 90, 0, 45), 18: ("ROTATION_ROLL_90_YAW_90", 90, 0, 90),
    19: ("ROTATION_ROLL_90_YAW_135", 90, 0, 135), 20: ("ROTATION_ROLL_270", 270, 0, 0),
    21: ("ROTATION_ROLL_270_YAW_45", 270, 0, 45), 22: ("ROTATION_ROLL_270_YAW_90", 270, 0, 90),
    23: ("ROTATION_ROLL_270_YAW_135", 270, 0, 135), 24: ("ROTATION_PITCH_90", 0, 90, 0),
    25: ("ROTATION_PITCH_270", 0, 270, 0), 26: ("ROTATION_PITCH_180_YAW_90", 0, 180, 90),
    27: ("ROTATION_PITCH_180_YAW_270", 0, 180, 270),
    28: ("ROTATION_ROLL_90_PITCH_90", 90, 90, 0), 29: ("ROTATION_ROLL_180_PITCH_90", 180, 90, 0),
    30: ("ROTATION_ROLL_270_PITCH_90", 270, 90, 0),
    31: ("ROTATION_ROLL_90_PITCH_180", 90, 180, 0),
    32: ("ROTATION_ROLL_270_PITCH_180", 270, 180, 0),
    33: ("ROTATION_ROLL_90_PITCH_270", 90, 270, 0),
    34: ("ROTATION_ROLL_180_PITCH_270", 180, 270, 0),
    35: ("ROTATION_ROLL_270_PITCH_270", 270, 270, 0),
    36: ("ROTATION_ROLL_90_PITCH_180_YAW_90", 90, 180, 90),
    37: ("ROTATION_ROLL_90_YAW_270", 90, 0, 270),
    38: ("ROTATION_ROLL_90_PITCH_68_YAW_293", 90, 68.8, 293.3),
    39: ("ROTATION_PITCH_315", 0, 315, 0), 40: ("ROTATION_ROLL_90_PITCH_315", 90, 315, 0),
    41: ("ROTATION_PITCH_7", 0, 7, 0), 42: ("ROTATION_ROLL_45", 45, 0, 0),
    43: ("ROTATION_ROLL_315", 315, 0, 0),
}

#: The rotations tried, as ArduPilot's compass calibration does (up to
#: ``ROTATION_MAX_AUTO_ROTATION``); 41-43 are board rotations it never guesses.
AUTO_ROTATIONS: tuple[int, ...] = tuple(range(41))

#: Below this confidence (second-best cost over best) no rotation is reported: ArduPilot's
#: ``variance_threshold``.
MIN_CONFIDENCE = 2.0

#: Fewest attitude-tagged samples a detection uses (ArduPilot collects 300 before fitting).
MIN_SAMPLES = 20


def rotation_matrix(rotation: int) -> np.ndarray:
    """``M`` of ``v_body = M v_sensor`` for a standard rotation id (``KeyError`` if unknown)."""
    _, roll, pitch, yaw = ROTATIONS[int(rotation)]
    return euler_zyx_to_matrix(*np.deg2rad([roll, pitch, yaw]))


@dataclass(frozen=True)
class MountingResult:
    """The ranked rotations of one detection.

    Attributes
    ----------
    rotation : int or None
        The detected id, None when refused.
    best, second : int
        The least-cost rotation and the best of those that are a different matrix.
    confidence : float
        ``cost[second] / cost[best]`` (ArduPilot's ``_orientation_confidence``).
    costs : dict
        ``id -> cost`` of every rotation tried.
    basis : str
        ``attitude`` or ``accelerometer``.
    samples : int
        Samples used.
    attitude_span_deg : float
        Largest angle between the first attitude and any later one (accelerometer: between
        down directions), how much the recording turned.
    reason : str
        Why a rotation was refused ("" when one is reported).
    """

    rotation: int | None
    best: int
    second: int
    confidence: float
    costs: dict
    basis: str
    samples: int
    attitude_span_deg: float
    reason: str = ""

    @property
    def name(self) -> str | None:
        return None if self.rotation is None else ROTATIONS[self.rotation][0]

    def to_dict(self) -> dict:
        """JSON-ready: the id and name (None when refused), best, second and confidence."""
        return {"id": self.rotation, "name": self.name, "best": self.best,
                "best_name": ROTATIONS[self.best][0], "second": self.second,
                "second_name": ROTATIONS[self.second][0],
                "confidence": float(self.confidence), "min_confidence": MIN_CONFIDENCE,
                "basis": self.basis, "samples": self.samples,
                "attitude_span_deg": float(self.attitude_span_deg), "reason": self.reason or None}

    def line(self) -> str:
        """One line for a person: the rotation and its confidence, or why none is given."""
        ranked = (f"best {ROTATIONS[self.best][0]} ({self.best}), second "
                  f"{ROTATIONS[self.second][0]} ({self.second}), confidence "
                  f"{self.confidence:.1f}")
        if self.rotation is None:
            return f"mounting rotation: not detected ({self.reason}; {ranked})"
        turned = "the attitude" if self.basis == "attitude" else "the down direction"
        return (f"mounting rotation: {self.name} (id {self.rotation}) from the {self.basis}, "
                f"confidence {self.confidence:.1f} (second best {ROTATIONS[self.second][0]}); "
                f"{self.samples} samples, {turned} turned through "
                f"{self.attitude_span_deg:.0f} deg")


def _same(a: int, b: int) -> bool:
    """Whether two ids are the same matrix (26 and 27 repeat 14 and 10, as ArduPilot notes)."""
    return bool(np.allclose(rotation_matrix(a), rotation_matrix(b), atol=1e-6))


#: Attitude rows turned at a time: the candidates' world fields of one block are
#: ``(n, BLOCK_ROWS, 3)``, never ``(n, K, 3)`` (41 candidates of a long log took gigabytes).
BLOCK_ROWS = 1 << 13


def _costs_attitude(m: np.ndarray, R: np.ndarray | MatrixView,
                    rotations: tuple[int, ...]) -> np.ndarray:
    """Variance of the world-frame field ``R_k M m_k`` about its mean, per rotation (two
    passes over blocks of rows: the mean, then the squared deviations)."""
    M = np.stack([rotation_matrix(r) for r in rotations])          # (n, 3, 3)
    K = len(m)
    total = np.zeros((len(rotations), 3))
    for rows in blocks(K, BLOCK_ROWS):
        total += np.einsum("kij,njl,kl->nki", R[rows], M, m[rows]).sum(axis=1)
    mean = (total / K)[:, None, :]
    squares = np.zeros(len(rotations))
    for rows in blocks(K, BLOCK_ROWS):
        world = np.einsum("kij,njl,kl->nki", R[rows], M, m[rows])
        squares += ((world - mean) ** 2).sum(axis=2).sum(axis=1)
    return squares / K


def _costs_dip(m: np.ndarray, down: np.ndarray, rotations: tuple[int, ...]) -> np.ndarray:
    """Variance of the dip cosine ``<down_k, M m_k / |m_k|>``, per rotation."""
    M = np.stack([rotation_matrix(r) for r in rotations])
    unit = m / np.linalg.norm(m, axis=1, keepdims=True)
    dip = np.einsum("ki,nij,kj->nk", down, M, unit)
    return dip.var(axis=1)


def detect_mounting(m: np.ndarray, *, attitude: np.ndarray | UnitRows | None = None,
                    accel: np.ndarray | None = None, rotations: tuple[int, ...] = AUTO_ROTATIONS,
                    min_confidence: float = MIN_CONFIDENCE) -> MountingResult:
    """Rank the standard rotations by how constant the field is in world axes.

    Parameters
    ----------
    m : ndarray, shape (K, 3)
        Calibrated field in the compass's own axes (``A (y - b)``; hard iron removed).
    attitude : ndarray, shape (K, 3, 3) or (K, 4), optional
        Body-to-world attitude at each sample, as matrices or unit quaternions (scalar
        first; turned into matrices a block at a time; or a :class:`UnitRows` view of
        them). Preferred when given.
    accel : ndarray, shape (K, 3), optional
        Accelerometer in body axes (specific force: ``-g`` at rest), used without an attitude;
        only samples whose magnitude is within 5 % of the median are used (at rest).
    rotations : tuple of int
        Candidate ids (default: ArduPilot's auto-rotation set, 0-40).
    min_confidence : float
        Refuse below this ratio of the second-best cost to the best.

    Returns
    -------
    MountingResult
        The detected rotation, or None with the reason (too few samples, a confidence below
        ``min_confidence``, as when the attitude barely changed).

    Raises
    ------
    ValueError
        If neither ``attitude`` nor ``accel`` is given, or shapes disagree.
    """
    m = np.asarray(m, dtype=float)
    if attitude is not None:
        # a UnitRows view is read a block at a time, as a (K, 4) array is
        R = attitude if isinstance(attitude, UnitRows) else np.asarray(attitude, dtype=float)
        if R.shape not in ((m.shape[0], 3, 3), (m.shape[0], 4)):
            raise ValueError(f"attitude must have shape ({m.shape[0]}, 3, 3) or "
                             f"({m.shape[0]}, 4), got {R.shape}")
        view = MatrixView(R) if R.shape[1:] == (4,) else R
        costs, basis, n = _costs_attitude(m, view, rotations), "attitude", len(m)
        span = quat_span_deg(view) if isinstance(view, MatrixView) else span_deg(R)
    elif accel is not None:
        a = np.asarray(accel, dtype=float)
        if a.shape != m.shape:
            raise ValueError(f"accel must have shape {m.shape}, got {a.shape}")
        norm = np.linalg.norm(a, axis=1)
        rest = np.abs(norm - np.median(norm)) < 0.05 * np.median(norm)
        down = -a[rest] / norm[rest, None]
        costs, basis, n = _costs_dip(m[rest], down, rotations), "accelerometer", int(rest.sum())
        span = float(np.degrees(np.arccos(np.clip(down @ down[0], -1.0, 1.0)).max())) if n else 0.0
    else:
        raise ValueError("detect_mounting needs an attitude or an accelerometer")
    order = np.argsort(costs, kind="stable")
    # A repeated matrix (26, 27) is reported by its first id, whichever rounding won.
    best = min(r for r in rotations if _same(r, rotations[order[0]]))
    second_i = next(i for i in order[1:] if not _same(best, rotations[i]))
    second = rotations[second_i]
    floor = np.finfo(float).tiny
    confidence = float(costs[second_i] / max(costs[order[0]], floor))
    table = {r: float(c) for r, c in zip(rotations, costs, strict=True)}
    reason = ""
    if n < MIN_SAMPLES:
        reason = f"{n} samples with an attitude, at least {MIN_SAMPLES} are needed"
    elif confidence < min_confidence:
        reason = (f"confidence {confidence:.2f} is below {min_confidence:g}: the {basis} turned "
                  f"through {span:.0f} deg; turn the vehicle through several orientations")
    return MountingResult(None if reason else best, best, second, confidence, table, basis, n,
                          span, reason)
