"""The unit a recording is in, and a field strength given with its unit.

A magnetometer file holds numbers; what one of them is worth decides whether a firmware's
parameters can be written (ArduPilot works in milligauss, PX4 in gauss, INAV and Betaflight in
the flight controller's raw counts). :func:`parse_units` reads the ``units`` key:

* a physical unit: ``uT``, ``nT``, ``gauss`` (``G``), ``mgauss`` (``mG``), ``T``, ``mT``;
* ``counts``: raw readings whose size is unknown;
* a count with its size: ``0.0625uT`` (one count is 0.0625 uT; a BNO055 gives 16 counts per
  uT), ``0.92mgauss`` (an HMC5883L at a gain of 1090 counts per gauss);
* nothing (``null``): the unit is unknown, and no firmware file that needs it is written.

1 gauss = 100 uT = 1e5 nT = 1000 mgauss = 1e-4 T.

*The Earth's field as a unit check* (:func:`unit_check`). At the surface the main field lies
between about 22 uT (South Atlantic) and 67 uT (near the magnetic poles): :data:`EARTH_FIELD_UT`.
A fitted field strength outside that range, widened by :data:`EARTH_MARGIN` for local
disturbance and scale error, in a declared physical unit means the unit is wrong, and no
firmware file may be written from it. The physical units are at least ten times apart and the
widened range spans less than a factor of five, so a magnitude fits at most one of them; an
undeclared unit is *inferred* when one fits (and said). Raw counts (``units=counts``) have no
size to check, but an int16 magnetometer's count is at most a few tenths of a uT (the coarsest
common gains give over a hundred counts for the Earth's field), so a field of fewer than
:data:`MIN_COUNTS_FIELD` "counts" is a physical unit given as counts.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

__all__ = [
    "EARTH_FIELD_UT",
    "EARTH_MARGIN",
    "GAUSS_PER",
    "MIN_COUNTS_FIELD",
    "UNKNOWN",
    "UnitCheck",
    "Units",
    "earth_unit",
    "infer_units",
    "parse_field",
    "parse_units",
    "unit_check",
]

#: Gauss per unit (the canonical keys).
GAUSS_PER = {"gauss": 1.0, "mgauss": 1e-3, "ut": 1e-2, "nt": 1e-5, "mt": 10.0, "t": 1e4}
#: Spellings matched without regard to case, and the symbols whose case is the unit.
_ANY_CASE = {"gauss": "gauss", "mgauss": "mgauss", "milligauss": "mgauss", "ut": "ut",
             "µt": "ut", "microtesla": "ut", "nt": "nt", "nanotesla": "nt", "tesla": "t",
             "millitesla": "mt"}
_EXACT = {"T": "t", "mT": "mt", "G": "gauss", "Ga": "gauss", "mG": "mgauss", "mGa": "mgauss"}
#: How each unit is printed.
_SHOWN = {"gauss": "gauss", "mgauss": "mGauss", "ut": "uT", "nt": "nT", "mt": "mT", "t": "T"}
_NUMBER_UNIT = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-zµ]+)\s*")


@dataclass(frozen=True)
class Units:
    """What one unit of a recording is worth.

    Attributes
    ----------
    name : str
        ``uT``, ``nT``, ``gauss``, ``mGauss``, ``T``, ``mT``, ``counts`` or ``""`` (unknown).
    gauss : float or None
        Gauss per unit of the file; None when unknown (raw counts of unknown size included).
    count : str
        For counts of a stated size, that size as given (e.g. ``"0.0625 uT"``), else ``""``.
    """

    name: str = ""
    gauss: float | None = None
    count: str = ""

    @property
    def known(self) -> bool:
        """Whether a value can be converted to gauss."""
        return self.gauss is not None

    @property
    def counts(self) -> bool:
        """Whether the file holds raw counts (of known size or not)."""
        return self.name == "counts"

    def describe(self) -> str:
        """The unit in words, e.g. ``uT``, ``counts of 0.0625 uT``, ``unknown``."""
        if self.counts:
            return f"counts of {self.count}" if self.count else "counts (size unknown)"
        return self.name or "unknown"

    def to_dict(self) -> dict:
        """The JSON form: name, gauss per unit (None if unknown) and the description."""
        return {"name": self.name or None, "gauss_per_unit": self.gauss,
                "description": self.describe()}

    @classmethod
    def from_dict(cls, data: dict | None) -> Units:
        """The inverse of :meth:`to_dict` (unknown for None)."""
        if not data or not data.get("name"):
            return UNKNOWN
        described = str(data.get("description", ""))
        count = described.removeprefix("counts of ") if described.startswith("counts of ") else ""
        return cls(str(data["name"]), data.get("gauss_per_unit"), count)

    def show(self, value: float) -> str:
        """``value`` (in file units) with its unit: ``0.532 gauss``, ``851 counts (0.532
        gauss)``, ``851 counts``, ``0.532 (file units, unit unknown)``."""
        if self.counts:
            return f"{value:.4g} counts" + (f" ({value * self.gauss:.4g} gauss)" if self.known
                                           else "")
        if not self.name:
            return f"{value:.4g} (file units, unit unknown)"
        return f"{value:.4g} {self.name}"


UNKNOWN = Units()


def _unit(text: str) -> str | None:
    """The canonical key of a unit name, or None."""
    return _EXACT.get(text) or _ANY_CASE.get(text.lower())


_EXPECTED = ("uT, nT, gauss, mgauss, counts, or the size of one count such as 0.0625uT "
             "(16 counts per uT)")


def parse_units(value: object) -> Units:
    """The ``units`` key (module notes): a unit, ``counts``, a count's size, or None.

    Raises
    ------
    ValueError
        For anything else, in one line naming what is accepted.
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return UNKNOWN
    if not isinstance(value, str):
        raise ValueError(f"units must be one of {_EXPECTED}, got {value!r}")
    text = value.strip()
    if text.lower() == "counts":
        return Units("counts")
    key = _unit(text)
    if key is not None:
        return Units(_SHOWN[key], GAUSS_PER[key])
    match = _NUMBER_UNIT.fullmatch(text)
    key = _unit(match.group(2)) if match else None
    if key is None:
        raise ValueError(f"units must be one of {_EXPECTED}, got {value!r}")
    size = float(match.group(1))
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"units: the size of one count must be positive, got {value!r}")
    return Units("counts", size * GAUSS_PER[key], f"{size:g} {_SHOWN[key]}")


