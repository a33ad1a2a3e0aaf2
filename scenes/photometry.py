"""Visual (Johnson V) magnitudes of the planets and the Moon, and the geometry they need.

Pure NumPy core. Distances km, angles rad at the interface; the phase laws themselves are
written in degrees as published.

Sources
-------
* Planets: Mallama, A. & Hilton, J. L. (2018), "Computing apparent planetary magnitudes for The
  Astronomical Almanac", Astronomy and Computing 25, 10-24 (arXiv:1808.01973), equations 1-17.
  ``V = 5 log10(r Delta) + V(1, alpha)`` with ``r`` (Sun-body) and ``Delta`` (observer-body)
  in au and the phase law ``V(1, alpha)`` of each planet. Each law is used only over the phase
  range the paper gives for it (geocentric plus the supplementary spacecraft ranges); outside
  it :func:`planet_v_mag` returns NaN.
* Moon: Allen (1973), Astrophysical Quantities, 3rd ed., sec. 66, as written by Krisciunas &
  Schaefer (1991, PASP 103, 1033, eq. 9): ``V = -12.73 + 0.026 |alpha| + 4e-9 alpha^4`` at
  the Moon's mean distance (384400 km from the observer, 1 au from the Sun), i.e.
  ``V(1, alpha) = 0.2212 + 0.026 alpha + 4e-9 alpha^4`` (alpha in deg). It omits the
  opposition surge (full Moon up to ~ 0.1-0.2 mag brighter within ~ 2 deg of opposition);
  used for alpha <= 150 deg, NaN beyond (the crescent is not well measured there).

Choices and what is left out
----------------------------
* Saturn: by default the GLOBE-ONLY laws (M&H eq. 11 for alpha <= 6 deg, eq. 12 for
  6 < alpha <= 150 deg), because the globe+rings law (eq. 10) holds only for alpha <= 6.5 deg
  and ring tilt <= 27 deg. Pass ``saturn_ring_tilt_rad`` (the paper's beta, see
  :func:`saturn_ring_tilt_rad`) to use eq. 10 (NaN outside its range): the rings add up to
  ~ 1.6 mag when open.
* Mars: the rotation and orbital-longitude corrections of M&H (their tables, +-0.06 mag) are
  not applied.
* Uranus: the sub-latitude term ``-0.00084 phi'`` (up to 0.076 mag) needs ``sub_latitude_rad``
  (the mean of the absolute sub-solar and sub-observer latitudes); by default it is 0.
* Neptune: the secular brightening (eq. 16) needs ``year``; by default the post-2000 value
  ``V(1, 0) = -7.00`` is used. Eq. 17 (alpha > 1.9 deg) holds only after 2000.0: NaN before.
* Earth: M&H eq. 4 (from the EPOXI/Deep Impact and Earthshine data), valid to 170 deg.
"""

from __future__ import annotations

import numpy as np

from .constants import AU_KM
from .errors import UnknownBodyError
from .frames import cross

MOON_MEAN_DISTANCE_KM = 384400.0
"""Mean Earth-Moon distance, km, at which Allen's full-Moon V = -12.73 is quoted."""

SATURN_POLE_ICRS = (np.deg2rad(40.589), np.deg2rad(83.537))
"""(ra, dec) of Saturn's north pole at J2000, rad; Archinal et al. (2018) WGCCRE 2015, Table 2."""

URANUS_POLE_ICRS = (np.deg2rad(257.311), np.deg2rad(-15.175))
"""(ra, dec) of Uranus's north pole at J2000, rad; Archinal et al. (2018) WGCCRE 2015, Table 2."""

# Phase-law validity ranges, deg (Mallama & Hilton 2018, the ranges stated with each equation).
PHASE_RANGE_DEG = {
    "mercury": (2.0, 170.0),
    "venus": (0.0, 179.0),
    "earth": (0.0, 170.0),
    "moon": (0.0, 150.0),
    "mars": (0.0, 120.0),
    "jupiter": (0.0, 130.0),
    "saturn": (0.0, 150.0),
    "uranus": (0.0, 154.0),
    "neptune": (0.0, 133.0),
}
MAGNITUDE_BODIES = tuple(PHASE_RANGE_DEG)


def _poly(a, coeffs):
    """sum coeffs[k] a^k (Horner)."""
    out = np.zeros_like(a)
    for c in reversed(coeffs):
        out = out * a + c
    return out


def _mercury(a):  # M&H eq. 1
    return _poly(a, (-0.613, 6.3280e-02, -1.6336e-03, 3.3644e-05, -3.4265e-07, 1.6893e-09, -3.0334e-12))


def _venus(a):  # M&H eq. 2 (alpha <= 163.7) and eq. 3 (163.7 < alpha < 179)
    low = _poly(a, (-4.384, -1.044e-03, 3.687e-04, -2.814e-06, 8.938e-09))
    high = _poly(a, (236.05828, -2.81914, 8.39034e-03))
    return np.where(a <= 163.7, low, high)


