"""What a calibration is written as: the JSON file, a C header, ArduPilot compass parameters.

Every format holds the correction in the safe gauge of :mod:`magbench.core.gauge`,

    m = A (y - b),   A = (T T^T)^(-1/2) symmetric positive definite,   b = h,

with ``y`` a raw sample in the recording's units and ``m`` the field in units of its own
magnitude (``||m|| = 1`` for a perfect calibration).

*JSON* (:func:`to_json_dict`, :func:`from_json_dict`). Schema version :data:`SCHEMA_VERSION`:

=============  ============================================================================
key            meaning
=============  ============================================================================
``format``     ``"magbench-calibration"``
``version``    schema version (an integer; a reader refuses a newer one)
``gauge``      ``"m = A (y - b), A symmetric positive definite"``
``units``      what ``y`` and ``b`` are measured in (``m`` is in units of the field magnitude)
``unit``       optional: ``name``, ``gauss_per_unit`` (null if unknown) and ``description``
``A``          3x3 list of rows
``b``          3 values
``T``, ``h``   the model ``y = T m + h`` in the same gauge (``T = A^-1``, ``h = b``)
``columns``    optional: the three input columns the calibration was fitted on
=============  ============================================================================

*Heading-true files* (version 2, written only for a calibration with a known alignment to the
inertial sensors): ``gauge`` is :data:`GAUGE_HEADING_TRUE`, ``A = R S`` with ``S`` symmetric
positive definite and ``R`` the rotation to the IMU's axes, and two more keys, ``R`` (3x3) and
``S`` (3x3); ``T = A^-1``. A reader of version 1 refuses them rather than mistaking ``A``.
The firmware parameter files hold symmetric matrices: from a heading-true calibration they hold
``S`` (turned by the detected standard mounting rotation, if any), and their header says the
rotation left out, the heading error if it is ignored, and the standard rotation to set instead
when one lies within :data:`ORIENT_TOLERANCE_DEG` (:func:`rotation_note`).

Other keys (the method, its verdict, ...) may be added by the writer and are ignored on reading.

*C header* (:func:`c_header`): ``static const float NAME_A[3][3]``, ``NAME_b[3]`` and a
``static inline`` function ``NAME_apply`` computing ``m = A (y - b)`` in float.

The unit of ``y`` (:mod:`magbench.core.units`) is recorded in the JSON (``unit``) and the
header; the firmware files below need it and are refused, in one line, when it is unknown. The
field strength ``F = |det T|^(1/3)`` (the recording's field, in its units) is the same in every
gauge. A firmware that applies a symmetric matrix gets ``F A``, so its corrected field keeps the
local field's strength in its own unit, as its own calibrator's does; in the symmetric gauge
nothing is dropped (a heading-true ``A = R S``: see above).

*ArduPilot* (:func:`ardupilot_params`). ArduPilot's compass driver corrects a raw sample (in
milligauss, in the sensor's axes after the board rotation) as

    corrected = M (s (raw + OFS)),   M = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z],
                                          [ODI_Y, ODI_Z, DIA_Z]]

(``AP_Compass_Backend::correct_field`` in libraries/AP_Compass/AP_Compass_Backend.cpp; the matrix
is the one spelled out in the COMPASS_DIA_* and COMPASS_ODI_* parameter descriptions of
libraries/AP_Compass/AP_Compass.cpp). ``s`` is COMPASS_SCALE, applied only when it lies
in [1/1.5, 1.5] (``Compass::have_scale_factor`` with COMPASS_MAX_SCALE_FACTOR = 1.5 of
AP_Compass_config.h; the parameter's documented @Range is 0 to 1.3). COMPASS_OFS_X/Y/Z are in
milligauss (@Units mGauss) and *added*. So ``OFS = -b`` and ``s M = F A`` in milligauss; we
write ``s = 1`` and ``M = F A`` (``det M = 1``). The second and third compass have their own
sets, COMPASS_OFS2_X ... COMPASS_SCALE2 and COMPASS_OFS3_X ... (``instance`` 1 and 2, as the
``I`` field of the MAG log message numbers them). With a mounting rotation ``M_r``
(:mod:`magbench.core.mounting`, ``v_body = M_r v_sensor``) the file also sets COMPASS_ORIENT
(COMPASS_ORIENT2, COMPASS_ORIENT3), documented in AP_Compass.cpp's parameter table as "the
orientation of the first external compass relative to the vehicle frame", ignored unless the
compass is external (COMPASS_EXTERNAL; an internal compass follows AHRS_ORIENT). ArduPilot turns
the raw sample by it before correcting (``AP_Compass_Backend::rotate_field``, then
``correct_field``), so the offsets and matrix are then written in the vehicle's axes:
``OFS = -M_r b`` and ``M = M_r F A M_r^T`` (still symmetric). The export is refused
(``ValueError`` naming the value) outside the limits ArduPilot's calibrator accepts
(``CompassCalibrator::fit_acceptable`` in CompassCalibrator.cpp): field strength in (150, 950)
mGauss (FIELD_RADIUS_MIN/MAX), offsets below 1800 mGauss (AP_COMPASS_OFFSETS_MAX_DEFAULT, the
default of COMPASS_OFFS_MAX), diagonals in (0.2, 5) and off-diagonals below 1 in magnitude.
File: ``NAME VALUE`` lines (``param load`` of MAVProxy, Mission Planner's "Load from file").
A disturbance proportional to the battery current or the throttle (:class:`MotorCompensation`,
``m = A (y - b - C u)``) is ArduPilot's motor compensation: ``correct_field`` adds
``COMPASS_MOT * u`` *after* the matrix, ``u`` the current in amperes (COMPASS_MOTCT = 2, @Units
mGauss/A) or the throttle from 0 to 1 (COMPASS_MOTCT = 1), so ``MOT = -M M_r k C`` (``k`` mGauss
per file unit); its @Range is -1000 to 1000. COMPASS_MOTCT is one setting for every compass.

*PX4* (:func:`px4_params`). ``calibration::Magnetometer::Correct`` (src/lib/sensor_calibration/
Magnetometer.hpp) applies

    corrected = R (S (raw - OFF)),   S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG],
                                          [YODIAG, ZODIAG, ZSCALE]]

with raw in gauss (``sensor_mag``), OFF = CAL_MAGn_{X,Y,Z}OFF *subtracted*, S symmetric (built
in ``Magnetometer::ParametersUpdate``/``set_offdiagonal`` of Magnetometer.cpp from
CAL_MAGn_{X,Y,Z}SCALE and CAL_MAGn_{X,Y,Z}ODIAG) and R the rotation CAL_MAGn_ROT (external
compasses; an internal one takes the board rotation and ROT = -1). So ``OFF = b`` in gauss and
``S = F A``: PX4's own calibrator also scales to the local field strength. A calibration slot
is used only for the compass whose device id is CAL_MAGn_ID (``FindCalibrationIndex``): pass
``device_id`` (the ULog ``sensor_mag.device_id``) to write it, else the file says that slot
``n`` must already hold this compass's id. PX4's calibrator warns of offsets above 1.3 gauss
(``MAG_MAX_OFFSET_LEN`` of mag_calibration.cpp, saturation); the file says so too. File:
QGroundControl's ``.params`` (its developer guide, "Parameter File Format"): ``#`` comments,
then ``vehicle-id<TAB>component-id<TAB>name<TAB>value<TAB>type`` with the MAV_PARAM_TYPE (9 =
REAL32, 6 = INT32). PX4's power compensation (``Correct`` above, in full
``S ((raw + p COMP) - OFF)``) adds CAL_MAGn_{X,Y,Z}COMP times ``p`` *before* the offset, ``p``
the battery current in kiloamperes (``VehicleMagnetometer::Run`` divides ``current_a`` by 1000;
CAL_MAG_COMP_TYP = 2, battery instance 0) or the throttle from 0 to 1 (CAL_MAG_COMP_TYP = 1),
and only while armed; so ``COMP = -k C``, times 1000 for the current (gauss per kA).

*INAV and Betaflight* (:func:`inav_cli`, :func:`betaflight_cli`) hold offsets in raw counts
and no cross-axis terms, so these files carry ``b`` (rounded to whole counts) and, for INAV,
the diagonal of ``A``, and say what they leave out and the field error of their own
correction on the recording (not the full model's). INAV's ``compassUpdate``
(src/main/sensors/compass.c) computes ``(raw - magzero) * 1024 / maggain`` per axis in the
driver's axes before ``align_mag``; the file sets ``magzero_x/y/z`` and ``maggain_x/y/z`` =
``1024 g / A_ii`` (:func:`inav_gains`). Betaflight's ``compassUpdate`` subtracts ``mag_calibration``
after its sensor alignment, so those offsets are right for a recording in the aligned axes (as
Betaflight's own raw readout shows them). Both need ``units=counts``: the flight controller's
own raw readings, in int16.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from magbench.core.gauge import (
    GAUGE_TEXT,
    HEADING_TRUE,
    SYMMETRIC,
    check_rotation,
    rotation_angle_deg,
    safe_gauge,
    symmetric_T,
)
from magbench.core.model import Calibration
from magbench.core.mounting import ROTATIONS, rotation_matrix
from magbench.core.units import UNKNOWN, Units

__all__ = ["ARDUPILOT_LIMITS", "FIRMWARE_FILES", "FORMAT", "GAUGE", "GAUGE_HEADING_TRUE",
           "MOTOR_REGRESSORS", "PX4_MAX_OFFSET_GAUSS", "SCHEMA_VERSION", "MotorCompensation",
           "ardupilot_param_file",
           "ardupilot_params", "betaflight_cli", "c_header", "field_strength",
           "firmware_files", "from_json_dict", "inav_cli", "inav_correction", "inav_gains",
           "nearest_rotation", "partial_error_pct", "px4_param_file", "px4_params",
           "rotation_note", "to_json_dict"]

FORMAT = "magbench-calibration"
SCHEMA_VERSION = 2
#: The version of a symmetric-gauge file (unchanged since the first schema).
SYMMETRIC_VERSION = 1
GAUGE = GAUGE_TEXT[SYMMETRIC]
GAUGE_HEADING_TRUE = GAUGE_TEXT[HEADING_TRUE]
#: What ArduPilot's calibrator accepts (see the module notes for the source of each).
ARDUPILOT_LIMITS = {"field_mgauss": (150.0, 950.0), "offset_mgauss": 1800.0,
                    "diagonal": (0.2, 5.0), "off_diagonal": 1.0}
_ODI = ((0, 1), (0, 2), (1, 2))          # ODI_X, ODI_Y, ODI_Z positions in M
#: ArduPilot's COMPASS_MOT_* @Range (mGauss/A, or mGauss at full throttle).
ARDUPILOT_MOT_MAX = 1000.0
#: The regressors a firmware's motor compensation holds, in the units of :class:`MotorCompensation`.
MOTOR_REGRESSORS = ("current", "throttle")
#: COMPASS_MOTCT and CAL_MAG_COMP_TYP values of a regressor (module notes).
_ARDUPILOT_MOTCT = {"throttle": 1, "current": 2}
_PX4_COMP_TYP = {"throttle": 1, "current": 2}
#: PX4's power per regressor unit: the current in kA, the throttle as it is.
_PX4_POWER = {"throttle": 1.0, "current": 1e-3}


@dataclass(frozen=True)
class MotorCompensation:
    """A disturbance proportional to the battery current or the throttle.

    The correction with it is ``m = A (y - b - C u)``: ``u`` is the current in amperes
    (``regressor="current"``) or the throttle from 0 to 1 (``"throttle"``), ``C`` the
    disturbance in the recording's units per unit of ``u``, in the sensor's axes.
    """

    regressor: str
    C: np.ndarray

    def __post_init__(self) -> None:
        if self.regressor not in MOTOR_REGRESSORS:
            raise ValueError(f"motor compensation is per current or throttle, got "
                             f"{self.regressor!r}")
        C = np.asarray(self.C, dtype=float).reshape(-1)
        if C.shape != (3,) or not np.isfinite(C).all():
            raise ValueError(f"motor compensation C must be 3 finite numbers, got {self.C!r}")
        object.__setattr__(self, "C", C)


def field_strength(cal: Calibration) -> float:
    """``F = |det T|^(1/3)``: the field strength of the recording in its units (any gauge)."""
    return float(np.cbrt(abs(np.linalg.det(cal.T))))


def to_json_dict(cal: Calibration, *, units: Units | str = UNKNOWN,
                 columns: list | None = None) -> dict:
    """The written file's core (see the module notes for the schema).

    Parameters
    ----------
    cal : Calibration
        Any gauge; it is written in the safe one, heading-true when ``cal`` has an alignment.
    units : Units or str
        What the raw samples (and ``b``) are measured in (a :class:`Units` adds ``unit``).
    columns : list of str, optional
        The input columns the calibration applies to.

    Raises
    ------
    ValueError
        If ``T`` is singular or not finite (such a calibration is never written).
    """
    gauge = safe_gauge(cal.T, cal.h, cal.alignment)
    heading_true = gauge.label == HEADING_TRUE
    shown = units.describe() if isinstance(units, Units) else units
    out = {"format": FORMAT, "version": SCHEMA_VERSION if heading_true else SYMMETRIC_VERSION,
           "gauge": GAUGE_TEXT[gauge.label],
           "units": f"y and b: {shown}; m: units of the field magnitude (|m| = 1)"
                    + ("; m in the IMU's axes" if heading_true else ""),
           "A": gauge.A.tolist(), "b": gauge.b.tolist(),
           "T": symmetric_T(cal.T).tolist(), "h": gauge.b.tolist()}
    if heading_true:
        out |= {"R": cal.alignment.tolist(), "S": safe_gauge(cal.T, cal.h).A.tolist(),
                "T": np.linalg.inv(gauge.A).tolist()}
    if isinstance(units, Units):
        out["unit"] = units.to_dict()
    if columns is not None:
        out["columns"] = [str(c) for c in columns]
    return out


def _matrix(data: dict, key: str, shape: tuple[int, ...]) -> np.ndarray:
    if key not in data:
        raise ValueError(f"calibration file lacks {key!r}; expected the keys A (3x3) and b (3) "
                         f"of '{GAUGE}'")
    try:
        value = np.array(data[key], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"calibration file: {key} must be numbers of shape {shape}") from None
    if value.shape != shape or not np.all(np.isfinite(value)):
        raise ValueError(f"calibration file: {key} must be finite numbers of shape {shape}, got "
                         f"shape {value.shape}")
    return value


def from_json_dict(data: object) -> Calibration:
    """The :class:`Calibration` (safe gauge: ``T = A^-1``, ``h = b``) of a written file.

    Raises
    ------
    ValueError
        Not a magbench calibration, a newer schema version, missing or malformed ``A`` or
        ``b``, or an ``A`` that is not symmetric positive definite; one message each.
    """
    if not isinstance(data, dict):
        raise ValueError(f"calibration file must hold a JSON object, got {type(data).__name__}")
    if data.get("format", FORMAT) != FORMAT:
        raise ValueError(f"calibration file has format {data.get('format')!r}; expected {FORMAT!r}")
    version = data.get("version", SCHEMA_VERSION)
    if not isinstance(version, int) or version > SCHEMA_VERSION:
        raise ValueError(f"calibration file has schema version {version!r}; this magbench reads "
                         f"up to {SCHEMA_VERSION}")
    A = _matrix(data, "A", (3, 3))
    b = _matrix(data, "b", (3,))
    if data.get("gauge") == GAUGE_HEADING_TRUE:
        return _heading_true(data, A, b)
    scale = float(np.abs(A).max())
    if not np.allclose(A, A.T, rtol=0, atol=1e-9 * scale) or \
            np.linalg.eigvalsh(0.5 * (A + A.T)).min() <= 0:
        raise ValueError(f"calibration file: A is not symmetric positive definite ('{GAUGE}'); "
                         "it was not written by magbench's safe gauge")
    return Calibration(np.linalg.inv(0.5 * (A + A.T)), b)


def _heading_true(data: dict, A: np.ndarray, b: np.ndarray) -> Calibration:
    """The calibration of a heading-true file: ``A = R S``, ``R`` a rotation, ``S`` SPD."""
    R = check_rotation(_matrix(data, "R", (3, 3)), "calibration file: R")
    S = R.T @ A
    scale = float(np.abs(S).max())
    if not np.allclose(S, S.T, rtol=0, atol=1e-9 * scale) or \
            np.linalg.eigvalsh(0.5 * (S + S.T)).min() <= 0:
        raise ValueError(f"calibration file: R^T A is not symmetric positive definite "
                         f"('{GAUGE_HEADING_TRUE}')")
    return Calibration(np.linalg.inv(0.5 * (S + S.T)), b, alignment=R)


def _c_float(value: float) -> str:
    # 9 significant digits round-trip every float32; "120f" is not C, so keep a point.
    text = f"{float(value):.9g}"
    return f"{text}f" if any(c in text for c in ".e") else f"{text}.0f"


def _c_floats(values: np.ndarray) -> str:
    return ", ".join(_c_float(v) for v in values)


def c_header(cal: Calibration, name: str = "mag_cal", *, verdict: str = "",
             units: Units = UNKNOWN) -> str:
    """A C header with ``static const float NAME_A[3][3]``, ``NAME_b[3]`` and ``NAME_apply``.

    Parameters
    ----------
    cal : Calibration
        Any gauge; written in the safe one (heading-true when ``cal`` has an alignment).
    name : str
        A C identifier prefixing the arrays, the function and the include guard.
    verdict : str
        A line quoted in the header's comment (e.g. the field-error verdict).
    units : Units
        The unit of ``y`` and ``b``, named in the comment.

    Raises
    ------
    ValueError
        If ``name`` is not a C identifier, or ``T`` is singular or not finite.
    """
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ValueError(f"name must be a C identifier (letters, digits, _), got {name!r}")
    gauge = safe_gauge(cal.T, cal.h, cal.alignment)
    rows = ",\n    ".join("{" + _c_floats(r) + "}" for r in gauge.A)
    comment = [f"magbench calibration: {GAUGE_TEXT[gauge.label]}.",
               f"y and b in {units.describe()}; m: field in units of its magnitude.",
               f"Rotation removed from the method's own correction: {gauge.rotation_deg:.1f} deg"
               + (" (it was a mirror image)" if gauge.mirrored else "") + "."]
    if cal.alignment is not None:
        comment.append("Heading-true: m is in the IMU's axes; the alignment rotation R is "
                       f"{rotation_angle_deg(cal.alignment):.2f} deg.")
    if verdict:
        comment.append(f"Verdict: {' '.join(verdict.split())}")
    guard = f"{name.upper()}_H"
    body = "\n".join(f" * {line.replace('*/', '* /')}" for line in comment)
    return (f"/*\n{body}\n */\n#ifndef {guard}\n#define {guard}\n\n"
            f"static const float {name}_A[3][3] = {{\n    {rows}\n}};\n"
            f"static const float {name}_b[3] = {{{_c_floats(gauge.b)}}};\n\n"
            f"/* m = A (y - b) */\n"
            f"static inline void {name}_apply(const float y[3], float m[3])\n{{\n"
            f"    const float d[3] = {{y[0] - {name}_b[0], y[1] - {name}_b[1], "
            f"y[2] - {name}_b[2]}};\n"
            f"    for (int i = 0; i < 3; ++i) {{\n"
            f"        m[i] = {name}_A[i][0] * d[0] + {name}_A[i][1] * d[1] + "
            f"{name}_A[i][2] * d[2];\n    }}\n}}\n\n#endif /* {guard} */\n")


def _needs_unit(units: Units, firmware: str, unit: str) -> float:
    """Gauss per file unit, or one line saying what ``firmware`` needs."""
    if not units.known:
        raise ValueError(f"{firmware} works in {unit} and the recording's unit is "
                         f"{units.describe()}: pass units=uT, nT, gauss or mgauss, or the size "
                         "of one count (e.g. units=0.0625uT)")
    return float(units.gauss)


def _instance_suffix(instance: int, count: int, firmware: str) -> int:
    if isinstance(instance, bool) or not isinstance(instance, int | np.integer) or \
            not 0 <= instance < count:
        raise ValueError(f"{firmware} has calibration sets for compasses 0 to {count - 1}, "
                         f"got instance {instance!r}")
    return int(instance)


def ardupilot_params(cal: Calibration, units: Units, *, instance: int = 0,
                     rotation: int | None = None,
                     motor: MotorCompensation | None = None) -> dict[str, float]:
    """ArduPilot COMPASS_OFS*, COMPASS_DIA*, COMPASS_ODI*, COMPASS_SCALE* and, with a
    rotation, COMPASS_ORIENT*; with a motor term, COMPASS_MOTCT and COMPASS_MOT* (module notes).

    Parameters
    ----------
    cal : Calibration
        Any gauge; the safe one is exported.
    units : Units
        The recording's unit; ArduPilot works in milligauss, so it must be known.
    instance : int
        The compass, 0 to 2 as the MAG log's ``I`` numbers them (names ``COMPASS_OFS_X``,
        ``COMPASS_OFS2_X``, ``COMPASS_OFS3_X``).
    rotation : int, optional
        The compass's mounting, an id of ArduPilot's ``enum Rotation`` (COMPASS_ORIENT of an
        external compass); the offsets and matrix are then in the vehicle's axes.
    motor : MotorCompensation, optional
        A current or throttle term fitted with ``cal`` (``cal`` is then the time-varying fit's
        ``A``, ``b``); COMPASS_MOTCT is one setting for all compasses.

    Returns
    -------
    dict
        Parameter name -> value, in ArduPilot's convention
        ``corrected = M (COMPASS_SCALE (raw + OFS)) + MOT u``, equal to ``F A (y - b - C u)``
        in mGauss (``M_r F A (...)`` with a rotation, raw turned by COMPASS_ORIENT first);
        COMPASS_ORIENT* and COMPASS_MOTCT are ints.

    Raises
    ------
    ValueError
        An unknown unit, an instance ArduPilot has no parameters for, a value outside what
        ArduPilot accepts (naming the value and the range), a rotation that is not an id
        of its enum, or a singular ``T``; one line each.
    """
    k = 1000.0 * _needs_unit(units, "ArduPilot", "milligauss")   # mGauss per file unit
    n = _instance_suffix(instance, 3, "ArduPilot")
    gauge = safe_gauge(cal.T, cal.h)
    F = field_strength(cal)
    Mr = np.eye(3) if rotation is None else rotation_matrix(_rotation_id(rotation))
    M = Mr @ (F * gauge.A) @ Mr.T         # dimensionless: F A in any unit
    offsets = -k * Mr @ gauge.b
    _check_ardupilot(k * F, offsets, M)
    s = "" if n == 0 else str(n + 1)
    out = {f"COMPASS_OFS{s}_{a}": float(v) for a, v in zip("XYZ", offsets, strict=True)}
    out |= {f"COMPASS_DIA{s}_{a}": float(M[i, i]) for i, a in enumerate("XYZ")}
    out |= {f"COMPASS_ODI{s}_{a}": float(M[i, j]) for a, (i, j) in zip("XYZ", _ODI, strict=True)}
    out[f"COMPASS_SCALE{s}"] = 1.0
    if rotation is not None:
        out[f"COMPASS_ORIENT{s}"] = int(rotation)
    if motor is not None:
        mot = -M @ Mr @ (k * motor.C)
        if np.abs(mot).max() > ARDUPILOT_MOT_MAX:
            raise ValueError(f"COMPASS_MOT values {np.round(mot, 1).tolist()} exceed ArduPilot's "
                             f"range of +-{ARDUPILOT_MOT_MAX:g} (mGauss per A or at full "
                             "throttle)")
        out["COMPASS_MOTCT"] = _ARDUPILOT_MOTCT[motor.regressor]
        out |= {f"COMPASS_MOT{s}_{a}": float(v) for a, v in zip("XYZ", mot, strict=True)}
    return out


def _rotation_id(rotation: object) -> int:
    """A rotation id of the autopilots' enum (:data:`magbench.core.mounting.ROTATIONS`)."""
    if isinstance(rotation, bool) or not isinstance(rotation, int | np.integer) or \
            int(rotation) not in ROTATIONS:
        raise ValueError(f"ArduPilot rotation must be an id of its Rotation enum "
                         f"(COMPASS_ORIENT, 0 to {max(ROTATIONS)}), got {rotation!r}")
    return int(rotation)


