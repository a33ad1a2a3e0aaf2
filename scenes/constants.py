"""Physical and astronomical constants: the one place each value is written.

Core module: floats only. Every other module of skynav imports its constants from here (a test,
``tests/scenes/test_constants.py``, scans the source for the literal values elsewhere), and the
values are checked against ``astropy.constants`` / ``astropy.units`` / ERFA where those have them.

Which value, when sources differ:

* Mass parameters (GM) are the **DE421** ones, because positions come from the DE421 kernel and a
  force model is only consistent with the ephemeris it integrates against. The SPK file that
  ``skyfield-data`` installs carries no constants (its comment area is the NIOSPK log only), so the
  values are quoted from Folkner, Williams & Boggs (2009), "The Planetary and Lunar Ephemeris
  DE 421", IPN Progress Report 42-178, Table 4 (km^3/s^2). They are the header's AU^3/day^2 values
  converted with DE421's own astronomical unit, 149597870.6996262 km (:data:`AU_DE421_KM`), not
  with the IAU 2012 au; e.g. ``GMS = k^2 = 0.01720209895^2 AU^3/day^2`` gives 132712440040.9446.
* Solar irradiance and luminosity are the IAU 2015 Resolution B3 nominal values (Prsa et al. 2016,
  AJ 152, 41): total solar irradiance 1361 W m^-2 (this replaced Kopp & Lean's 1360.8 +- 0.5,
  which the nominal value rounds), luminosity 3.828e26 W = 4 pi (1 au)^2 x 1361 W m^-2.
"""

from __future__ import annotations

import math
from types import MappingProxyType

__all__ = [
    "ARCSEC_RAD",
    "AU_KM",
    "AU_DE421_KM",
    "C_KM_S",
    "C_M_S",
    "PLANCK_J_S",
    "GM_KM3_S2",
    "GM_SUN_KM3_S2",
    "SOLAR_CONSTANT_W_M2",
    "SOLAR_LUMINOSITY_W",
    "J2000_JD",
    "SECONDS_PER_DAY",
    "JULIAN_YEAR_S",
    "OBLIQUITY_J2000_RAD",
]

AU_KM = 149597870.700
"""Astronomical unit, km (IAU 2012 Resolution B2: exactly 149597870700 m)."""

AU_DE421_KM = 149597870.6996262
"""DE421's astronomical unit, km (the ``AU`` of the DE421 header; Folkner et al. 2009). Used only
to state how the DE421 mass parameters below were converted; distances use :data:`AU_KM`."""

C_M_S = 299792458.0
"""Speed of light in vacuum, m/s (exact, SI definition of the metre, CGPM 1983)."""

C_KM_S = 299792.458
"""Speed of light in vacuum, km/s (exact)."""

PLANCK_J_S = 6.62607015e-34
"""Planck constant, J s (exact, SI 2019 redefinition; CODATA 2018)."""

GM_KM3_S2 = MappingProxyType({
    "sun": 132712440040.944,
    "mercury": 22032.090,
    "venus": 324858.592,
    "earth": 398600.436,
    "moon": 4902.800,
    "mars": 42828.376,
    "jupiter": 126712764.8,
    "saturn": 37940585.2,
    "uranus": 5794548.6,
    "neptune": 6836535.0,
})
"""DE421 mass parameters, km^3/s^2 (Folkner et al. 2009, IPN PR 42-178, Table 4; see the module
docstring). Mars and Jupiter..Neptune are whole systems (planet + moons), as their DE421 positions
are system barycentres. Read-only mapping; the key order is the force model's default body order."""

GM_SUN_KM3_S2 = GM_KM3_S2["sun"]
"""Heliocentric gravitational constant, km^3/s^2 (DE421). The TDB-compatible IERS 2010 value
1.32712440041e11 differs by 4.2e-13 relative."""

SOLAR_CONSTANT_W_M2 = 1361.0
"""Total solar irradiance at 1 au, W m^-2 (IAU 2015 Resolution B3 nominal value)."""

SOLAR_LUMINOSITY_W = 3.828e26
"""Nominal solar luminosity, W (IAU 2015 Resolution B3)."""

J2000_JD = 2451545.0
"""The J2000.0 epoch, Julian date; skynav's time origin is JD 2451545.0 **TDB** (IAU 1976/1994:
J2000.0 is JD 2451545.0 TT; TDB - TT stays below 2 ms)."""

SECONDS_PER_DAY = 86400.0
"""Seconds per day (the day of Julian dates and of the ephemerides' TDB), s."""

ARCSEC_RAD = math.pi / (180.0 * 3600.0)
"""One second of arc, rad."""

JULIAN_YEAR_S = 365.25 * SECONDS_PER_DAY
"""Julian year, s (IAU: 365.25 days; the time unit of Hipparcos proper motions)."""

OBLIQUITY_J2000_RAD = math.radians(84381.406 / 3600.0)
"""Obliquity of the ecliptic at J2000, rad (IAU 2006 precession, Capitaine et al. 2003:
84381.406 arcsec). Ecliptic J2000 axes are ICRS rotated about x by it."""