def parse_field(value: object, units: Units) -> float | None:
    """The ``field_strength`` key in the file's units: a number (file units) or a number with
    a unit (``48uT``, ``0.48gauss``), converted through ``units``; None if not given.

    Raises
    ------
    ValueError
        Not a positive number, an unknown unit, or a unit given while the file's unit is
        unknown (no conversion exists); one line each.
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    if isinstance(value, int | float) and not isinstance(value, bool):
        number, key = float(value), None
    else:
        match = _NUMBER_UNIT.fullmatch(str(value))
        key = _unit(match.group(2)) if match else None
        if key is None:
            raise ValueError(f"field_strength must be a number in the file's unit or a number "
                             f"with a unit (e.g. 48uT, 0.48gauss), got {value!r}")
        number = float(match.group(1))
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f"field_strength must be positive, got {value!r}")
    if key is None:
        return number
    if not units.known:
        raise ValueError(f"field_strength={value} has a unit but the file's unit is "
                         f"{units.describe()}: give units= too (e.g. units=uT), or the field "
                         "in the file's own units")
    return number * GAUSS_PER[key] / units.gauss


def infer_units(strength: float, expected_gauss: float, tol: float = 0.25) -> Units:
    """The physical unit in which a measured field strength matches an expected one (e.g. the
    geomagnetic model's at the site) within ``tol`` (relative); :data:`UNKNOWN` when none does
    (raw counts, or a disturbed site).

    Parameters
    ----------
    strength : float
        The fit's field strength, in the file's units.
    expected_gauss : float
        The field expected there, gauss.
    tol : float
        Relative mismatch allowed (the units are at least ten times apart, so at most one
        matches for ``tol`` < 0.8).
    """
    if not (math.isfinite(strength) and strength > 0 and expected_gauss > 0):
        return UNKNOWN
    for key, gauss in GAUSS_PER.items():
        if abs(strength * gauss / expected_gauss - 1.0) <= tol:
            return Units(_SHOWN[key], gauss)
    return UNKNOWN


#: The Earth's main field at the surface, uT (minimum and maximum, module notes).
EARTH_FIELD_UT = (22.0, 67.0)
#: Relative widening of :data:`EARTH_FIELD_UT` before a unit is refused or inferred.
EARTH_MARGIN = 0.2
#: Fewest raw counts a magnetometer gives for the Earth's field (module notes).
MIN_COUNTS_FIELD = 100.0
#: The units an undeclared file is inferred to be in, most common first.
_INFERRED = ("ut", "gauss", "mgauss", "nt", "t")


def _earth_range_ut() -> tuple[float, float]:
    low, high = EARTH_FIELD_UT
    return low * (1 - EARTH_MARGIN), high * (1 + EARTH_MARGIN)


def earth_unit(strength: float) -> Units:
    """The one physical unit in which ``strength`` lies in the Earth's (widened) range, or
    :data:`UNKNOWN` when none does (module notes: at most one can)."""
    if not (math.isfinite(strength) and strength > 0):
        return UNKNOWN
    low, high = _earth_range_ut()
    for key in _INFERRED:
        if low <= strength * GAUSS_PER[key] * 100.0 <= high:
            return Units(_SHOWN[key], GAUSS_PER[key])
    return UNKNOWN


@dataclass(frozen=True)
class UnitCheck:
    """What :func:`unit_check` decided.

    Attributes
    ----------
    units : Units
        The unit to write the calibration in (the declared one, or the inferred one).
    fail : str
        One line when the field strength is impossible in the declared unit, else ``""``.
    note : str
        One line saying an inference (or why none was made), else ``""``.
    inferred : bool
        Whether ``units`` was inferred rather than declared.
    """

    units: Units
    fail: str = ""
    note: str = ""
    inferred: bool = False


def _likely(strength: float) -> str:
    found = earth_unit(strength)
    if found.known:
        return f"it fits {found.name} (pass units={found.name})"
    return ("it fits no physical unit: raw counts? (pass units=counts, or one count's size "
            "such as units=0.0625uT)")


def unit_check(strength: float, units: Units) -> UnitCheck:
    """Check a fitted field strength (file units) against the Earth's field (module notes).

    Parameters
    ----------
    strength : float
        The calibration's field strength ``|det T|^(1/3)`` in the file's units.
    units : Units
        The declared unit (:data:`UNKNOWN` when not given).

    Returns
    -------
    UnitCheck
        A declared unit in which the field is impossible gives ``fail`` naming the likely
        unit; an unknown unit is replaced by the one the magnitude fits, if any.
    """
    low, high = _earth_range_ut()
    earth = f"the Earth's field is {EARTH_FIELD_UT[0]:g}-{EARTH_FIELD_UT[1]:g} uT"
    if units.known:
        ut = strength * units.gauss * 100.0
        if low <= ut <= high:
            return UnitCheck(units)
        shown = units.show(strength) + ("" if units.name == "uT" else f" = {ut:.4g} uT")
        return UnitCheck(units, fail=f"field strength {shown}, but {earth}: "
                                     f"the file is not in {units.describe()}; {_likely(strength)}")
    if units.counts:
        if strength >= MIN_COUNTS_FIELD:
            return UnitCheck(units)
        return UnitCheck(units, fail=f"field strength {strength:.4g} counts is too few for a "
                                     f"magnetometer's raw counts (at least {MIN_COUNTS_FIELD:g} "
                                     f"for the Earth's field); {_likely(strength)}")
    found = earth_unit(strength)
    if found.known:
        return UnitCheck(found, note=f"units: inferred {found.name} from the field strength "
                                     f"{strength:.4g} ({earth}); pass units= if that is wrong "
                                     "(units=counts for raw readings)", inferred=True)
    return UnitCheck(units, note=f"units: unknown, and the field strength {strength:.4g} fits "
                                 f"no physical unit ({earth}): raw counts? pass units=counts, or "
                                 "one count's size such as units=0.0625uT")