def _check_ardupilot(field: float, offsets: np.ndarray, M: np.ndarray,
                     firmware: str = "ArduPilot",
                     names: tuple[str, str] = ("COMPASS_DIA", "COMPASS_ODI")) -> None:
    lo, hi = ARDUPILOT_LIMITS["field_mgauss"]
    if not lo < field < hi:
        raise ValueError(f"field strength {field:.4g} mGauss is outside {firmware}'s accepted "
                         f"({lo:g}, {hi:g}) mGauss (the Earth's field is 220-670 mGauss: check "
                         "the units= key)")
    worst = float(np.abs(offsets).max())
    if worst >= ARDUPILOT_LIMITS["offset_mgauss"]:
        raise ValueError(f"offset {worst:.4g} mGauss exceeds ArduPilot's COMPASS_OFFS_MAX "
                         f"default of {ARDUPILOT_LIMITS['offset_mgauss']:g} mGauss")
    lo, hi = ARDUPILOT_LIMITS["diagonal"]
    diag = np.diag(M)
    if not np.all((diag > lo) & (diag < hi)):
        raise ValueError(f"{names[0]} values {np.round(diag, 4).tolist()} are outside "
                         f"{firmware}'s accepted ({lo:g}, {hi:g})")
    odi = np.array([M[i, j] for i, j in _ODI])
    if np.abs(odi).max() >= ARDUPILOT_LIMITS["off_diagonal"]:
        raise ValueError(f"{names[1]} values {np.round(odi, 4).tolist()} exceed {firmware}'s "
                         f"accepted magnitude {ARDUPILOT_LIMITS['off_diagonal']:g}")