def _earth(a):  # M&H eq. 4
    return _poly(a, (-3.99, -1.060e-03, 2.054e-04))


def _mars(a):  # M&H eq. 5 (alpha <= 50) and eq. 6 (50 < alpha <= 120)
    return np.where(a <= 50.0, _poly(a, (-1.601, 2.267e-02, -1.302e-04)), _poly(a, (-0.367, -0.02573, 3.445e-04)))


def _jupiter(a):  # M&H eq. 7 (alpha <= 12) and eq. 8 (12 < alpha <= 130)
    x = a / 180.0
    with np.errstate(invalid="ignore", divide="ignore"):
        far = -9.428 - 2.5 * np.log10(_poly(x, (1.0, -1.507, -0.363, -0.062, 2.809, -1.876)))
    return np.where(a <= 12.0, _poly(a, (-9.395, -3.7e-04, 6.16e-04)), far)


def _saturn_globe(a):  # M&H eq. 11 (alpha <= 6) and eq. 12 (6 < alpha <= 150)
    return np.where(a <= 6.0, _poly(a, (-8.95, -3.7e-04, 6.16e-04)), _poly(a, (-8.94, 2.446e-04, 2.672e-04, -1.505e-06, 4.767e-09)))


def _saturn_rings(a, beta_rad):  # M&H eq. 10, alpha <= 6.5 deg and beta <= 27 deg
    s = np.sin(beta_rad)
    v = -8.914 - 1.825 * s + 0.026 * a - 0.378 * s * np.exp(-2.25 * a)
    ok = (a <= 6.5) & (beta_rad >= 0.0) & (beta_rad <= np.deg2rad(27.0))
    return np.where(ok, v, np.nan)


def _uranus(a, phi_rad):  # M&H eq. 13 (alpha <= 3.1) and eq. 14 (3.1 < alpha <= 154)
    v = -7.110 - 8.4e-04 * np.rad2deg(np.abs(phi_rad))
    return v + np.where(a > 3.1, _poly(a, (0.0, 6.587e-03, 1.045e-04)), 0.0)


def _neptune(a, year):  # M&H eq. 16 (secular V(1,0)) and eq. 17 (alpha > 1.9, t > 2000.0)
    if year is None:
        v0 = np.full_like(a, -7.00)
        after_2000 = np.ones_like(a, dtype=bool)
    else:
        year = np.asarray(year, dtype=float)
        v0 = np.clip(-6.89 - 0.0054 * (year - 1980.0), -7.00, -6.89)
        after_2000 = year >= 2000.0
    phase = np.where(after_2000, _poly(a, (0.0, 7.944e-03, 9.617e-05)), np.nan)
    return v0 + np.where(a > 1.9, phase, 0.0)


def _moon(a):  # Allen (1973) via Krisciunas & Schaefer (1991) eq. 9, rescaled to r = Delta = 1 au
    v10 = -12.73 - 5.0 * np.log10(MOON_MEAN_DISTANCE_KM / AU_KM)
    return v10 + 0.026 * a + 4e-9 * a**4


