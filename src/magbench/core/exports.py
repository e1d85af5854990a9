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
``A``          3x3 list of rows
``b``          3 values
``T``, ``h``   the model ``y = T m + h`` in the same gauge (``T = A^-1``, ``h = b``)
``columns``    optional: the three input columns the calibration was fitted on
=============  ============================================================================

*Heading-true files* (version 2, written only for a calibration with a known alignment to the
inertial sensors): ``gauge`` is :data:`GAUGE_HEADING_TRUE`, ``A = R S`` with ``S`` symmetric
positive definite and ``R`` the rotation to the IMU's axes, and two more keys, ``R`` (3x3) and
``S`` (3x3); ``T = A^-1``. A reader of version 1 refuses them rather than mistaking ``A``.

Other keys (the method, its verdict, ...) may be added by the writer and are ignored on reading.

*C header* (:func:`c_header`): ``static const float NAME_A[3][3]``, ``NAME_b[3]`` and a
``static inline`` function ``NAME_apply`` computing ``m = A (y - b)`` in float.

*ArduPilot* (:func:`ardupilot_params`). ArduPilot's compass driver corrects a raw sample (in
milligauss, in the sensor's axes after the board rotation) as

    corrected = M (s (raw + OFS)),   M = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z],
                                          [ODI_Y, ODI_Z, DIA_Z]]

(``AP_Compass_Backend::correct_field`` in libraries/AP_Compass/AP_Compass_Backend.cpp; the matrix
is the one spelled out in the COMPASS_DIA_* and COMPASS_ODI_* parameter descriptions of
libraries/AP_Compass/AP_Compass_Params.cpp). ``s`` is COMPASS_SCALE, applied only when it lies
in [1/1.5, 1.5] (``Compass::have_scale_factor`` with COMPASS_MAX_SCALE_FACTOR = 1.5 of
AP_Compass_config.h; the parameter's documented @Range is 0 to 1.3). COMPASS_OFS_X/Y/Z are in
milligauss (@Units mGauss). Because ArduPilot's ``M`` is symmetric, the safe gauge maps onto it
exactly: ``OFS = -b`` and ``s M = F A`` with ``F = |det T|^(1/3)`` the field strength, so the
corrected field keeps the recording's magnitude in milligauss as ArduPilot's own calibrator does;
we write ``s = 1`` and ``M = F A`` (``det M = 1``). The export is refused (``ValueError`` naming
the value) outside the limits ArduPilot's calibrator accepts (``CompassCalibrator::fit_acceptable``
in CompassCalibrator.cpp): field strength in (150, 950) mGauss (FIELD_RADIUS_MIN/MAX), offsets
below 1800 mGauss (AP_COMPASS_OFFSETS_MAX_DEFAULT, the default of COMPASS_OFFS_MAX), diagonals in
(0.2, 5) and off-diagonals below 1 in magnitude.
"""

from __future__ import annotations

import math
import re

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

__all__ = ["ARDUPILOT_LIMITS", "FORMAT", "GAUGE", "GAUGE_HEADING_TRUE", "SCHEMA_VERSION",
           "ardupilot_param_file", "ardupilot_params", "c_header", "from_json_dict",
           "to_json_dict"]

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


def to_json_dict(cal: Calibration, *, units: str = "as recorded",
                 columns: list | None = None) -> dict:
    """The written file's core (see the module notes for the schema).

    Parameters
    ----------
    cal : Calibration
        Any gauge; it is written in the safe one, heading-true when ``cal`` has an alignment.
    units : str
        What the raw samples (and ``b``) are measured in.
    columns : list of str, optional
        The input columns the calibration applies to.

    Raises
    ------
    ValueError
        If ``T`` is singular or not finite (such a calibration is never written).
    """
    gauge = safe_gauge(cal.T, cal.h, cal.alignment)
    heading_true = gauge.label == HEADING_TRUE
    out = {"format": FORMAT, "version": SCHEMA_VERSION if heading_true else SYMMETRIC_VERSION,
           "gauge": GAUGE_TEXT[gauge.label],
           "units": f"y and b: {units}; m: units of the field magnitude (|m| = 1)"
                    + ("; m in the IMU's axes" if heading_true else ""),
           "A": gauge.A.tolist(), "b": gauge.b.tolist(),
           "T": symmetric_T(cal.T).tolist(), "h": gauge.b.tolist()}
    if heading_true:
        S = safe_gauge(cal.T, cal.h).A
        out |= {"R": cal.alignment.tolist(), "S": S.tolist(),
                "T": np.linalg.inv(gauge.A).tolist()}
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
    try:
        R = check_rotation(_matrix(data, "R", (3, 3)), "calibration file: R")
    except ValueError as exc:
        raise ValueError(str(exc)) from None
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


def c_header(cal: Calibration, name: str = "mag_cal", *, verdict: str = "") -> str:
    """A C header with ``static const float NAME_A[3][3]``, ``NAME_b[3]`` and ``NAME_apply``.

    Parameters
    ----------
    cal : Calibration
        Any gauge; written in the safe one (heading-true when ``cal`` has an alignment).
    name : str
        A C identifier prefixing the arrays, the function and the include guard.
    verdict : str
        A line quoted in the header's comment (e.g. the field-error verdict).

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
               "y: raw sample in the recording's units; m: field in units of its magnitude.",
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