def ardupilot_param_file(params: dict[str, float], comment: str = "") -> str:
    """``NAME VALUE`` lines (ArduPilot's .parm format, '#' comments) for ``param load``."""
    return "\n".join([*_comment(comment), *(f"{k} {v:.9g}" for k, v in params.items())]) + "\n"


def _comment(text: str, mark: str = "#") -> list[str]:
    return [f"{mark} {line}" for line in text.splitlines() if line.strip()]


#: PX4's calibrator warns above this offset (gauss): the sensor saturates in some directions.
PX4_MAX_OFFSET_GAUSS = 1.3
#: MAV_PARAM_TYPE of QGroundControl's .params files.
_REAL32, _INT32 = 9, 6


def px4_params(cal: Calibration, units: Units, *, instance: int = 0,
               device_id: int | None = None, rotation: int | None = None,
               motor: MotorCompensation | None = None) -> dict[str, float]:
    """PX4 CAL_MAGn_* parameters (module notes): offsets in gauss, the symmetric scale matrix.

    Parameters
    ----------
    cal : Calibration
        Any gauge; the safe one is exported.
    units : Units
        The recording's unit; PX4 works in gauss, so it must be known.
    instance : int
        The calibration slot ``n`` of CAL_MAGn_*, 0 to 3.
    device_id : int, optional
        The compass's device id (ULog ``sensor_mag.device_id``), written as CAL_MAGn_ID.
    rotation : int, optional
        PX4's rotation enum value for CAL_MAGn_ROT (external compasses).
    motor : MotorCompensation, optional
        A current or throttle term fitted with ``cal``: CAL_MAG_COMP_TYP (one setting for all
        compasses) and CAL_MAGn_{X,Y,Z}COMP.

    Returns
    -------
    dict
        Name -> value; CAL_MAGn_ID, CAL_MAGn_ROT and CAL_MAG_COMP_TYP are ints (INT32), the
        rest floats: ``S ((raw + p COMP) - OFF)`` equals ``F A (y - b - C u)`` in gauss.

    Raises
    ------
    ValueError
        An unknown unit, an instance outside 0-3, a rotation outside PX4's enum range, or a
        singular ``T``; one line each.
    """
    k = _needs_unit(units, "PX4", "gauss")
    n = _instance_suffix(instance, 4, "PX4")
    gauge = safe_gauge(cal.T, cal.h)
    S = field_strength(cal) * gauge.A
    # PX4's parameters carry no range of their own: the field strength is checked against
    # the Earth's, and the matrix against the limits ArduPilot's calibrator applies.
    _check_ardupilot(1000.0 * k * field_strength(cal), np.zeros(3), S, "PX4",
                     (f"CAL_MAG{n}_*SCALE", f"CAL_MAG{n}_*ODIAG"))
    out: dict[str, float] = {}
    if device_id is not None:
        out[f"CAL_MAG{n}_ID"] = int(device_id)
    out |= {f"CAL_MAG{n}_{a}OFF": float(k * v) for a, v in zip("XYZ", gauge.b, strict=True)}
    out |= {f"CAL_MAG{n}_{a}SCALE": float(S[i, i]) for i, a in enumerate("XYZ")}
    out |= {f"CAL_MAG{n}_{a}ODIAG": float(S[i, j]) for a, (i, j) in zip("XYZ", _ODI, strict=True)}
    if rotation is not None:
        if isinstance(rotation, bool) or not isinstance(rotation, int | np.integer) or \
                not -1 <= rotation < 64:
            raise ValueError(f"PX4 rotation must be an entry of its Rotation enum (CAL_MAGn_ROT, "
                             f"an integer from -1), got {rotation!r}")
        out[f"CAL_MAG{n}_ROT"] = int(rotation)
    if motor is not None:
        comp = -k * motor.C / _PX4_POWER[motor.regressor]
        out["CAL_MAG_COMP_TYP"] = _PX4_COMP_TYP[motor.regressor]
        out |= {f"CAL_MAG{n}_{a}COMP": float(v) for a, v in zip("XYZ", comp, strict=True)}
    return out