def planet_v_mag(
    body,
    sun_distance_km,
    observer_distance_km,
    phase_angle_rad,
    *,
    saturn_ring_tilt_rad=None,
    sub_latitude_rad=0.0,
    year=None,
):
    """Apparent V magnitude of a planet or the Moon (Mallama & Hilton 2018; Allen 1973).

    Parameters
    ----------
    body : str
        One of :data:`MAGNITUDE_BODIES` (mercury .. neptune, earth, moon).
    sun_distance_km : float or ndarray
        Sun-body distance ``r``, km.
    observer_distance_km : float or ndarray
        Observer-body distance ``Delta``, km.
    phase_angle_rad : float or ndarray
        Sun-body-observer angle, rad, in [0, pi].
    saturn_ring_tilt_rad : float or ndarray, optional
        Saturn only: the paper's ring tilt beta (:func:`saturn_ring_tilt_rad`); if given, the
        globe+rings law (eq. 10) is used instead of the globe-only laws.
    sub_latitude_rad : float or ndarray
        Uranus only: mean of the absolute sub-solar and sub-observer latitudes (default 0).
    year : float or ndarray, optional
        Neptune only: epoch as a decimal year (secular term); default: after 2000.

    Returns
    -------
    float or ndarray
        V magnitude; NaN where the phase angle is outside the law's range (see
        ``PHASE_RANGE_DEG``) or the law is undefined (Saturn rings, Neptune before 2000).

    Raises
    ------
    UnknownBodyError
        ``body`` has no phase law here.

    References
    ----------
    Mallama, A. & Hilton, J. L. (2018), Astronomy and Computing 25, 10-24, Eqs. 1-17 (the
    planets); Krisciunas, K. & Schaefer, B. E. (1991), PASP 103, 1033, Eq. 9 (the Moon, after
    Allen 1973).

    Examples
    --------
    Jupiter at opposition, 5.2 au from the Sun and 4.2 au from the observer:

    >>> from skynav.scenes import planet_v_mag
    >>> from skynav.scenes.constants import AU_KM
    >>> round(planet_v_mag("jupiter", 5.2 * AU_KM, 4.2 * AU_KM, 0.0), 3)
    -2.699
    >>> planet_v_mag("mercury", AU_KM, AU_KM, 0.0)   # outside its law's 2..170 deg
    nan
    """
    key = body.lower() if isinstance(body, str) else body
    if key not in PHASE_RANGE_DEG:
        raise UnknownBodyError(body, MAGNITUDE_BODIES)
    r_au = np.asarray(sun_distance_km, dtype=float) / AU_KM
    d_au = np.asarray(observer_distance_km, dtype=float) / AU_KM
    a = np.rad2deg(np.asarray(phase_angle_rad, dtype=float))
    scalar = r_au.ndim == 0 and d_au.ndim == 0 and a.ndim == 0
    a = np.atleast_1d(a).astype(float)
    if key == "saturn":
        law = _saturn_globe(a) if saturn_ring_tilt_rad is None else _saturn_rings(a, np.asarray(saturn_ring_tilt_rad, dtype=float))
    elif key == "uranus":
        law = _uranus(a, np.asarray(sub_latitude_rad, dtype=float))
    elif key == "neptune":
        law = _neptune(a, year)
    else:
        law = {"mercury": _mercury, "venus": _venus, "earth": _earth, "mars": _mars,
               "jupiter": _jupiter, "moon": _moon}[key](a)  # fmt: skip
    lo, hi = PHASE_RANGE_DEG[key]
    law = np.where((a >= lo) & (a <= hi), law, np.nan)  # NaN phase stays NaN
    with np.errstate(divide="ignore", invalid="ignore"):
        v = 5.0 * np.log10(r_au * d_au) + law
    return float(np.reshape(v, -1)[0]) if scalar and np.size(v) == 1 else v


def _angle(a, b):
    """Angle between vectors (..., 3), robust at small and large angles (atan2 of |a x b|, a.b)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return np.arctan2(np.linalg.norm(cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def phase_angle_rad(body_position_km, sun_position_km, observer_position_km):
    """Sun-body-observer angle, rad, in [0, pi].

    Parameters
    ----------
    body_position_km, sun_position_km, observer_position_km : ndarray, shape (3,) or (N, 3)
        Barycentric positions, km: the body at emission, the Sun at the body's emission epoch,
        the observer at reception.

    Returns
    -------
    float or ndarray, shape (N,)
        The phase angle, rad, in [0, pi] (0: the observer sees the lit side full).

    Examples
    --------
    A body at 1 au on the x axis, the observer beside it on the y axis: quarter phase.

    >>> from skynav.scenes import phase_angle_rad
    >>> a = phase_angle_rad([1.496e8, 0.0, 0.0], [0.0, 0.0, 0.0], [1.496e8, 1e6, 0.0])
    >>> round(float(np.degrees(a)), 6)
    90.0
    """
    body = np.asarray(body_position_km, dtype=float)
    return _angle(np.asarray(sun_position_km, dtype=float) - body, np.asarray(observer_position_km, dtype=float) - body)


def elongation_rad(body_position_km, sun_position_km, observer_position_km):
    """Sun-observer-body angle (solar elongation of the body), rad, in [0, pi]."""
    obs = np.asarray(observer_position_km, dtype=float)
    return _angle(np.asarray(sun_position_km, dtype=float) - obs, np.asarray(body_position_km, dtype=float) - obs)


def angular_diameter_rad(radius_km, distance_km):
    """Exact angular diameter of a sphere, ``2 asin(R / d)``, rad (NaN if ``d < R``)."""
    with np.errstate(invalid="ignore"):
        return 2.0 * np.arcsin(np.asarray(radius_km, dtype=float) / np.asarray(distance_km, dtype=float))


def sub_latitude_rad(pole_radec_rad, body_position_km, point_position_km):
    """Planetocentric latitude of the point below ``point`` (Sun or observer) on a body, rad.

    ``pole_radec_rad`` is the body's north pole (ra, dec) in ICRS, e.g. :data:`SATURN_POLE_ICRS`.
    """
    ra, dec = pole_radec_rad
    pole = np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])
    v = np.asarray(point_position_km, dtype=float) - np.asarray(body_position_km, dtype=float)
    return np.pi / 2.0 - _angle(np.broadcast_to(pole, v.shape), v)


def saturn_ring_tilt_rad(sun_sub_latitude_rad, observer_sub_latitude_rad):
    """Mallama & Hilton's beta: sqrt of the product of the saturnicentric sub-solar and
    sub-observer latitudes, 0 when they have opposite signs (unlit side of the rings)."""
    p = np.asarray(sun_sub_latitude_rad, dtype=float) * np.asarray(observer_sub_latitude_rad, dtype=float)
    return np.sqrt(np.where(p > 0.0, p, 0.0))
