"""The geomagnetic field expected at a site and date (IGRF via ``ppigrf``), what a fit's field
strength and inclination are checked against (the unit a recording's strength matches is
:func:`magbench.core.units.infer_units`'s).

The International Geomagnetic Reference Field (Alken et al., Earth Planets Space 73:49, 2021,
and its 14th generation) gives the main field ``(X, Y, Z)`` = north, east, down in nT at a
geodetic latitude, longitude and height above the WGS-84 ellipsoid; from it the total
intensity ``F = |(X, Y, Z)|``, the inclination ``I = atan2(Z, H)`` (positive down, ``H`` the
horizontal intensity) and the declination ``D = atan2(Y, X)`` (positive east). Local crustal
anomalies and magnetic storms are not modelled (typically up to a few hundred nT and tenths of
a degree).
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass

import numpy as np

from magbench.core.units import GAUSS_PER

__all__ = ["ExpectedField", "Site", "expected_field", "parse_date", "parse_location"]


@dataclass(frozen=True)
class Site:
    """Geodetic latitude and longitude (degrees, north and east positive) and height above
    the WGS-84 ellipsoid (metres)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0


@dataclass(frozen=True)
class ExpectedField:
    """The model field at a site: north, east, down components and what follows from them."""

    north_nT: float
    east_nT: float
    down_nT: float
    model: str

    @property
    def strength_nT(self) -> float:
        return math.sqrt(self.north_nT**2 + self.east_nT**2 + self.down_nT**2)

    @property
    def strength_gauss(self) -> float:
        return self.strength_nT * GAUSS_PER["nt"]

    @property
    def inclination_deg(self) -> float:
        return math.degrees(math.atan2(self.down_nT, math.hypot(self.north_nT, self.east_nT)))

    @property
    def declination_deg(self) -> float:
        return math.degrees(math.atan2(self.east_nT, self.north_nT))


def parse_location(text: object) -> Site:
    """``"lat,lon"`` or ``"lat,lon,alt"`` (degrees, degrees, metres) as a :class:`Site`.

    Raises
    ------
    ValueError
        Not two or three numbers, or latitude outside [-90, 90], longitude outside
        [-180, 360], height outside [-1000 m, 100 km].
    """
    parts = list(text) if isinstance(text, (list, tuple)) else str(text).split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise ValueError(f"location must be 'lat,lon' or 'lat,lon,alt' (degrees, degrees, "
                         f"metres above the WGS-84 ellipsoid), got {text!r}")
    lat, lon, alt = (*values, 0.0)[:3]
    if not (-90 <= lat <= 90 and -180 <= lon <= 360 and -1e3 <= alt <= 1e5):
        raise ValueError(f"location {text!r}: latitude must be in [-90, 90], longitude in "
                         "[-180, 360] and height in [-1000, 100000] m")
    return Site(lat, lon, alt)


def parse_date(text: object) -> dt.date:
    """An ISO date (``2024-05-17``) or a ``datetime.date``.

    Raises
    ------
    ValueError
        Not an ISO date, or outside IGRF's 1900-2030 span.
    """
    if isinstance(text, dt.date):
        date = text
    else:
        try:
            date = dt.date.fromisoformat(str(text).strip())
        except ValueError:
            raise ValueError(f"date must be an ISO date such as 2024-05-17, got {text!r}") \
                from None
    if not dt.date(1900, 1, 1) <= date <= dt.date(2030, 12, 31):
        raise ValueError(f"date {date} is outside the geomagnetic model's span (1900-2030)")
    return date


def expected_field(site: Site, date: dt.date) -> ExpectedField:
    """The IGRF main field at ``site`` on ``date`` (``ppigrf.igrf``, geodetic coordinates).

    Parameters
    ----------
    site : Site
        Where (see :func:`parse_location`).
    date : datetime.date
        When (see :func:`parse_date`).

    Returns
    -------
    ExpectedField
        North, east and down components in nT, with strength, inclination and declination.
    """
    import ppigrf

    east, north, up = ppigrf.igrf(site.lon_deg, site.lat_deg, site.alt_m / 1e3,
                                  dt.datetime(date.year, date.month, date.day))
    version = getattr(ppigrf, "__version__", "")
    return ExpectedField(float(np.squeeze(north)), float(np.squeeze(east)),
                         -float(np.squeeze(up)), f"IGRF (ppigrf {version})".replace(" )", ")"))