def px4_param_file(params: dict[str, float], comment: str = "") -> str:
    """QGroundControl's .params text (module notes) of ``params`` for vehicle 1, component 1.

    Floats are written with 9 significant digits, which a float32 parameter reads back exactly.
    """
    rows = [f"1\t1\t{k}\t{v:d}\t{_INT32}" if isinstance(v, int) else
            f"1\t1\t{k}\t{v:.9g}\t{_REAL32}" for k, v in params.items()]
    offsets = [abs(v) for k, v in params.items() if k.endswith("OFF")]
    note = (f"\nPX4 warns of offsets above {PX4_MAX_OFFSET_GAUSS:g} gauss (the sensor saturates "
            "in some directions)" if offsets and max(offsets) > PX4_MAX_OFFSET_GAUSS else "")
    slot = next((k[:8] for k in params), "CAL_MAGn")
    ident = ("" if any(k.endswith("_ID") for k in params) else
             f"\n{slot}_ID is not set here: the slot must already belong to this compass")
    head = _comment(f"Onboard parameters for Vehicle 1\n{comment}{note}{ident}")
    return "\n".join([*head, "#", "# Vehicle-Id Component-Id Name Value Type", *rows]) + "\n"


_INT16 = (-32768, 32767)


def _raw_offsets(cal: Calibration, units: Units, firmware: str) -> list[int]:
    if not units.counts:
        raise ValueError(f"{firmware} holds offsets in the flight controller's raw counts and "
                         f"the recording is in {units.describe()}: record the flight "
                         "controller's own raw readings and pass units=counts")
    b = safe_gauge(cal.T, cal.h).b
    values = [round(float(v)) for v in b]
    if not all(_INT16[0] <= v <= _INT16[1] for v in values):
        raise ValueError(f"{firmware} offsets {values} do not fit its int16 settings")
    return values


