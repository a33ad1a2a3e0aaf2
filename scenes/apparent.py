"""Apparent directions of solar-system bodies and stars as seen by a moving spacecraft.

Pure NumPy core: positions km, velocities km/s, times s (TDB past J2000), barycentric ICRS.
The renderer is the truth (docs/conventions.md, "Apparent directions"), so nothing here is first order.

What is modelled
----------------
1. Light-time, iterated (Newton's method on ``|r_b(t - tau) - r_o(t)| = c tau``) until the step
   is below 1e-10 s (the position then moved by ``-v step``, exact to < 1e-24 km); the emission
   epoch ``t - tau`` is kept as two parts so the ephemeris is read at it to ~1e-11 s, not to the
   ~2e-7 s resolution of a float of seconds past J2000.
2. Gravitational light deflection by the Sun, PPN gamma = 1, for a target at a finite distance
   (ERFA ``eraLd``; Kaplan et al. 2005, NOVAS ``grav_vec``; Klioner 2003 AJ 125, 1580). The Sun is
   taken where it was when the ray passed closest to it (as NOVAS and skyfield do). For stars the
   target is at infinity (ERFA ``eraLdsun``). Size: 1.75 arcsec at the solar limb, 4 mas at 90 deg
   from the Sun as seen from 1 AU, falling as ``1/r_obs``.
3. Aberration by the observer's barycentric velocity, exact special relativity (ERFA ``eraAb``
   WITHOUT its ``SRS/s`` gravitational-potential term; Kaplan et al. 2005 NOVAS ``aberration``;
   Klioner 2003 eq. 15). Up to 27.5 arcsec at 40 km/s; the second-order part is ~ 3.7 mas there.

What is neglected
-----------------
* Deflection by the planets: Jupiter 16 mas and Saturn 6 mas at their limbs, < 1 mas beyond
  ~ 20 and ~ 6 radii; Earth 0.6 mas at the limb. Apply them if a frame grazes a giant planet.
* The ``SRS/s`` term of ``eraAb`` (the Sun's potential at the observer): < 2e-8 x the aberration,
  i.e. < 1 microarcsec at 40 km/s and 0.3 AU.
* Gravitational time delay (Shapiro) in the light-time: < 250 microseconds in light-time, i.e.
  < 10 m of body motion at 40 km/s.
* The difference between the barycentric and the observer's proper time (the observer's clock).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import AU_KM, C_KM_S, GM_SUN_KM3_S2
from .frames import cross

SCHWARZSCHILD_RADIUS_SUN_KM = 2.0 * GM_SUN_KM3_S2 / C_KM_S**2
"""2 GM_sun / c^2, km, with the DE421 GM_sun of :mod:`skynav.scenes.constants` (ERFA ``ERFA_SRS`` x au
to 1.5e-12, its rounding)."""

LIGHT_TIME_TOL_S = 1e-10
"""Newton step below which the light-time iteration stops, s."""


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def aberrate(u, velocity_km_s):
    """Relativistic aberration of directions for a moving observer.

    Parameters
    ----------
    u : ndarray, shape (N, 3) or (3,)
        Unit vectors towards the sources, barycentric (natural, after deflection) directions.
    velocity_km_s : ndarray, shape (3,) or broadcastable to ``u``
        Observer's barycentric velocity, km/s (``|v| < c``).

    Returns
    -------
    ndarray, same shape as ``u``
        Apparent unit vectors in the observer's proper frame, axes parallel to ICRS.

    Notes
    -----
    With ``beta = v / c``, ``g = sqrt(1 - beta^2)`` (the inverse Lorentz factor):

    ``u' = (g u + (1 + u.beta / (1 + g)) beta) / (1 + u.beta)``

    which is exactly unit length. This is ERFA ``eraAb`` (IAU SOFA ``iauAb``) without the
    ``SRS/s`` term for the Sun's potential at the observer (< 1 microarcsec for any spacecraft
    beyond 0.3 AU), and the same as Kaplan et al. (2005, USNO Circular 179 / NOVAS
    ``aberration``) and Klioner (2003, AJ 125, 1580, eq. 15).

    Examples
    --------
    >>> u = aberrate(np.array([1.0, 0.0, 0.0]), np.array([0.0, 30.0, 0.0]))
    >>> bool(abs(np.arctan2(u[1], u[0]) - np.arcsin(30.0 / C_KM_S)) < 1e-15)
    True
    """
    u = np.asarray(u, dtype=float)
    beta = np.asarray(velocity_km_s, dtype=float) / C_KM_S
    g = np.sqrt(1.0 - np.sum(beta * beta, axis=-1, keepdims=True))
    pdv = np.sum(u * beta, axis=-1, keepdims=True)
    w1 = 1.0 + pdv / (1.0 + g)
    p = g * u + w1 * beta
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def deflect_by_sun(u, target_position_km, observer_position_km, sun_position_km):
    """Gravitational light deflection by the Sun (PPN gamma = 1).

    Parameters
    ----------
    u : ndarray, shape (N, 3) or (3,)
        Unit vectors from the observer to the sources (geometric, light-time corrected).
    target_position_km : ndarray, shape (N, 3) or (3,), or None
        Barycentric positions of the sources at emission, km. ``None`` means infinitely far
        (stars): the source direction seen from the Sun equals ``u``.
    observer_position_km : ndarray, shape (3,)
        Barycentric position of the observer, km.
    sun_position_km : ndarray, shape (3,)
        Barycentric position of the Sun (ideally when the ray passed closest to it), km.

    Returns
    -------
    ndarray, same shape as ``u``
        Deflected unit vectors (renormalised).

    Notes
    -----
    ERFA ``eraLd`` (Klioner 2003, eq. 70; Kaplan et al. 2005 NOVAS ``grav_vec``), with
    ``e`` the unit vector Sun -> observer at distance ``em``, ``q`` the unit vector
    Sun -> source:

    ``u' = u + (2 GM / c^2 em) / (q.(q + e)) * u x (e x q)``

    With ``target_position_km=None``, ``q = u`` (ERFA ``eraLdsun``). The denominator is
    limited below by ``1e-6 / max(em_au^2, 1)`` (ERFA's ``dlim``), which only matters for
    sources within ~0.1 deg behind the Sun, i.e. occulted.
    """
    u = np.asarray(u, dtype=float)
    sun = np.asarray(sun_position_km, dtype=float)
    e_vec = np.asarray(observer_position_km, dtype=float) - sun
    em_km = np.linalg.norm(e_vec, axis=-1, keepdims=True)
    e = e_vec / em_km
    if target_position_km is None:
        q = u
    else:
        q = _unit(np.asarray(target_position_km, dtype=float) - sun)
    em_au = em_km / AU_KM
    dlim = 1e-6 / np.maximum(em_au * em_au, 1.0)
    qdqpe = np.sum(q * (q + e), axis=-1, keepdims=True)
    w = SCHWARZSCHILD_RADIUS_SUN_KM / em_km / np.maximum(qdqpe, dlim)
    p1 = u + w * cross(u, cross(e, q))
    return p1 / np.linalg.norm(p1, axis=-1, keepdims=True)


def apparent_star_directions(
    u_astrometric, observer_position_km, observer_velocity_km_s, sun_position_km, *, deflection=True
):
    """Apparent directions of stars: Sun deflection (source at infinity), then aberration.

    Parameters
    ----------
    u_astrometric : ndarray, shape (N, 3) or (3,)
        Unit vectors already corrected for proper motion and parallax as seen from the observer.
    observer_position_km : ndarray, shape (3,)
        Observer's barycentric ICRS position, km.
    observer_velocity_km_s : ndarray, shape (3,)
        Observer's barycentric ICRS velocity, km/s.
    sun_position_km : ndarray, shape (3,)
        Sun's barycentric position at the observation epoch, km.
    deflection : bool
        Apply the Sun's light deflection (default True).

    Returns
    -------
    ndarray, same shape as ``u_astrometric``
        Apparent unit vectors (ICRS axes, observer's proper frame).

    References
    ----------
    Kaplan, G. H. et al. (2005), USNO Circular 179 (NOVAS ``grav_vec`` and ``aberration``);
    Klioner, S. A. (2003), AJ 125, 1580, Eq. 15 (aberration) and Eq. 70 (deflection); ERFA
    ``eraLdsun`` and ``eraAb``.

    Examples
    --------
    A star 90 deg from the direction of motion, seen at 30 km/s, moves by about v/c:

    >>> from skynav.scenes import apparent_star_directions
    >>> u = apparent_star_directions([1.0, 0.0, 0.0], [1.496e8, 0.0, 0.0], [0.0, 30.0, 0.0],
    ...                              [0.0, 0.0, 0.0], deflection=False)
    >>> round(float(np.degrees(np.arcsin(u[1])) * 3600), 2)   # arcsec
    20.64
    """
    u = _unit(u_astrometric)
    if deflection:
        u = deflect_by_sun(u, None, observer_position_km, sun_position_km)
    return aberrate(u, observer_velocity_km_s)


@dataclass(frozen=True, kw_only=True)
class BodyDirections:
    """Directions of one body seen from the observer at one epoch (all ICRS, barycentric).

    Made by :func:`apparent_bodies` and :func:`apparent_body`.

    Attributes
    ----------
    u_geometric : ndarray, shape (3,)
        Unit vector to the body's position at the observation epoch (no light-time).
    u_light_time : ndarray, shape (3,)
        Unit vector to the body where it emitted the light (astrometric direction).
    u_icrs : ndarray, shape (3,)
        The apparent direction: ``u_light_time`` deflected by the Sun (if asked) and
        aberrated; ICRS axes. The name of the truth files (``stars[].u_icrs``,
        ``bodies[].u_icrs``) and of the scene's views; ``u_apparent`` is an alias
        (docs/conventions.md "One name per quantity").
    light_time_s : float
        Light travel time, s.
    distance_km : float
        Observer (at reception) to body (at emission), km (= c * light_time_s).
    geometric_distance_km : float
        Observer to body, both at the observation epoch, km.
    position_km : ndarray, shape (3,)
        Body's barycentric position at emission, km.
    sun_position_km : ndarray, shape (3,)
        Sun's barycentric position at the body's emission epoch, km (for the phase angle).
    observer_position_km : ndarray, shape (3,)
        Observer's barycentric position, km.

    Examples
    --------
    >>> from skynav.scenes import apparent_body, default_ephemeris
    >>> eph = default_ephemeris()
    >>> r_earth, v_earth = eph.position_velocity("earth", 0.0)
    >>> mars = apparent_body(eph, "mars", r_earth, v_earth, 0.0)
    >>> bool(np.isclose(mars.distance_km, 299792.458 * mars.light_time_s))
    True
    >>> mars.u_icrs is mars.u_apparent
    True
    """

    u_geometric: np.ndarray
    u_light_time: np.ndarray
    u_icrs: np.ndarray
    light_time_s: float
    distance_km: float
    geometric_distance_km: float
    position_km: np.ndarray
    sun_position_km: np.ndarray
    observer_position_km: np.ndarray

    @property
    def u_apparent(self) -> np.ndarray:
        """Alias of :attr:`u_icrs` (the apparent direction), kept for code written before the
        names were unified."""
        return self.u_icrs


def _pv(eph, body, t_tdb_s, offset_s):
    """Ephemeris read at ``t_tdb_s + offset_s``, two-part when the ephemeris supports it."""
    try:
        return eph.position_velocity(body, t_tdb_s, offset_s=offset_s)
    except TypeError:  # an ephemeris without the two-part keyword
        return eph.position_velocity(body, t_tdb_s + offset_s)


def position_at(eph, body, t_tdb_s, offset_s=0.0):
    """Position only (``eph.position``: the bits of ``position_velocity(...)[0]`` at about half
    the cost) where the ephemeris has it, else :func:`_pv`'s."""
    try:
        return eph.position(body, t_tdb_s, offset_s=offset_s)
    except (AttributeError, TypeError):
        return _pv(eph, body, t_tdb_s, offset_s)[0]


def _light_times(eph, bodies, r_obs, t_tdb_s):
    """Newton's method on f(tau) = |r_b(t - tau) - r_o| - c tau, f'(tau) = -(rho_hat . v_b) - c,
    for each body, the bodies as rows of arrays; each body stops at its own first step below
    :data:`LIGHT_TIME_TOL_S`. Returns (tau (n,), r_b at t - tau (n, 3), r_b at t (n, 3)).

    The first step is taken from tau = 0 with the state at t (read anyway for the geometric
    direction). After the last step (< 1e-10 s) the position is moved by ``-v_b step``: its
    neglected term, ``|a_b| step^2 / 2 < 1e-24 km``, is far below a float's resolution of a
    position (~1e-8 km), so the ephemeris is not read again."""
    states = [_pv(eph, b, t_tdb_s, 0.0) for b in bodies]
    r_geo = np.array([s[0] for s in states], dtype=float).reshape(-1, 3)
    r_b = r_geo.copy()
    v_b = np.array([s[1] for s in states], dtype=float).reshape(-1, 3)
    tau = np.zeros(len(bodies))
    going = np.ones(len(bodies), bool)  # bodies still iterating
    for _ in range(20):
        rho = r_b - r_obs
        d = np.linalg.norm(rho, axis=-1)
        step = np.where(going, (d - C_KM_S * tau) / (C_KM_S + np.sum(rho * v_b, axis=-1) / d), 0.0)
        tau += step
        last = going & (np.abs(step) < LIGHT_TIME_TOL_S)
        if last.any():
            r_b[last] -= v_b[last] * step[last, None]
            going &= ~last
        if not going.any():
            return tau, r_b, r_geo
        todo = np.flatnonzero(going).tolist()
        states = [_pv(eph, bodies[i], t_tdb_s, -float(tau[i])) for i in todo]
        r_b[todo] = np.array([s[0] for s in states], dtype=float).reshape(-1, 3)
        v_b[todo] = np.array([s[1] for s in states], dtype=float).reshape(-1, 3)
    i = int(np.flatnonzero(going)[0])
    raise RuntimeError(f"light-time to {bodies[i]} did not converge (last step {step[i]:.3g} s)")


def apparent_bodies(
    eph, bodies, observer_position_km, observer_velocity_km_s, t_tdb_s, *, deflection=True, sun_position_km=None
) -> tuple:
    """Apparent directions of solar-system bodies: light-time, Sun deflection, aberration.

    Parameters
    ----------
    eph : Ephemeris
        Anything with ``position_velocity(body, t_tdb_s, offset_s=0.0)`` returning barycentric
        ICRS km and km/s (``skynav.scenes.ephemeris_jpl.Ephemeris``).
    bodies : sequence of str
        Body names, each one of ``ephemeris_jpl.BODIES``.
    observer_position_km, observer_velocity_km_s : ndarray, shape (3,)
        Observer's barycentric ICRS state at reception, km and km/s.
    t_tdb_s : float
        Reception epoch, TDB seconds past J2000.
    deflection : bool
        Apply the Sun's light deflection (never applied to the Sun itself).
    sun_position_km : ndarray, shape (3,), optional
        The Sun's barycentric position at ``t_tdb_s`` as ``eph.position("sun", t_tdb_s)`` gives
        it, from a caller that has it (read here when not given).

    Returns
    -------
    tuple of BodyDirections
        One per body, in the order of ``bodies``. The bodies are computed together, as rows of
        arrays (one formula for one body or ten; each body's numbers depend on that body alone).

    Raises
    ------
    RuntimeError
        The light-time iteration did not converge in 20 steps.

    References
    ----------
    Kaplan, G. H. et al. (2005), USNO Circular 179 (NOVAS ``grav_vec``, ``aberration``);
    Klioner, S. A. (2003), AJ 125, 1580, Eq. 15 and Eq. 70; ERFA ``eraLd`` and ``eraAb``. The
    model and what it neglects are in the module's docstring.

    Examples
    --------
    Jupiter and Saturn from the Earth at J2000 (the Earth's state from the same ephemeris):

    >>> from skynav.scenes import apparent_bodies, default_ephemeris
    >>> eph = default_ephemeris()
    >>> r_earth, v_earth = eph.position_velocity("earth", 0.0)
    >>> jup, sat = apparent_bodies(eph, ("jupiter", "saturn"), r_earth, v_earth, 0.0)
    >>> 1800.0 < jup.light_time_s < 3000.0 < sat.light_time_s
    True
    """
    bodies = tuple(bodies)
    r_obs = np.asarray(observer_position_km, dtype=float).reshape(3)
    v_obs = np.asarray(observer_velocity_km_s, dtype=float).reshape(3)
    t_tdb_s = float(t_tdb_s)
    tau, r_b, r_geo = _light_times(eph, bodies, r_obs, t_tdb_s)
    taus = tau.tolist()
    sun_emit = np.array([position_at(eph, "sun", t_tdb_s, -ti) for ti in taus], dtype=float).reshape(-1, 3)
    rho = r_b - r_obs
    distance_km = np.linalg.norm(rho, axis=-1)
    u_lt = rho / distance_km[:, None]
    u = u_lt
    bent = [i for i, b in enumerate(bodies) if deflection and b != "sun"]
    if bent:
        # Sun where the ray passed closest to it (NOVAS/skyfield): time from the point of
        # closest approach to the observer, clipped to [0, tau].
        if sun_position_km is not None:
            sun_now = sun_position_km
        elif "sun" in bodies:  # its state at t, read for its geometric direction
            sun_now = r_geo[bodies.index("sun")]
        else:
            sun_now = position_at(eph, "sun", t_tdb_s, 0.0)
        dlt = np.clip(np.sum((np.asarray(sun_now, dtype=float) - r_obs) * u_lt[bent], axis=-1) / C_KM_S, 0.0, tau[bent])
        sun_close = np.array([position_at(eph, "sun", t_tdb_s, -x) for x in dlt.tolist()], dtype=float).reshape(-1, 3)
        u = u_lt.copy()
        u[bent] = deflect_by_sun(u_lt[bent], r_b[bent], r_obs, sun_close)
    u_app = aberrate(u, v_obs)
    geo = r_geo - r_obs
    geo_d = np.linalg.norm(geo, axis=-1)
    u_geo = geo / geo_d[:, None]
    return tuple(
        BodyDirections(
            u_geometric=u_geo[i],
            u_light_time=u_lt[i],
            u_icrs=u_app[i],
            light_time_s=taus[i],
            distance_km=float(distance_km[i]),
            geometric_distance_km=float(geo_d[i]),
            position_km=r_b[i],
            sun_position_km=sun_emit[i],
            observer_position_km=r_obs,
        )
        for i in range(len(bodies))
    )


def apparent_body(
    eph, body, observer_position_km, observer_velocity_km_s, t_tdb_s, *, deflection=True, sun_position_km=None
) -> BodyDirections:
    """Apparent direction of one solar-system body: :func:`apparent_bodies` of ``(body,)``.

    Parameters
    ----------
    eph : Ephemeris
        Anything with ``position_velocity(body, t_tdb_s, offset_s=0.0)`` returning barycentric
        ICRS km and km/s (``skynav.scenes.ephemeris_jpl.Ephemeris``).
    body : str
        Body name, one of ``ephemeris_jpl.BODIES``.
    observer_position_km, observer_velocity_km_s : ndarray, shape (3,)
        Observer's barycentric ICRS state at reception, km and km/s.
    t_tdb_s : float
        Reception epoch, TDB seconds past J2000.
    deflection : bool
        Apply the Sun's light deflection (never applied to the Sun itself).
    sun_position_km : ndarray, shape (3,), optional
        The Sun's barycentric position at ``t_tdb_s``, km, when the caller has it.

    Returns
    -------
    BodyDirections
        The body's geometric, light-time and apparent directions and distances.

    References
    ----------
    As :func:`apparent_bodies`.

    Examples
    --------
    Mars from 1e6 km beside the Earth at J2000: light-time, then about 14 arcsec of
    deflection and aberration:

    >>> from skynav.scenes import apparent_body, default_ephemeris
    >>> eph = default_ephemeris()
    >>> r, v = eph.position_velocity("earth", 0.0)
    >>> mars = apparent_body(eph, "mars", r + [1e6, 0.0, 0.0], v, 0.0)
    >>> round(mars.light_time_s, 1)
    920.2
    >>> round(float(np.degrees(np.arccos(mars.u_icrs @ mars.u_light_time)) * 3600), 1)   # arcsec
    14.1
    """
    return apparent_bodies(eph, (body,), observer_position_km, observer_velocity_km_s, t_tdb_s, deflection=deflection,
                           sun_position_km=sun_position_km)[0]
