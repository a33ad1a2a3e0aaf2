"""scenes.constants against astropy.constants / astropy.units / ERFA, and used from one place.

astropy's values are the IAU and CODATA ones the docstrings cite; the DE421 mass parameters are
checked against the DE421 header's Gaussian constant instead (astropy has only nominal GMs, given
to 7-8 digits, which DE421 must match within their rounding).
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import astropy.constants as const
import astropy.units as u
import erfa
from astropy.time import Time

from skynav.scenes import constants as K

ROOT = Path(__file__).resolve().parents[2]
ROOMS = ("scenes", "renderer", "datasets", "pipeline", "calibration", "skynav")


def test_exact_values_equal_astropy():
    assert K.AU_KM * 1e3 == const.au.to_value(u.m)  # IAU 2012 B2
    assert K.C_M_S == const.c.to_value(u.m / u.s) and K.C_KM_S * 1e3 == K.C_M_S  # SI, exact
    assert K.PLANCK_J_S == const.h.to_value(u.J * u.s)  # SI 2019, exact
    assert K.SOLAR_LUMINOSITY_W == const.L_sun.to_value(u.W)  # IAU 2015 B3 nominal
    assert K.SECONDS_PER_DAY == u.day.to(u.s)
    assert K.JULIAN_YEAR_S == u.yr.to(u.s)  # astropy's year is the Julian year
    assert K.J2000_JD == Time("J2000", scale="tt").jd


def test_solar_constant_is_the_nominal_luminosity_over_4_pi_au2():
    # IAU 2015 B3 derives L = 4 pi (1 au)^2 S with S = 1361 W/m^2 and gives L to 4 digits (3.828e26):
    # the relation holds to half a unit of that last digit, 1.3e-4
    s_from_l = K.SOLAR_LUMINOSITY_W / (4.0 * math.pi * (K.AU_KM * 1e3) ** 2)
    assert abs(s_from_l / K.SOLAR_CONSTANT_W_M2 - 1.0) < 1.3e-4


def test_de421_gm_against_astropy_nominal_values():
    # astropy's IAU 2015 nominal GM_sun (8 digits) and GM_earth (7 digits): DE421's must agree
    # within half a unit of the nominal value's last digit
    gm_sun_km = const.GM_sun.to_value(u.km**3 / u.s**2)
    gm_earth_km = const.GM_earth.to_value(u.km**3 / u.s**2)
    assert abs(K.GM_SUN_KM3_S2 - gm_sun_km) <= 0.5e-7 * gm_sun_km
    assert abs(K.GM_KM3_S2["earth"] - gm_earth_km) <= 0.05
    assert K.GM_SUN_KM3_S2 == K.GM_KM3_S2["sun"]


def test_de421_gm_sun_is_the_gaussian_constant_in_de421_units():
    # DE421 header: GMS = k^2 AU^3/day^2 with k = 0.01720209895 (IAU 1976) and its AU; Folkner et
    # al. (2009) quote the km^3/s^2 value to 1e-3
    k = 0.01720209895
    gm = k**2 * K.AU_DE421_KM**3 / K.SECONDS_PER_DAY**2
    assert abs(gm - K.GM_SUN_KM3_S2) < 1e-3


def test_obliquity_against_erfa_iau2006():
    eps0 = erfa.obl06(K.J2000_JD, 0.0)
    assert abs(eps0 - K.OBLIQUITY_J2000_RAD) < 1e-15  # rad; the IAU 2006 constant term


def _literals():
    """Numeric values written in scenes.constants (the values that must not be repeated)."""
    values = {v for v in vars(K).values() if isinstance(v, float)}
    values |= set(K.GM_KM3_S2.values())
    values |= {84381.406, 365.25 * 86400.0, 1360.8, 1.32712440041e11}  # also the superseded ones
    return values


def test_constants_are_written_in_one_place():
    # Scan the package's source for numeric literals equal to a constant's value: each must be
    # imported from scenes.constants instead (tests keep their own literals: they are references).
    values = _literals()
    offenders = []
    for room in ROOMS:
        for path in sorted((ROOT / room).rglob("*.py")):
            if path == ROOT / "scenes" / "constants.py":
                continue
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if (isinstance(node, ast.Constant) and type(node.value) in (int, float)
                        and node.value in values):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    assert not offenders, "constants written outside scenes/constants.py:\n" + "\n".join(offenders)