_OFFSETS_ONLY = ("holds offsets only: the soft-iron and scale correction A of "
                 "calibration.json is not applied")


def _offsets_file(cal: Calibration, units: Units, firmware: str, comment: str, how: str,
                  settings: Callable[[list[int]], list[str]], what: str = _OFFSETS_ONLY) -> str:
    """A CLI file of ``set`` lines holding ``b`` in raw counts, saying what is not applied."""
    zero = _raw_offsets(cal, units, firmware)
    head = _comment(f"{comment}\n{firmware}'s compass model {what}; {how}\npaste "
                    f"into the {firmware} CLI")
    return "\n".join([*head, *settings(zero), "save"]) + "\n"


#: INAV's unit gain: ``maggain`` 1024 means no scale.
INAV_UNIT_GAIN = 1024


def inav_gains(cal: Calibration) -> list[int]:
    """INAV's ``maggain_x/y/z`` holding the diagonal of ``A`` (module notes): INAV scales
    axis ``i`` by ``1024 / maggain_i``, so ``maggain_i = 1024 g / A_ii`` with ``g`` the
    geometric mean of the diagonal (gains about 1024, as INAV's own calibrator writes).

    Raises
    ------
    ValueError
        A gain outside INAV's setting range (1 to 32767); one line.
    """
    d = np.diag(safe_gauge(cal.T, cal.h).A)
    gains = [round(INAV_UNIT_GAIN * float(np.cbrt(np.prod(d))) / float(v)) for v in d]
    if not all(1 <= g <= _INT16[1] for g in gains):
        raise ValueError(f"INAV maggain values {gains} are outside its range 1-{_INT16[1]}")
    return gains