def ardupilot_params(cal: Calibration, *, mgauss_per_unit: float = 1.0) -> dict[str, float]:
    """ArduPilot COMPASS_OFS_*, COMPASS_DIA_*, COMPASS_ODI_* and COMPASS_SCALE (module notes).

    Parameters
    ----------
    cal : Calibration
        Any gauge; the symmetric one is exported (ArduPilot's matrix is symmetric, so an
        alignment cannot be written here; ArduPilot sets the board rotation by COMPASS_ORIENT).
    mgauss_per_unit : float
        Milligauss per unit of the recording (1 if recorded in mGauss, 1000 for gauss, 10 for
        microtesla); ArduPilot works in milligauss.

    Returns
    -------
    dict
        Parameter name -> value, in ArduPilot's convention
        ``corrected = M (COMPASS_SCALE (raw + OFS))``, equal to ``F A (y - b)`` in mGauss.

    Raises
    ------
    ValueError
        When a value lies outside what ArduPilot accepts (naming the value and the range), or
        ``T`` is singular or not finite.
    """
    if not (math.isfinite(mgauss_per_unit) and mgauss_per_unit > 0):
        raise ValueError(f"mgauss_per_unit must be a positive number, got {mgauss_per_unit!r}")
    gauge = safe_gauge(cal.T, cal.h)
    field = mgauss_per_unit * float(np.cbrt(abs(np.linalg.det(cal.T))))
    M = field * gauge.A / mgauss_per_unit          # F A in mGauss: A_mg = A / k, F_mg = k F
    offsets = -mgauss_per_unit * gauge.b
    _check_ardupilot(field, offsets, M)
    out = {f"COMPASS_OFS_{a}": float(v) for a, v in zip("XYZ", offsets, strict=True)}
    out |= {f"COMPASS_DIA_{a}": float(M[i, i]) for i, a in enumerate("XYZ")}
    out |= {f"COMPASS_ODI_{a}": float(M[i, j]) for a, (i, j) in zip("XYZ", _ODI, strict=True)}
    out["COMPASS_SCALE"] = 1.0
    return out


def _check_ardupilot(field: float, offsets: np.ndarray, M: np.ndarray) -> None:
    lo, hi = ARDUPILOT_LIMITS["field_mgauss"]
    if not lo < field < hi:
        raise ValueError(f"field strength {field:.4g} mGauss is outside ArduPilot's accepted "
                         f"({lo:g}, {hi:g}) mGauss; ArduPilot needs the recording in milligauss "
                         "(convert it, or pass mgauss_per_unit to magbench.core.exports."
                         "ardupilot_params: 1000 for gauss, 10 for microtesla)")
    worst = float(np.abs(offsets).max())
    if worst >= ARDUPILOT_LIMITS["offset_mgauss"]:
        raise ValueError(f"offset {worst:.4g} mGauss exceeds ArduPilot's COMPASS_OFFS_MAX "
                         f"default of {ARDUPILOT_LIMITS['offset_mgauss']:g} mGauss")
    lo, hi = ARDUPILOT_LIMITS["diagonal"]
    diag = np.diag(M)
    if not np.all((diag > lo) & (diag < hi)):
        raise ValueError(f"COMPASS_DIA values {np.round(diag, 4).tolist()} are outside "
                         f"ArduPilot's accepted ({lo:g}, {hi:g})")
    odi = np.array([M[i, j] for i, j in _ODI])
    if np.abs(odi).max() >= ARDUPILOT_LIMITS["off_diagonal"]:
        raise ValueError(f"COMPASS_ODI values {np.round(odi, 4).tolist()} exceed ArduPilot's "
                         f"accepted magnitude {ARDUPILOT_LIMITS['off_diagonal']:g}")


def ardupilot_param_file(params: dict[str, float], comment: str = "") -> str:
    """``NAME VALUE`` lines (ArduPilot's .parm format, '#' comments) for ``param load``."""
    head = [f"# {line}" for line in comment.splitlines() if line.strip()]
    return "\n".join([*head, *(f"{k} {v:.9g}" for k, v in params.items())]) + "\n"