def inav_correction(zero: list[int], gains: list[int], y: np.ndarray) -> np.ndarray:
    """What INAV computes from raw samples ``y`` with ``magzero`` and ``maggain``:
    ``(y - zero) * 1024 / gain`` per axis."""
    return (np.asarray(y, float) - np.asarray(zero, float)) * INAV_UNIT_GAIN / \
        np.asarray(gains, float)


def inav_cli(cal: Calibration, units: Units, comment: str = "") -> str:
    """INAV CLI ``set`` lines: ``magzero_x/y/z`` = ``b`` in raw counts and ``maggain_x/y/z``
    the diagonal of ``A`` (:func:`inav_gains`); the cross-axis terms are not held.

    Raises
    ------
    ValueError
        The recording is not in raw counts, or an offset does not fit an int16, or a gain is
        out of range; one line.
    """
    gains = inav_gains(cal)
    return _offsets_file(
        cal, units, "INAV", comment, "it computes (raw - magzero) * 1024 / maggain per axis in "
        "the driver's raw axes before align_mag: maggain holds the diagonal of A",
        lambda zero: [*(f"set magzero_{a} = {v}" for a, v in zip("xyz", zero, strict=True)),
                      *(f"set maggain_{a} = {g}" for a, g in zip("xyz", gains, strict=True))],
        what="holds offsets and per-axis gains only: the cross-axis terms of calibration.json's "
             "A are not applied")


def betaflight_cli(cal: Calibration, units: Units, comment: str = "") -> str:
    """Betaflight CLI ``set mag_calibration = x,y,z`` with ``b`` in raw counts.

    Raises
    ------
    ValueError
        The recording is not in raw counts, or an offset does not fit an int16; one line.
    """
    return _offsets_file(
        cal, units, "Betaflight", comment, "it subtracts mag_calibration after the sensor "
        "alignment, so the recording must be in the aligned axes",
        lambda zero: [f"set mag_calibration = {zero[0]},{zero[1]},{zero[2]}"])


#: The firmware files :func:`firmware_files` writes, in order.
FIRMWARE_FILES = ("ardupilot.param", "px4.params", "inav.txt", "betaflight.txt")


def firmware_files(cal: Calibration, units: Units, *, instance: int = 0,
                   device_id: int | None = None, rotation: int | None = None,
                   motor: MotorCompensation | None = None,
                   comment: str = "",
                   samples: np.ndarray | None = None) -> tuple[dict[str, str], dict[str, str]]:
    """Every firmware file the calibration can be written as, and why the others cannot.

    Parameters
    ----------
    cal : Calibration
        Any gauge; the safe one is exported.
    units : Units
        The recording's unit (ArduPilot and PX4 need it known, INAV and Betaflight need counts).
    instance : int
        The compass (ArduPilot's set 0-2, PX4's slot 0-3).
    device_id : int, optional
        PX4's CAL_MAGn_ID.
    rotation : int, optional
        The detected mounting (:mod:`magbench.core.mounting`): ArduPilot's COMPASS_ORIENT and
        PX4's CAL_MAGn_ROT, both for an external compass; None writes neither.
    motor : MotorCompensation, optional
        A current or throttle term fitted with ``cal``: ArduPilot's COMPASS_MOT* and PX4's
        CAL_MAGn_*COMP; INAV's and Betaflight's files say they cannot hold it.
    comment : str
        Lines put at the head of each file (e.g. the verdict). A heading-true ``cal`` (with an
        alignment ``R``, ``A = R S``) adds to the ArduPilot and PX4 files exactly what they do
        not hold (:func:`rotation_note`).
    samples : ndarray, optional
        Raw samples (file units); the INAV and Betaflight files then quote the field error of
        their own correction on them (:func:`partial_error_pct`), not the full model's.

    Returns
    -------
    written : dict
        File name -> text, for :data:`FIRMWARE_FILES` that could be written.
    refused : dict
        File name -> one-line reason for the others (equal reasons have equal text, so a
        caller can say them once).
    """
    written: dict[str, str] = {}
    refused: dict[str, str] = {}
    physical = (f"unit {units.describe()}: pass units=uT, nT, gauss, mgauss or one count's "
                "size, e.g. units=0.0625uT")
    raw = "they take the flight controller's raw counts: units=counts"
    orient = rot = ""
    if rotation is not None:
        name = ROTATIONS[_rotation_id(rotation)][0]
        orient = (f" after COMPASS_ORIENT = {name}, the detected mounting (used only for an "
                  "external compass: COMPASS_EXTERNAL)")
        rot = (f", then turned by CAL_MAGn_ROT = {name}, the detected mounting (external "
               "compass; an internal one takes the board rotation)")
    mot = offsets_only = ""
    px4_formula = "S (raw - OFF)"
    if motor is not None:
        u = "the current in A" if motor.regressor == "current" else "the throttle (0 to 1)"
        mot = f" + COMPASS_MOT * u, u {u}"
        p = "the current in kA" if motor.regressor == "current" else u
        px4_formula = f"S ((raw + p COMP) - OFF), p {p} (while armed)"
        offsets_only = (f"\nthe {motor.regressor} term C of calibration.json's time_varying is "
                        "not applied either (no such setting)")
    turned = rotation_note(cal, rotation)
    turned_raw = rotation_note(cal, None, "offsets in the sensor's axes")
    partial = {}
    if samples is not None and units.counts:
        with np.errstate(all="ignore"):
            for name, apply in (("inav.txt", _inav_apply), ("betaflight.txt", _offsets_apply)):
                try:
                    p95 = float(np.percentile(partial_error_pct(apply(cal, samples)), 95))
                except ValueError:
                    continue
                partial[name] = (f"\nthis file's own correction (not calibration.json's full "
                                 f"model) gives a field magnitude error of {p95:.2f} % (95th "
                                 "percentile) on the recording")
    makers = {
        "ardupilot.param": (units.known, physical, lambda: ardupilot_param_file(
            ardupilot_params(cal, units, instance=instance, rotation=rotation, motor=motor),
            f"magbench calibration for ArduPilot: corrected = M (COMPASS_SCALE (raw + OFS)){mot}"
            f", raw in milligauss{orient}\n{comment}{turned}")),
        "px4.params": (units.known, physical, lambda: px4_param_file(
            px4_params(cal, units, instance=instance, device_id=device_id, rotation=rotation,
                       motor=motor),
            f"magbench calibration for PX4: corrected = {px4_formula}, raw in gauss{rot}"
            f"\n{comment}{turned}")),
        "inav.txt": (units.counts, raw, lambda: inav_cli(
            cal, units, comment + offsets_only + partial.get("inav.txt", "") + turned_raw)),
        "betaflight.txt": (units.counts, raw, lambda: betaflight_cli(
            cal, units, comment + offsets_only + partial.get("betaflight.txt", "") + turned_raw)),
    }
    for name, (possible, why, make) in makers.items():
        if not possible:
            refused[name] = why
            continue
        try:
            written[name] = make()
        except ValueError as exc:
            refused[name] = str(exc)
    return written, refused


#: A standard rotation within this angle of a heading-true alignment is suggested for it.
ORIENT_TOLERANCE_DEG = 5.0


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def nearest_rotation(R: np.ndarray) -> tuple[int, float]:
    """The standard rotation id (:data:`magbench.core.mounting.ROTATIONS`) nearest to ``R``
    and the angle between them (deg)."""
    best = min(ROTATIONS, key=lambda r: _angle_deg(R @ rotation_matrix(r).T))
    return best, _angle_deg(R @ rotation_matrix(best).T)


def rotation_note(cal: Calibration, rotation: int | None = None, holds: str = "S") -> str:
    """For a heading-true ``cal`` (``A = R S``): the header lines of a firmware file, which
    holds ``S`` turned by the standard ``rotation`` (or by nothing), saying the rotation left
    out, ``R M_r^T``, the heading error if it is ignored, and the standard rotation to set
    instead when one is within :data:`ORIENT_TOLERANCE_DEG`; "" for a symmetric ``cal``.
    ``holds``: what the file holds of the correction, in words."""
    if cal.alignment is None:
        return ""
    R = np.asarray(cal.alignment, float)
    Mr = np.eye(3) if rotation is None else rotation_matrix(_rotation_id(rotation))
    left = _angle_deg(R @ Mr.T)
    if left < 1e-6:
        return ""
    text = ("\ncalibration.json's A = R S also turns the field to the IMU's axes (R); this file "
            f"holds {holds}" + (f" turned by {ROTATIONS[int(rotation)][0]}" if rotation is not None
                         else "") + f": the remaining {left:.2f} deg rotation is not "
            f"representable here (heading error up to {left:.2f} deg if ignored)")
    best, off = nearest_rotation(R)
    if off <= ORIENT_TOLERANCE_DEG and (rotation is None or best != int(rotation)) and best:
        text += (f"; the nearest standard rotation is {ROTATIONS[best][0]} ({off:.2f} deg from "
                 "R): set it as COMPASS_ORIENT (ArduPilot, external compass), CAL_MAGn_ROT "
                 "(PX4, external) or the board rotation AHRS_ORIENT / SENS_BOARD_ROT "
                 f"(internal), leaving {off:.2f} deg")
    return text


def partial_error_pct(corrected: np.ndarray) -> np.ndarray:
    """The field magnitude error (%) of a correction that does not scale to the field: the
    norms against their median (a firmware that holds offsets only leaves the scale as is)."""
    norms = np.linalg.norm(np.asarray(corrected, float), axis=1)
    norms = norms[np.isfinite(norms)]
    if norms.size == 0:
        raise ValueError("no finite sample")
    return 100.0 * np.abs(norms / np.median(norms) - 1.0)


def _offsets_apply(cal: Calibration, y: np.ndarray) -> np.ndarray:
    return np.asarray(y, float) - np.round(safe_gauge(cal.T, cal.h).b)


def _inav_apply(cal: Calibration, y: np.ndarray) -> np.ndarray:
    zero = [round(float(v)) for v in safe_gauge(cal.T, cal.h).b]
    return inav_correction(zero, inav_gains(cal), y)
